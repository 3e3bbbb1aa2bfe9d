#!/usr/bin/env bash
# The GPU tests and benchmarks in one time-boxed run (issue 25 part 3; results/gpu/figures.md):
# cuda_ad_rgb, each figure with its CPU baseline (llvm_ad_rgb) measured in the same run on the
# same machine.
#
#   make bench-gpu        # or: PY=.venv/bin/python OUT=results/gpu/run bash bench/benchmarks/gpu_run.sh
#
# Environment: PY (python with the project's dependencies; default python3), OUT (what to keep:
# log.txt, figures.json, results.tar.gz; default ./gpu-run), BUDGET (seconds for the whole run,
# default 1800; a step that would not fit is skipped and says so), WORKERS_BIG (workers of the
# 8-sample dataset, default 8), CPU_VARIANT (the baseline, default llvm_ad_rgb). Each step has its
# own timeout; a failing step is logged and the run goes on. The figures are read from the
# commands' own manifests, never estimated (figures.json), and every step's count of Dr.Jit's
# OptiX warning "more than one OptiX shader binding table" is printed at the end (it means ray
# queries were dropped: renderers/frames.py evaluates each scene's queries in its own kernel).
set -u
T0=${T0:-$(date +%s)}
PY=${PY:-python3}
OUT=${OUT:-$PWD/gpu-run}
BUDGET=${BUDGET:-1800}
WORKERS_BIG=${WORKERS_BIG:-8}
WORK=${WORK:-$(mktemp -d /tmp/gpu-run.XXXX)}
CUDA=cuda_ad_rgb
CPU=${CPU_VARIANT:-llvm_ad_rgb}
mkdir -p "$OUT" "$WORK"
exec > >(tee "$OUT/log.txt") 2>&1
export PYTHONUNBUFFERED=1
STEPS=$WORK/steps.tsv
: > "$STEPS"

left() { echo $(( BUDGET - ($(date +%s) - T0) )); }

# step NAME MAX_S CMD...: run CMD with a timeout of min(MAX_S, time left - 15 s); log rc and wall.
step() {
  local name=$1 max=$2; shift 2
  local l t s e rc cmd="$*"
  cmd=${cmd//$'\n'/ }
  l=$(left); t=$(( max < l - 15 ? max : l - 15 ))
  if [ "$t" -lt 20 ]; then
    echo "### SKIP $name: $l s of the budget left"
    printf '%s\tskipped\t\t%s\n' "$name" "$cmd" >> "$STEPS"
    return 0
  fi
  echo "### STEP $name (timeout ${t} s, $(( $(date +%s) - T0 )) s into the run): $*"
  s=$(date +%s.%N)
  timeout -k 5 "$t" "$@"
  rc=$?
  e=$(date +%s.%N)
  echo "### END $name rc=$rc wall=$(awk "BEGIN{printf \"%.1f\", $e - $s}") s"
  printf '%s\t%s\t%s\t%s\n' "$name" "$rc" "$(awk "BEGIN{printf \"%.1f\", $e - $s}")" "$cmd" >> "$STEPS"
}


echo "### machine"
nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader 2>&1
nproc; free -g | head -2
"$PY" - <<'EOF'
import platform, importlib
print("python", platform.python_version())
for m in ("numpy", "pandas", "pyarrow", "cv2", "trimesh", "mitsuba", "drjit", "matplotlib"):
    try:
        mod = importlib.import_module(m)
        print(m, getattr(mod, "__version__", "?"), mod.__file__)
    except Exception as exc:
        print(m, "IMPORT FAILED:", repr(exc))
import cv2
print("cv2.aruco.ArucoDetector:", hasattr(getattr(cv2, "aruco", None), "ArucoDetector"))
EOF
step variant-auto 60 "$PY" -m renderers.variant
step probe-cuda 90 "$PY" -c "
import time; t=time.perf_counter()
from renderers.variant import select_variant; print(select_variant('$CUDA'))
import drjit as dr, mitsuba as mi
x = dr.arange(mi.Float, 1 << 20)
print('sum', dr.sum(dr.minimum(x, 5.0)), 'in', round(time.perf_counter() - t, 2), 's')
print(dr.whos_str() if hasattr(dr, 'whos_str') else '')
"
step probe-cpu 60 "$PY" -c "
from renderers.variant import select_variant; print(select_variant('$CPU'))
import drjit as dr, mitsuba as mi
print('libLLVM', dr.detail.llvm_version(), 'sum', dr.sum(dr.minimum(dr.arange(mi.Float, 1000), 5.0)))
"

# --- the GPU tests (skip without a GPU; compare with llvm_ad_rgb where libLLVM >= 17 is found) ----
step pytest-gpu 900 "$PY" -m pytest -q tests/test_gpu.py -p no:cacheprovider -rA --durations=0

# --- figures: each GPU figure with its CPU baseline right after it --------------------------------
step render-marker-cuda 90 "$PY" -m bench.cli bench render --variant $CUDA --out "$WORK/render-marker-$CUDA"
step render-marker-cpu 60 "$PY" -m bench.cli bench render --variant $CPU --out "$WORK/render-marker-$CPU"
step study-quick-cuda 90 "$PY" -m bench.cli detectability --quick --variant $CUDA --out "$WORK/study-quick-$CUDA"
step study-quick-cpu 120 "$PY" -m bench.cli detectability --quick --variant $CPU --out "$WORK/study-quick-$CPU"
step dataset-quick-cuda-w1 90 "$PY" -m bench.cli dataset --quick --variant $CUDA --workers 1 --out "$WORK/dataset-quick-$CUDA-w1"
step dataset-quick-cpu-w1 240 "$PY" -m bench.cli dataset --quick --variant $CPU --workers 1 --out "$WORK/dataset-quick-$CPU-w1"
BIG=(--protocol outdoor --foliage soft,dense --distance intermediate --branches none,0,50,0+100 --passes 1)
step dataset-8-cuda-w$WORKERS_BIG 120 "$PY" -m bench.cli dataset "${BIG[@]}" --variant $CUDA --workers "$WORKERS_BIG" --out "$WORK/dataset-8-$CUDA-w$WORKERS_BIG"
step dataset-8-cpu-w$WORKERS_BIG 300 "$PY" -m bench.cli dataset "${BIG[@]}" --variant $CPU --workers "$WORKERS_BIG" --out "$WORK/dataset-8-$CPU-w$WORKERS_BIG"
step dataset-quick-cuda-w3 60 "$PY" -m bench.cli dataset --quick --variant $CUDA --workers 3 --out "$WORK/dataset-quick-$CUDA-w3"
step dataset-quick-cpu-w3 120 "$PY" -m bench.cli dataset --quick --variant $CPU --workers 3 --out "$WORK/dataset-quick-$CPU-w3"

# --- more figures, while the budget lasts ----------------------------------------------------------
step bench-dataset-cuda 120 "$PY" -m bench.cli bench dataset --quick --frames 30 --variant $CUDA --out "$WORK/bench-dataset-$CUDA"
step bench-dataset-cpu 120 "$PY" -m bench.cli bench dataset --quick --frames 30 --variant $CPU --out "$WORK/bench-dataset-$CPU"
step render-array-cuda 60 "$PY" -m bench.cli bench render --scene array --variant $CUDA --out "$WORK/render-array-$CUDA"
step render-array-cpu 60 "$PY" -m bench.cli bench render --scene array --variant $CPU --out "$WORK/render-array-$CPU"
step study-bench-cuda 120 "$PY" -m bench.cli bench detectability --quick --variant $CUDA
step study-bench-cpu 120 "$PY" -m bench.cli bench detectability --quick --variant $CPU
step scale-cuda 300 "$PY" -m bench.cli bench scale --variant $CUDA --executors inline,pool --workers-max 4 --out "$WORK/scale-$CUDA"
step scale-cpu 300 "$PY" -m bench.cli bench scale --variant $CPU --executors inline,pool --workers-max 4 --out "$WORK/scale-$CPU"

# --- collect: figures.json from the manifests, the small files in one archive ---------------------
"$PY" - "$WORK" "$OUT/figures.json" <<'EOF'
import json, sys, platform, subprocess
from pathlib import Path
work, dest = Path(sys.argv[1]), Path(sys.argv[2])
def load(p):
    try:
        return json.loads(p.read_text())
    except Exception:
        return None
try:
    gpu = subprocess.run(["nvidia-smi", "--query-gpu=name,driver_version", "--format=csv,noheader"],
                         capture_output=True, text=True).stdout.strip()
except OSError as exc:
    gpu = f"no nvidia-smi: {exc}"
out = {"gpu": gpu or None, "python": platform.python_version(), "steps": [], "figures": {}}
for line in (work / "steps.tsv").read_text().splitlines():
    name, rc, wall, cmd = (line.split("\t") + ["", "", ""])[:4]
    out["steps"].append({"step": name, "rc": rc, "wall_s": wall, "command": cmd})
for d in sorted(p for p in work.iterdir() if p.is_dir()):
    m, b = load(d / "manifest.json"), load(d / "bench.json")
    fig = {}
    if m:
        for k in ("kind", "variant", "workers", "executor", "wall_s", "images_total", "images_per_s",
                  "frames", "frames_rendered", "frames_per_s", "stage_s", "stage_cpu_s", "versions"):
            if k in m:
                fig[k] = m[k]
    if b:
        fig["bench"] = b
    if fig:
        out["figures"][d.name] = fig
dest.write_text(json.dumps(out, indent=1, default=str))
print("### FIGURES")
for name, f in out["figures"].items():
    keys = ("images_per_s", "frames_per_s", "wall_s", "workers")
    print(name, {k: f[k] for k in keys if k in f},
          {k: v for k, v in (f.get("bench") or {}).items() if k in ("project", "cycles")})
EOF
(cd "$WORK" && find . -type f \( -name '*.json' -o -name '*.csv' -o -name '*.tsv' -o -name '*.md' \) \
  -size -4M -print0 | tar czf "$OUT/results.tar.gz" --null -T -)
awk '/^### STEP/{s=$3} /more than one OptiX shader binding table/{c[s]++}
  END{for (k in c) print "### OptiX warning (ray queries dropped) in step", k ":", c[k], "times"}' "$OUT/log.txt"
ls -la "$OUT"
echo "### run done after $(( $(date +%s) - T0 )) s"
