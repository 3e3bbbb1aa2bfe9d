"""``bench targets``: "met" is the figure against the threshold, an unmeasured target says why,
and the table and ``targets.csv`` have a row per target. Fake figures stand in for the dataset
runs and the renders in the fast tests; one slow test runs the real thing small."""

from __future__ import annotations

import csv
import io
import json
import os
import shutil
import time
from dataclasses import replace

import pytest

from bench.benchmarks import targets as t
from bench.benchmarks.scale import default_dataset_frames
from bench.cli.main import _parser
from bench.dataset.config import DatasetConfig
from scenes.validation import FieldError

QUICK = DatasetConfig(foliage=("soft",), distances=("intermediate",), branches=((),))
INDOOR = DatasetConfig(
    foliage=("soft",), distances=("far",), branches=((), (0.0,), (50.0,)), protocols=("indoor",)
)
HEADER = "| target | figure | threshold | met | baseline / ratio | command |"


@pytest.fixture
def fake_rates(monkeypatch):
    """dataset_rate answers from a table {workers: frames/s} (and records its calls)."""
    rates = {1: 10.0, 2: 20.0, "fewest": 25.0, "indoor": 4.0}
    calls = []

    def fake(config, workers, variant):
        calls.append((config, workers, variant))
        kind = "fewest" if config.sampling.subframes == 1 else workers
        kind = "indoor" if config.protocols == ("indoor",) else kind
        rate = rates["gpu" if variant == "cuda_ad_rgb" else kind]
        return {"frames_per_s": rate, "frames_rendered": 30, "wall_s": 30 / rate,
                "variant": variant or "llvm_ad_rgb", "cpu_s": 6.0}  # fmt: skip

    monkeypatch.setattr(t, "dataset_rate", fake)
    monkeypatch.setattr(t, "gpu_present", lambda: False)
    return rates, calls


@pytest.mark.parametrize(
    ("figure", "threshold", "above", "met"),
    [(15.0, 15.0, True, True), (14.9, 15.0, True, False), (1.49, 1.5, False, True),
     (1.5, 1.5, False, False), (240.0, 240.0, False, False), (31.0, 30.0, False, False)],
)  # fmt: skip
def test_met_is_the_figure_against_the_threshold(figure, threshold, above, met):
    assert t.judge(figure, threshold, above) is met
    target = t.Target("x", "x", "s", threshold, above, "cmd")
    assert t.Outcome(target, figure).met is met
    assert t.Outcome(target, None, why="not measured: because").met is None


def test_every_issue_target_once_with_a_command():
    keys = [x.key for x in t.TARGETS]
    assert keys == ["1a", "1b", "1c", "2a", "2b", "3", "4a", "4b"]
    assert all(x.command for x in t.TARGETS) and len(set(keys)) == len(keys)


@pytest.mark.parametrize("rates", [{1: 10.0, 2: 20.0}, {1: 5.0, 2: 7.0}])
def test_fake_figures_decide_met_and_unmeasured_rows_say_why(fake_rates, rates, monkeypatch):
    fake_rates[0].update(rates)
    import bench.benchmarks.cycles_scene as cycles

    monkeypatch.setattr(cycles, "import_bpy", lambda: None)
    outcomes = t.measure(QUICK, INDOOR)
    by_key = {o.target.key: o for o in outcomes}
    assert [o.target.key for o in outcomes] == [x.key for x in t.TARGETS]
    assert by_key["1a"].figure == rates[2] and by_key["1b"].figure == rates[1]
    assert by_key["1a"].met is (rates[2] >= 15) and by_key["1b"].met is (rates[1] >= 8)
    assert f"{rates[2] / rates[1]:.2f}x the 1-worker rate" in by_key["1a"].baseline
    cores = os.cpu_count()  # 6 s of CPU for 30 frames: 0.2 s a frame
    bound = f"0.200 s of CPU a frame: {cores} cores allow at most {cores / 0.2:.1f} frames/s"
    assert bound in by_key["1a"].baseline and by_key["1b"].baseline == bound
    assert by_key["1a"].baseline.endswith(
        "at the fewest rays (--spp 1 --subframes 1, under the 4 spp the ladder keeps for video): "
        f"25.00 frames/s, {bound}"
    )
    assert by_key["1a"].figure == rates[2]  # the fewest rays' rate is a bound, not the figure
    hours = default_dataset_frames(INDOOR) / 4.0 / 3600  # at the indoor samples' rate
    assert by_key["1c"].figure == pytest.approx(hours) and by_key["1c"].met is (hours < 1.5)
    assert by_key["1c"].baseline == (
        f"estimate: {default_dataset_frames(INDOOR):,} indoor frames at the rate of its first "
        f"samples on 2 workers, soft-far-none-indoor-sun, soft-far-0-indoor-sun (30 frames: "
        f"4.00 frames/s; {bound})"
    )
    (indoor,) = [c for c in fake_rates[1] if c[0].protocols == ("indoor",)]
    assert indoor[0] == t.leading_samples(INDOOR, 2) and indoor[1] == 2  # as make indoor
    for key in ("2a", "2b"):
        assert by_key[key].figure is None and "bpy not installed" in by_key[key].why
    assert by_key["3"].figure is None and "no device on this machine" in by_key["3"].why
    assert "results/gpu" in by_key["3"].why
    for key in ("4a", "4b"):
        assert by_key[key].figure is None and "--time-tests" in by_key[key].why
    text = t.table(outcomes)
    lines = text.splitlines()
    assert lines[0] == HEADER and len(lines) == 2 + len(t.TARGETS)
    assert all(line.count(" | ") == 5 for line in lines[2:])
    assert [line.split(" | ")[3] for line in lines[2:]] == [
        {True: "yes", False: "no", None: "n/a"}[o.met] for o in outcomes
    ]


def test_the_fewest_rays_change_only_the_sampling_as_the_options_named_do():
    """One ray a pixel at one time sample; the grid, camera and frames stay the quick run's,
    and the row's options give the same dataset on the command line."""
    from bench.cli.dataset import dataset_config

    fewest = t.fewest_rays(QUICK)
    assert (fewest.sampling.marker_spp, fewest.sampling.background_spp) == (1, 1)
    assert fewest.sampling.subframes == 1 and QUICK.sampling.subframes == 4
    assert replace(fewest, sampling=QUICK.sampling) == QUICK
    quick = dataset_config(_parser().parse_args(["dataset", "--quick"]))
    named = ["dataset", "--quick", *t.FEWEST_RAYS_OPTIONS.split()]
    assert dataset_config(_parser().parse_args(named)) == t.fewest_rays(quick) != quick


def test_the_leading_samples_are_the_grids_first():
    grid = DatasetConfig(
        foliage=("stiff", "soft"), distances=("close", "far"), protocols=("indoor",)
    )
    for n in (1, 2, 3):
        lead = t.leading_samples(grid, n)
        assert lead.samples() == grid.samples()[:n] and len(grid.samples()) > n
        assert replace(lead, foliage=grid.foliage, distances=grid.distances,
                       branches=grid.branches) == grid  # fmt: skip
    assert [s.sample_id for s in t.leading_samples(grid, 2).samples()] == [
        "stiff-close-none-indoor-sun",
        "stiff-close-0-indoor-sun",
    ]


def _burn(seconds: float) -> None:
    end = time.process_time() + seconds
    while time.process_time() < end:
        pass


def test_cpu_seconds_count_a_joined_child():
    """A pool's workers are joined when it closes: their CPU counts (1a's CPU a frame)."""
    import multiprocessing

    before = t.cpu_seconds()
    child = multiprocessing.get_context("spawn").Process(target=_burn, args=(0.4,))
    child.start()
    child.join()
    assert t.cpu_seconds() - before >= 0.4
    assert t.cpu_bound(4.0, 20, 2) == "0.200 s of CPU a frame: 2 cores allow at most 10.0 frames/s"


def test_quick_steps_the_frames_and_renders_no_cycles(fake_rates, monkeypatch):
    _, calls = fake_rates
    import bench.benchmarks.render as render

    monkeypatch.setattr(render, "bench_render", lambda *a, **k: pytest.fail("rendered"))
    outcomes = t.measure(QUICK, INDOOR, quick=True)
    assert {c[0].frames_step for c in calls} == {t.QUICK_FRAMES_STEP}  # the indoor one's too
    by_key = {o.target.key: o for o in outcomes}
    assert by_key["1a"].command.endswith(f"--frames-step {t.QUICK_FRAMES_STEP}")
    assert "--quick renders no Cycles" in by_key["2a"].why


def _render_figures(wall: float, cpu: float, equal: bool) -> dict:
    rows = {k: {"wall_s": [9.0, s]} for k, s in (("cycles", 12.0), ("project", 1.0))}
    return {"ratio_wall": wall, "ratio_cpu": cpu, "detection_equal": equal, **rows}


@pytest.mark.parametrize(("wall", "cpu", "equal"), [(12.0, 11.0, True), (12.0, 9.0, True),
                                                     (30.0, 30.0, False)])  # fmt: skip
def test_render_ratio_is_the_smaller_one_and_only_at_equal_detection(monkeypatch, wall, cpu, equal):
    import bench.benchmarks.cycles_scene as cycles
    import bench.benchmarks.render as render

    monkeypatch.setattr(cycles, "import_bpy", lambda: object())
    monkeypatch.setattr(render, "bench_render", lambda *a, **k: _render_figures(wall, cpu, equal))
    outcome = t.render_ratio("array", "2a")
    if not equal:
        assert outcome.figure is None and "detections differ" in outcome.why
        return
    assert outcome.figure == min(wall, cpu) and outcome.met is (min(wall, cpu) >= 10)
    assert "Cycles 12.00 s" in outcome.baseline


@pytest.mark.parametrize("within", [True, False])
def test_the_marker_ratio_counts_only_a_frame_within_the_traced_frames_seed_spread(
    monkeypatch, within
):
    import bench.benchmarks.cycles_scene as cycles
    import bench.benchmarks.render as render

    figures = _render_figures(40.0, 30.0, True)
    figures.update(traced={"wall_s": [2.0, 1.5]}, within_seed_spread=within)
    monkeypatch.setattr(cycles, "import_bpy", lambda: object())
    monkeypatch.setattr(render, "bench_render", lambda *a, **k: figures)
    outcome = t.render_ratio("marker", "2b")
    assert "crop + sky (1.50 s with every pixel traced)" in outcome.baseline
    if within:
        assert outcome.figure == 30.0 and outcome.met
    else:
        assert outcome.figure is None and "strays from the traced one" in outcome.why


def test_gpu_row_measures_on_a_device(fake_rates, monkeypatch):
    rates, calls = fake_rates
    rates["gpu"] = 400.0
    monkeypatch.setattr(t, "gpu_present", lambda: True)
    outcome = t.gpu_outcome(QUICK, 10.0, "")
    assert outcome.figure == 400.0 and outcome.met is True
    assert "40.0x the CPU" in outcome.baseline and calls[-1][1:] == (1, "cuda_ad_rgb")


@pytest.mark.skipif(shutil.which("make") is None, reason="needs make")
def test_test_rows_time_make_and_a_failure_has_no_figure(tmp_path):
    (tmp_path / "Makefile").write_text("test:\n\ttrue\ntest-fast:\n\tfalse\n")
    passed = t.suite_outcome("4a", tmp_path, measure=True)
    assert passed.figure is not None and passed.figure > 0 and passed.met is True
    failed = t.suite_outcome("4b", tmp_path, measure=True)
    assert failed.figure is None and "make test-fast failed (exit 2)" in failed.why
    missing = t.suite_outcome("4a", tmp_path / "nowhere", measure=True)
    assert missing.figure is None and "no Makefile" in missing.why


def test_csv_has_a_row_per_target_and_empty_cells_where_unmeasured():
    outcomes = [t.Outcome(t.BY_KEY["1a"], 16.0, "2.00x"), t.Outcome(t.BY_KEY["4a"], None, why="w")]
    rows = list(csv.DictReader(io.StringIO(t.csv_text(outcomes))))
    assert list(rows[0]) == list(t.CSV_COLUMNS)
    assert (rows[0]["figure"], rows[0]["met"], rows[0]["threshold"]) == ("16.0", "true", "15")
    assert (rows[1]["figure"], rows[1]["met"], rows[1]["baseline"]) == ("", "", "w")


def test_writes_csv_and_manifest_and_refuses_another_commands_folder(fake_rates, tmp_path):
    out = tmp_path / "targets"
    outcomes = t.bench_targets(QUICK, INDOOR, out, quick=True)
    rows = list(csv.DictReader(io.StringIO((out / "targets.csv").read_text())))
    assert [r["target"] for r in rows] == [o.target.key for o in outcomes]
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["kind"] == "bench-targets" and "targets.csv" in manifest["outputs"]
    assert len(manifest["load_average"]) == 2  # what the figures were measured under
    other = tmp_path / "other"
    other.mkdir()
    (other / "manifest.json").write_text(json.dumps({"kind": "bench-scale"}))
    calls = len(fake_rates[1])
    with pytest.raises(FieldError) as err:
        t.bench_targets(QUICK, INDOOR, other, quick=True)
    assert err.value.field == "out" and len(fake_rates[1]) == calls  # refused before any work


@pytest.mark.slow
def test_quick_run_prints_a_row_per_target(variant, pair_config, tmp_path, capsys):
    if variant.startswith("scalar"):
        pytest.skip("frame rendering needs a JIT variant")
    import dataclasses

    # one sample of the pair, a few frames: rates and rows do not depend on the sample count
    one = dataclasses.replace(pair_config, branches=pair_config.branches[:1])
    # 1c's grid: that sample at one frame in 40 (an indoor sample's dynamics take seconds)
    indoor = dataclasses.replace(one, frames_step=40)
    outcomes = t.bench_targets(one, indoor, tmp_path / "b", quick=True)
    printed = capsys.readouterr().out
    assert HEADER in printed and t.table(outcomes) in printed
    from bench.common.manifest import machine

    assert f"({machine()['cpu']}, " in printed.splitlines()[0]  # the figures' machine, named
    for o in outcomes:
        assert (o.figure is None) == (o.met is None) == bool(o.why.startswith("not "))
        assert o.met is None or o.met == t.judge(o.figure, o.target.threshold, o.target.above)
    measured = {o.target.key for o in outcomes if o.figure is not None}
    assert {"1a", "1b", "1c"} <= measured
    assert all(o.figure > 0 for o in outcomes if o.figure is not None)
    row_1a = {o.target.key: o for o in outcomes}["1a"].baseline
    assert " s of CPU a frame: " in row_1a and "at the fewest rays (--spp 1 --subframes 1" in row_1a
    row_1c = {o.target.key: o for o in outcomes}["1c"].baseline
    frames = default_dataset_frames(indoor)  # the whole grid is its one sample here
    assert f"{frames} indoor frames at the rate of its first samples on 2 workers, " in row_1c
    assert f"soft-intermediate-none-outdoor-lab ({frames} frames, one in 40: " in row_1c


@pytest.mark.skipif(shutil.which("make") is None, reason="needs make")
def test_make_bench_installs_cycles_before_the_targets_and_make_test_does_not(tmp_path):
    """Targets 2a and 2b need bpy: `make bench` installs it (no pip extra can: it pins numpy<2)
    before it measures; the suite's own set-up stays without it."""
    import subprocess
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]

    def dry_run(goal: str) -> list[str]:
        done = subprocess.run(
            ["make", "-n", goal, f"VENV={tmp_path / 'venv'}"],
            cwd=root, capture_output=True, text=True, check=True,
        )  # fmt: skip
        return done.stdout.splitlines()

    bench = dry_run("bench")
    install = [i for i, line in enumerate(bench) if "pip install --quiet --no-deps bpy==" in line]
    targets = [i for i, line in enumerate(bench) if "whiskerbench bench targets" in line]
    assert len(install) == 1 and len(targets) == 1 and install[0] < targets[0], bench
    assert not any("bpy" in line for line in dry_run("test") + dry_run("test-fast"))
