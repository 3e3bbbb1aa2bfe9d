"""The detectability study with another detector: ``--detector`` and ``--family``, peers' own
corners named as such, refusals in one line, and a crashing backend that costs its images, not
the run."""

from __future__ import annotations

import json
from pathlib import Path

import pandas as pd
import pytest
from crashing_study_backend import MODULE, crashes

from bench.cli.main import _parser, default_out, main, study_config
from bench.study import cells
from bench.study.config import Cell, StudyConfig, StudyConfigError
from pipeline.backends import BACKENDS, Backend, available
from pipeline.backends.isolated import stop_workers
from pipeline.detect import DetectorConfig

ROOT = Path(__file__).resolve().parents[1]
#: One cell: a frontal 13.2 mm marker, always detected.
GRID = ["--sizes", "13.2", "--alphas", "0", "--phis", "0", "--images", "6", "--workers", "1"]


def _run(argv: list[str], capsys) -> tuple[int, str, list[str]]:
    code = main(["detectability", *argv])
    captured = capsys.readouterr()
    return code, captured.out, [line for line in captured.err.splitlines() if "error" in line]


@pytest.mark.slow  # renders and a worker process: about 10 s
@pytest.mark.skipif(not available("locus"), reason="locus-tag not installed (.[peers])")
def test_a_study_with_locus_scores_its_own_corners(variant, tmp_path, capsys):
    out = tmp_path / "locus"
    code, _, errors = _run([*GRID, "--detector", "locus", "--out", str(out)], capsys)
    assert code == 0, errors
    images = pd.read_parquet(out / "images.parquet")
    summary = pd.read_csv(out / "summary.csv")
    assert set(images.detector) == set(summary.detector) == {"locus"}
    assert {"det_x0_px_own", "corner_err_px_own", "corner_err_px_lines"} <= set(images.columns)
    assert not [c for c in [*images.columns, *summary.columns] if "subpix" in c]
    assert len(images) == 6 and images.id_ok.all() and not images.backend_failed.any()
    assert (images.corner_err_px_own < 1.0).all() and (images.corner_err_px_lines < 1.0).all()
    manifest = json.loads((out / "manifest.json").read_text())
    assert (manifest["detector"], manifest["family"]) == ("locus", "4x4_50")
    assert manifest["backend_failures"] == {}
    assert json.loads((out / "config.json").read_text())["detector"]["backend"] == "locus"


@pytest.mark.parametrize(
    ("argv", "folder"),
    [
        ([], "default"),
        (["--quick"], "quick"),
        (["--quick", "--detector", "locus"], "quick-locus"),
        (["--detector", "locus", "--family", "apriltag_36h11"], "default-locus-apriltag_36h11"),
        (["--dictionary", "apriltag_16h5"], "default-apriltag_16h5"),
    ],
)
def test_default_folders_differ_by_detector_and_family(argv, folder, monkeypatch):
    monkeypatch.setattr("bench.study.config.require", lambda backend: None)  # peers or not
    args = _parser().parse_args(["detectability", *argv])
    assert default_out(study_config(args), args.quick).name == folder


def test_user_runs_default_outside_the_committed_results():
    """A bare ``whiskerbench detectability`` on a fresh clone was refused: its default folder
    was the committed results/detectability/default. Defaults go under runs/, ignored by git."""
    from bench.cli.images import DEFAULT_OUT

    args = _parser().parse_args(["detectability"])
    assert default_out(study_config(args), args.quick) == Path("runs/detectability/default")
    assert DEFAULT_OUT.parts == ("runs", "detect-images")  # detect-images' default
    assert "/runs/" in (ROOT / ".gitignore").read_text().splitlines()


def test_custom_grids_keep_their_hash_and_add_the_detector(monkeypatch):
    monkeypatch.setattr("bench.study.config.require", lambda backend: None)
    names = [
        default_out(study_config(_parser().parse_args(["detectability", "--sizes", "8.8", *a])), 0)
        for a in ([], ["--detector", "locus"])
    ]
    assert names[0].name.startswith("custom-") and names[1].name == f"{names[0].name}-locus"


def test_a_family_the_detector_cannot_decode_is_refused():
    with pytest.raises(StudyConfigError, match="detector locus cannot detect family") as info:
        StudyConfig(
            dictionary="apriltag_25h9", detector=DetectorConfig("4x4_50", "none", backend="locus")
        )
    assert info.value.field == "dictionary"


def test_a_missing_peer_says_how_to_install_it(tmp_path, capsys, monkeypatch):
    from pipeline.backends import missing_library

    def not_installed():
        raise missing_library("locus", "locus-tag")

    monkeypatch.setattr("pipeline.backends.locus.load", not_installed)
    out = tmp_path / "never"
    code, _, errors = _run([*GRID, "--detector", "locus", "--out", str(out)], capsys)
    assert code == 2 and len(errors) == 1 and not out.exists()
    assert errors[0].startswith("whiskerbench detectability: error: --detector: ")
    assert "locus-tag" in errors[0] and "pip install -e '.[peers]'" in errors[0]


@pytest.fixture
def crashing(monkeypatch):
    """A backend whose worker process aborts on about one image in three."""
    monkeypatch.syspath_prepend(str(ROOT))  # the parent imports it by the worker's name too
    row = Backend("crashing", MODULE, ("4x4_50",), "test", own_pose=False, isolated=True)
    monkeypatch.setitem(BACKENDS, row.name, row)
    yield row.name
    stop_workers()


@pytest.mark.slow  # a fresh worker process after each crash: about 7 s
def test_a_backend_crash_costs_its_images_and_the_study_goes_on(
    crashing, variant, tmp_path, capsys
):
    out = tmp_path / "crash"
    code, printed, errors = _run([*GRID, "--detector", crashing, "--out", str(out)], capsys)
    assert code == 0, errors
    config = StudyConfig(
        sizes_mm=(13.2,), alphas_deg=(0.0,), phis_deg=(0.0,), images=6,
        detector=DetectorConfig("4x4_50", "none", backend=crashing),
    )  # fmt: skip
    flat = Cell("sun", 13.2, 0.0, 0.0)
    drawn, _, _ = cells.cell_images(config, flat, cells.study_renderer(config), 6)
    expected = sum(crashes(image) for image in drawn)
    assert 0 < expected < 6  # the test needs both kinds of image

    images = pd.read_parquet(out / "images.parquet")
    failed = images[images.backend_failed]
    assert len(images) == 6 and len(failed) == expected and not failed.detected.any()
    row = pd.read_csv(out / "summary.csv").iloc[0]
    assert row.backend_failures == expected
    assert row.n_images == row.n_id_ok == 6 - expected and row.detection_rate == 1.0
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["backend_failures"][flat.output_name(1.0)] == expected
    assert manifest["detector"] == crashing
    assert f"detector {crashing} crashed on" in printed
    assert f"{flat.output_name(1.0)} ({expected})" in printed
