"""Plugins (docs/plugins.md): a user's detector and branch finder, named on the command line,
run wherever a built-in pipeline runs, isolated, and refused or stopped in one line by name.

The plugins are ``tests/plugin_samples.py`` (one per way to fail) and the example package
``examples/whisker_plugin`` (by path and, installed, by entry point).
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pandas as pd
import pytest
from fake_dataset import SAMPLES, make_dataset, small_camera

from bench.cli.main import main
from pipeline.backends import BackendCrashError, BackendError, get_backend
from pipeline.backends.plugin import TIMEOUT_ENV, PluginError, resolve
from pipeline.detect import DetectorConfig, detect_markers
from pipeline.presets import PRESETS, get_pipeline

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "whisker_plugin"
EXAMPLE_FILE = "examples/whisker_plugin/whisker_plugin/detector.py:detect"
SAMPLE = "tests.plugin_samples"
LONG, SHORT = SAMPLES


@pytest.fixture(autouse=True)
def _at_the_root(monkeypatch):
    """The tests run from the project root, as a user runs from their own folder."""
    monkeypatch.chdir(ROOT)


@pytest.fixture(scope="module")
def fake(tmp_path_factory) -> Path:
    return make_dataset(tmp_path_factory.mktemp("plugins") / "data")


def drawn(marker_id: int = 7, shape=(72, 96), at=(20, 30), side: int = 32) -> np.ndarray:
    """A white image with one 4x4_50 marker: exact corners at pixel centres."""
    family = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50)
    image = np.full(shape, 255, np.uint8)
    y, x = at
    image[y : y + side, x : x + side] = cv2.aruco.generateImageMarker(family, marker_id, side)
    return image


# -- naming a plugin ----------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("spec", "says"),
    [
        ("nowhere_at_all:detect", "cannot import nowhere_at_all: ModuleNotFoundError"),
        (f"{SAMPLE}:absent", "has no attribute 'absent'"),
        (f"{SAMPLE}:NOT_CALLABLE", "is a int, not callable"),
        (f"{SAMPLE}:not a name", "is not a function name"),
        ("no/such/file.py:detect", "no such file"),
        ("not-registered", "no entry point of that name in whiskerbench.detectors"),
        ("3bad module:detect", "is not a module name"),
    ],
)
def test_a_spec_that_cannot_be_resolved_is_refused_by_name(spec, says):
    with pytest.raises(PluginError, match=says) as raised:
        get_pipeline(f"plugin:{spec}")
    assert spec in str(raised.value) and "\n" not in str(raised.value)


def test_a_module_that_raises_on_import_is_refused(tmp_path, monkeypatch):
    (tmp_path / "broken_plugin.py").write_text("raise RuntimeError('no model file')\n")
    monkeypatch.chdir(tmp_path)
    with pytest.raises(PluginError, match="RuntimeError: no model file"):
        resolve("broken_plugin:detect")
    with pytest.raises(PluginError, match="cannot load broken_plugin.py"):
        resolve("broken_plugin.py:detect")


def test_a_plugin_pipeline_is_the_peers_preset_on_the_plugin():
    name = f"plugin:{EXAMPLE_FILE}/refine=lines"
    pipeline = get_pipeline(name)
    assert pipeline.name == name and pipeline.detector.backend == f"plugin:{EXAMPLE_FILE}"
    assert pipeline.detector.corner_refinement == "lines"
    assert (pipeline.search, pipeline.pose_method) == (PRESETS["locus"].search, "virtual")
    assert "/" not in pipeline.folder_name
    row = get_backend(pipeline.detector.backend)
    assert row.isolated and row.whole_frame and "4x4_50" in row.families
    with pytest.raises(ValueError, match="sets an OpenCV parameter"):
        get_pipeline(f"plugin:{SAMPLE}:good/window=15")


# -- running one ----------------------------------------------------------------------------------


@pytest.mark.parametrize("spec", [f"{SAMPLE}:good", EXAMPLE_FILE, "whisker_plugin.detector:detect"])
def test_a_plugin_finds_what_opencv_finds_in_its_worker(spec, monkeypatch):
    monkeypatch.syspath_prepend(str(EXAMPLE))  # the module form finds the package there
    monkeypatch.setenv("PYTHONPATH", str(EXAMPLE))  # and so does the worker
    image = drawn()
    config = DetectorConfig(corner_refinement="none", backend=f"plugin:{spec}")
    mine = detect_markers(image, config)
    theirs = detect_markers(image, DetectorConfig(corner_refinement="none"))
    assert [d.marker_id for d in mine] == [d.marker_id for d in theirs] == [7]
    np.testing.assert_allclose(mine[0].corners_px, theirs[0].corners_px)
    # a crop's detections come back in the full frame's pixels
    crop = detect_markers(image[10:, 20:], config, offset_px=(20, 10))
    np.testing.assert_allclose(crop[0].corners_px, theirs[0].corners_px)


def test_a_plugins_own_pose_is_kept_on_the_whole_frame_only():
    camera = small_camera()
    config = DetectorConfig(corner_refinement="none", backend=f"plugin:{SAMPLE}:with_pose")
    image = drawn()
    whole = detect_markers(image, config, camera=camera, own_pose_size_mm=10.0)
    np.testing.assert_array_equal(whole[0].own_T_cam_marker, np.eye(4))
    crop = detect_markers(image[5:, 5:], config, (5, 5), camera=camera, own_pose_size_mm=10.0)
    assert crop[0].own_T_cam_marker is None


@pytest.mark.parametrize(
    ("function", "says"),
    [
        ("raises", "raised ZeroDivisionError: planted on a 96x72 image"),
        ("wrong_shape", r"corners of shape \(3, 2\), not \(4, 2\)"),
        ("nan_corners", "corners with NaN or infinite values"),
        ("not_a_list", "returned a dict"),
    ],
)
def test_a_plugin_that_breaks_its_contract_is_stopped_by_name(function, says):
    config = DetectorConfig(corner_refinement="none", backend=f"plugin:{SAMPLE}:{function}")
    with pytest.raises(BackendError, match=says) as raised:
        detect_markers(drawn(), config)
    assert f"plugin:{SAMPLE}:{function}" in str(raised.value)
    assert "\n" not in str(raised.value)


@pytest.mark.parametrize(
    ("function", "says"),
    [
        pytest.param("hangs", "did not answer within 1 s", marks=pytest.mark.slow),
        ("crashes", r"crashed \(signal 11\)"),
    ],
)
def test_a_crash_or_hang_costs_the_image_and_three_in_a_row_stop_the_plugin(
    function, says, monkeypatch
):
    monkeypatch.setenv(TIMEOUT_ENV, "1")
    config = DetectorConfig(corner_refinement="none", backend=f"plugin:{SAMPLE}:{function}")
    for _ in range(2):
        with pytest.raises(BackendCrashError, match=says):
            detect_markers(drawn(), config)
    with pytest.raises(BackendError, match=f"{function} crashed or hung on 3 images in a row"):
        detect_markers(drawn(), config)
    # a good image between resets the count: the crash on black images costs those only
    config = DetectorConfig(corner_refinement="none", backend=f"plugin:{SAMPLE}:crashes_on_black")
    for image in (np.zeros((72, 96), np.uint8), drawn(), np.zeros((72, 96), np.uint8), drawn()):
        try:
            found = detect_markers(image, config)
        except BackendCrashError:
            assert not image.any()
        else:
            assert [d.marker_id for d in found] == [7]


# -- the command line -------------------------------------------------------------------------


def _refused(argv: list[str], capsys, says: str) -> None:
    try:
        code = main(argv)
    except SystemExit as exc:  # argparse's refusal of an option's value
        code = exc.code
    assert code == 2
    err = capsys.readouterr().err.strip()
    assert says in err and len(err.splitlines()) == 1, err


def test_an_unresolvable_plugin_is_refused_before_any_work(fake, tmp_path, capsys):
    out = tmp_path / "out"
    nope = "plugin:nowhere_at_all:detect"
    _refused(["score", str(fake), "--pipeline", nope, "--out", str(out)], capsys, nope[7:])
    argv = ["compare", str(fake), "--pipelines", f"paper,{nope}", "--out", str(out), "--quick"]
    _refused(argv, capsys, "cannot import nowhere_at_all")
    argv = ["compare", str(fake), "--pipelines", "paper,branch-plugin:nowhere:find", "--quick",
            "--out", str(out)]  # fmt: skip
    _refused(argv, capsys, "plugin 'nowhere:find': cannot import nowhere")
    argv = ["compare", str(fake), "--pipelines", "paper,results:missing.csv", "--quick",
            "--out", str(out)]  # fmt: skip
    _refused(argv, capsys, "results:missing.csv: missing.csv: no such file or folder")
    argv = ["detectability", "--quick", "--detector", "nowhere_at_all:detect", "--out", str(out)]
    _refused(argv, capsys, "--detector: plugin 'nowhere_at_all:detect'")
    _refused(["detectability", "--detector", "opencvv", "--out", str(out)], capsys,
             "no entry point of that name")  # fmt: skip
    assert not out.exists() and not (fake / "scores").exists()


@pytest.mark.slow
def test_a_branch_finder_is_scored_per_sample(fake, tmp_path, capsys):
    out = tmp_path / "gap"
    argv = ["score", str(fake), "--pipeline", f"branch-plugin:{SAMPLE}:gap_six", "--out", str(out)]
    assert main(argv) == 0
    assert "2 samples, 0 refused: branch outcome correct in 50%" in capsys.readouterr().out
    table = pd.read_csv(out / "samples.csv").set_index("sample_id")
    assert table.loc[SHORT, "outcome"] == "correct"  # its true gap is (6, 7)
    assert table.loc[LONG, "outcome"] == "false_positive"
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["config"]["branch_plugin"] == f"branch-plugin:{SAMPLE}:gap_six"


@pytest.mark.slow
def test_a_branch_finder_that_fails(fake, tmp_path, capsys):
    argv = ["score", str(fake), "--pipeline", f"branch-plugin:{SAMPLE}:bad_gap", "--out",
            str(tmp_path / "bad")]  # fmt: skip
    assert main(argv) == 1
    err = capsys.readouterr().err.strip()
    assert "returned gap 0: (6, 8); expected a list of (i, i + 1) gaps" in err, err
    assert len(err.splitlines()) == 1 and not (tmp_path / "bad" / "samples.csv").exists()
    out = tmp_path / "crash"
    argv = ["score", str(fake), "--pipeline", f"branch-plugin:{SAMPLE}:crashes_on_short",
            "--out", str(out)]  # fmt: skip
    assert main(argv) == 0
    assert f"{SHORT} refused: branch-plugin:{SAMPLE}:crashes_on_short crashed (signal 11)" in (
        capsys.readouterr().err
    )
    table = pd.read_csv(out / "samples.csv").set_index("sample_id")
    assert table.loc[SHORT, "outcome"] == "refused" and table.loc[LONG, "outcome"] == "correct"


# -- end to end -----------------------------------------------------------------------------------


def _install_example(tmp_path: Path) -> Path:
    """The example package installed with pip into a folder of its own (its entry points in
    its dist-info there), from a copy: the build leaves nothing in the clone."""
    source = shutil.copytree(EXAMPLE, tmp_path / "src", ignore=shutil.ignore_patterns("build"))
    site = tmp_path / "site"
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    pip = [sys.executable, "-m", "pip", "--disable-pip-version-check", "-q", "install"]
    argv = [
        *pip,
        "--no-deps",
        "--no-build-isolation",
        "--no-index",
        "--target",
        str(site),
        str(source),
    ]
    done = subprocess.run(argv, env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    return site


@pytest.mark.slow
def test_the_example_installed_is_found_by_its_entry_points(tmp_path, monkeypatch, fake, capsys):
    site = _install_example(tmp_path)
    monkeypatch.syspath_prepend(str(site))
    monkeypatch.setenv("PYTHONPATH", str(site))  # the worker's imports
    found = detect_markers(drawn(), DetectorConfig("4x4_50", "none", backend="plugin:plain-aruco"))
    assert [d.marker_id for d in found] == [7]
    assert resolve("largest-motion", "whiskerbench.branch_finders").__name__ == "find_branches"
    out = tmp_path / "scores"
    argv = ["score", str(fake), "--pipeline", "branch-plugin:largest-motion", "--out", str(out)]
    assert main(argv) == 0  # noise frames: no marker, no motion, no branch
    table = pd.read_csv(out / "samples.csv").set_index("sample_id")
    assert table.loc[LONG, "outcome"] == "correct" and table.loc[SHORT, "outcome"] != "refused"


def _exact_results(dataset: Path, path: Path) -> Path:
    """Every visible marker's labelled corners as a results file: an exact, untimed method."""
    from bench.dataset.loader import open_dataset
    from scenes.tables import CORNER_COLUMNS

    corners = [name for pair in CORNER_COLUMNS for name in pair]
    parts = [
        s.labels.loc[s.labels["visible"], ["frame", "marker_id", *corners]].assign(sample_id=s.id)
        for s in open_dataset(dataset)
    ]
    pd.concat(parts, ignore_index=True).to_csv(path, index=False)
    return path


def plugin_compare(tmp_path_factory, worker_id, rendered_pair):
    """(folder, names, summary) of ``compare`` of naive, plain OpenCV as a detector plugin, a
    plugin that raises, the labels' exact corners as a results file and a branch finder, on a
    copy of the rendered pair, run once per test run (:func:`conftest.compare_once`). Only the
    Pareto chart is drawn, the one figure read (the untimed method beside the others). Read,
    never written: the compare test below reads the report, test_results_file's plain-OpenCV
    test naive's scores (``score_dataset``'s, as ``score`` writes them)."""
    import dataclasses

    from conftest import compare_once

    from bench.evaluate.outside import parse_method
    from bench.evaluate.sweep_config import QUICK_SWEEP

    def names(folder: Path) -> list[str]:
        return ["naive", f"plugin:{EXAMPLE_FILE}", f"plugin:{SAMPLE}:raises",
                f"results:{folder / 'exact.csv'}", f"branch-plugin:{SAMPLE}:gap_six"]  # fmt: skip

    sweep = dataclasses.replace(
        QUICK_SWEEP, alphas_deg=(0.0,), phis_deg=(0.0,), lightings=("lab",), blur_px=(0.0,),
        read_noise_e=(3.0,), seeds=1, images=2,
    )  # fmt: skip
    folder, summary = compare_once(
        tmp_path_factory, worker_id, rendered_pair, "plugin-compare",
        lambda folder: [parse_method(n) for n in names(folder)], sweep, drawn=("pareto.png",),
        prepare=lambda folder: _exact_results(folder / "data", folder / "exact.csv"),
        cwd=ROOT,  # the plugin named by its path from the root
    )  # fmt: skip
    return folder, names(folder), summary


@pytest.mark.start_early
@pytest.mark.slow
def test_compare_runs_plugins_results_and_branch_finders_beside_the_pipelines(
    rendered_pair, tmp_path_factory, worker_id
):
    folder, names, summary = plugin_compare(tmp_path_factory, worker_id, rendered_pair)
    dataset, results, out = folder / "data", folder / "exact.csv", folder / "report"
    summary = summary.set_index("pipeline")
    assert summary.index.tolist() == names
    naive, plugin = summary.loc["naive"], summary.loc[names[1]]
    # plain OpenCV as a plugin is naive's detector: the same markers, the same corners
    assert plugin["fps"] > 0 and plugin["recall"] == naive["recall"] > 0.9
    assert 0 < plugin["fps_min"] <= plugin["fps"] <= plugin["fps_max"]  # in the shared rounds
    assert plugin["corner_err_px"] == pytest.approx(naive["corner_err_px"], abs=1e-6)
    assert "raised ZeroDivisionError: planted" in summary.loc[names[2], "failed"]
    assert np.isnan(summary.loc[names[2], "recall"])
    exact = summary.loc[names[3]]
    assert np.isnan(exact["fps"]) and exact["recall"] == 1 and exact["corner_err_px"] == 0
    finder = summary.loc[names[4]]
    assert np.isnan(finder["fps"]) and np.isfinite(finder["correct_rate"])
    sweeps = pd.read_csv(out / "sweeps.csv")
    assert set(sweeps["pipeline"]) == {"naive", names[1]}  # the failed one left out
    rounds = pd.read_csv(out / "speed_rounds.csv")  # it failed while timed: out of the rounds
    assert set(rounds["pipeline"]) == {"naive", names[1]} and len(rounds) == 2 * 3
    leads = pd.read_csv(out / "leaders.csv").set_index("measure")
    assert leads.loc["fps", "leader"] in ("naive", names[1])  # untimed: never a rival
    assert set(str(leads.loc["fps", "spread_rivals"]).split(", ")) <= {"naive", names[1], "nan"}
    assert leads.loc["recall", "best_peer"] == names[3]  # outside methods are peers
    report = (out / "report.md").read_text()
    assert f"- {names[2]}: failed, no measure: " in report
    assert (out / "pareto.png").stat().st_size > 1000
    assert (dataset / "scores" / f"results:{str(results).replace('/', '~')}").is_dir()


@pytest.mark.slow
def test_the_study_runs_a_plugin_detector(tmp_path, capsys):
    out = tmp_path / "study"
    argv = ["detectability", "--sizes", "13.2", "--alphas", "0", "--phis", "0", "--images", "10",
            "--lighting", "lab", "--detector", f"{SAMPLE}:good", "--workers", "1",
            "--out", str(out)]  # fmt: skip
    assert main(argv) == 0, capsys.readouterr().err
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["config"]["detector"]["backend"] == f"plugin:{SAMPLE}:good"
    table = pd.read_csv(out / "max_phi.csv")
    assert len(table) == 1


def test_compare_says_which_method_failed_and_which_has_no_speed(
    fake, tmp_path, monkeypatch, capsys
):
    """The console's lines, from run_compare's summary (stubbed: the real one is the slow test
    above): a failed method says why, an untimed one says accuracy only."""
    from bench.evaluate import compare
    from bench.evaluate.compare import failed_row, summarize
    from bench.evaluate.leaders import leaders

    scored = pd.DataFrame({"outcome": ["correct", "false_positive"], "markers_visible": [4, 4],
                           "markers_found": [4, 2], "false_detections": [0, 0]})  # fmt: skip
    for column in ("deflection_err_mm", "corner_err_px", "rot_err_deg", "trans_err_mm"):
        scored[column] = 0.5
    failed = failed_row(f"plugin:{SAMPLE}:raises", 2, "detector ... raised ZeroDivisionError")
    rows = [{**summarize("results:mine.csv", scored), "fps": float("nan")}, failed]

    def run_compare(dataset, pipelines, out, *args, **kwargs):
        assert [p.name for p in pipelines] == ["results:mine.csv", f"plugin:{SAMPLE}:raises"]
        out.mkdir(parents=True)
        summary = pd.DataFrame(rows)
        leaders(summary).to_csv(out / "leaders.csv", index=False)
        return summary

    monkeypatch.setattr(compare, "run_compare", run_compare)
    argv = ["compare", str(fake), "--pipelines", f"results:mine.csv,plugin:{SAMPLE}:raises",
            "--quick", "--out", str(tmp_path / "report")]  # fmt: skip
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert "results:mine.csv: accuracy only, correct 50%, recall 0.750" in out
    assert f"plugin:{SAMPLE}:raises: failed: detector ... raised ZeroDivisionError" in out
