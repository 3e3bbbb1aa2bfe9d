# Set-up lives here: `make study` and `make test` do everything on a fresh Debian machine.
VENV ?= .venv
PYTHON ?= python3
BIN := $(VENV)/bin

.PHONY: setup llvm cycles study quick test test-fast bench bench-gpu bench-pipeline compare ladder indoor lint

setup: $(VENV)/.installed llvm

$(VENV)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e '.[dev,peers]'
	touch $@

# Dr.Jit's fast CPU backend needs libLLVM >= 17 (15/16 abort drjit 1.5): install Debian's 19.
llvm: $(VENV)/.installed
	@if $(BIN)/python -m renderers.variant --has-llvm; then \
	  echo "libLLVM >= 17 found: the fast llvm_ad_rgb variant is available"; \
	elif [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then \
	  echo "installing libllvm19 (Dr.Jit's LLVM backend needs libLLVM >= 17)"; \
	  apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libllvm19 >/dev/null; \
	else \
	  echo "NOTE: no libLLVM >= 17 found; rendering falls back to the ~8x slower scalar_rgb."; \
	  echo "      Fast path: sudo apt-get install libllvm19  (or set DRJIT_LIBLLVM_PATH)"; \
	fi

# The default study on the prototype camera across its band: the PSF scales the profile's
# calibration left open (scenes/profiles/prototype.json "band"; whiskerbench camera calibrate).
BAND ?= band

study: setup
	$(BIN)/whiskerbench detectability --camera prototype --psf-scale $(BAND) \
	  --out results/detectability/default

quick: setup
	$(BIN)/whiskerbench detectability --quick

# Two pytest-xdist workers (a 2-core machine; TEST_WORKERS=0 runs in one process); session
# fixtures such as the rendered pair are built once per worker.
TEST_WORKERS ?= 2
TEST_PARALLEL := $(if $(filter 0,$(TEST_WORKERS)),,-n $(TEST_WORKERS) --dist load)

test: setup
	$(BIN)/pytest -q $(TEST_PARALLEL)

# The inner loop: everything but the tests marked slow (rendered datasets, real runs).
test-fast: setup
	$(BIN)/pytest -q -m "not slow" $(TEST_PARALLEL)

# Blender Cycles for `bench render` and targets 2a, 2b: bpy 5.0.1 (the newest for Python 3.11,
# a 374 MB wheel) pins numpy<2, which opencv 5 rules out, so pip cannot resolve it as an extra;
# it renders with numpy 2 (pyproject.toml). Only `make bench` installs it; `make test` does not.
BPY_VERSION ?= 5.0.1

cycles: $(VENV)/.cycles

$(VENV)/.cycles: $(VENV)/.installed
	$(BIN)/pip install --quiet --no-deps bpy==$(BPY_VERSION)
	touch $@

# Ends with issue 25's targets, each figure against its threshold (runs/bench-targets/targets.csv);
# they include `bench render` of both scenes (--scene array and the marker, 4 spp) against Cycles.
# TARGETS_OPTIONS= leaves out timing make test and make test-fast (minutes).
TARGETS_OPTIONS ?= --time-tests

bench: setup cycles
	$(BIN)/whiskerbench bench detectability
	$(BIN)/whiskerbench bench detectability --psf-scale $(BAND) --full-frame-cells 1
	$(BIN)/whiskerbench bench scale
	$(BIN)/whiskerbench bench targets $(TARGETS_OPTIONS)

# On a machine with an NVIDIA GPU: tests/test_gpu.py, then each benchmark on cuda_ad_rgb with its
# llvm_ad_rgb baseline in the same run; time-boxed (BUDGET s). Figures: results/gpu/figures.md.
GPU_OUT ?= results/gpu/run
bench-gpu: setup
	PY=$(BIN)/python OUT=$(GPU_OUT) BUDGET=$${BUDGET:-1800} bash bench/benchmarks/gpu_run.sh

# The comparison's dataset: 24 outdoor samples (soft strips and dense leaves, 3 distances, no /
# one / two branches), about 5 min to render; reruns skip what is done.
COMPARE_DATASET ?= data/compare
COMPARE_PIPELINES ?= paper,fast,robust,naive,paper/aruco3=on,paper/refine=contour,fast/search=full,locus,apriltag,robust/detector=locus,hybrid

compare: setup
	$(BIN)/whiskerbench dataset --protocol outdoor --foliage soft,dense \
	  --distance far,intermediate,close --branches none,0,50,0+100 --passes 1 \
	  --out $(COMPARE_DATASET)
	$(BIN)/whiskerbench compare $(COMPARE_DATASET) --pipelines $(COMPARE_PIPELINES) \
	  --out results/compare/default

# The fidelity ladder (issue 13): each rendering choice against a path-traced full-frame
# reference, for study cells near 95 % and a labeled video; resumable. Renders and videos stay
# in data/ladder; its tables and chart go to results/ladder/.
LADDER_OPTIONS ?= --spp 1,2,4,8,16 --workers 2

ladder: setup
	$(BIN)/whiskerbench ladder --out data/ladder $(LADDER_OPTIONS)
	mkdir -p results/ladder
	cp data/ladder/rungs.csv data/ladder/defaults.csv data/ladder/table.md \
	  data/ladder/ladder.png data/ladder/config.json data/ladder/manifest.json results/ladder/

# The default grid's 84 indoor samples (issue 13 part 5): prototype camera, every frame (about
# 82,600), then the `paper` preset; the small results go to results/indoor/, the videos stay in
# data/. Hours on 2 cores; reruns resume where they stopped.
INDOOR_DATASET ?= data/indoor

indoor: setup
	$(BIN)/whiskerbench dataset --protocol indoor --workers 2 --out $(INDOOR_DATASET)
	$(BIN)/whiskerbench score $(INDOOR_DATASET) --pipeline paper --workers 2
	mkdir -p results/indoor
	cp $(INDOOR_DATASET)/scores/paper/samples.csv $(INDOOR_DATASET)/scores/paper/grid-indoor-sun.png \
	  results/indoor/
	cp $(INDOOR_DATASET)/scores/paper/manifest.json results/indoor/score-manifest.json
	cp $(INDOOR_DATASET)/manifest.json results/indoor/dataset-manifest.json

bench-pipeline: setup
	$(BIN)/whiskerbench bench pipeline --out results/compare/bench

lint: setup
	$(BIN)/ruff check .
