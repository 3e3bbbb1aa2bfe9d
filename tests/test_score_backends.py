"""Scoring any backend: its own pose scored beside the project's, the dataset's marker family
given to every pipeline (or refused in one line), frames a backend crashed on reported."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pandas as pd
import pytest
from test_score import _labels

from bench.evaluate.score import dataset_family, for_family, score_markers
from pipeline.backends import BackendCrashError, available
from pipeline.presets import PRESETS
from scenes.conventions import make_T, rot_x
from scenes.tables import OWN_POSE_PREFIX, pose_values


def test_own_pose_errors_are_scored_beside_the_projects() -> None:
    labels = _labels()
    det = labels.drop(columns=["visible"]).copy()
    own = make_T(rot_x(np.radians(4.0)), [0, 2.5, 200])  # 4 deg and 2.5 mm off
    det = det.assign(**pose_values(np.tile(own, (len(det), 1, 1)), OWN_POSE_PREFIX))
    s = score_markers(det, labels)
    assert s["own_rot_err_deg"] == pytest.approx(4.0) and s["own_trans_err_mm"] == pytest.approx(
        2.5
    )
    assert s["rot_err_deg"] == pytest.approx(0.0) and s["trans_err_mm"] == pytest.approx(0.0)
    none = det.assign(**pose_values(np.full((len(det), 4, 4), np.nan), OWN_POSE_PREFIX))
    s = score_markers(none, labels)  # a backend without a pose of its own, as opencv
    assert np.isnan(s["own_rot_err_deg"]) and np.isnan(s["own_trans_err_mm"])
    assert s["trans_err_mm"] == pytest.approx(0.0)


def test_a_pipeline_takes_the_datasets_family_or_is_refused() -> None:
    paper = PRESETS["paper"]
    assert for_family(paper, None) is paper and for_family(paper, "4x4_50") is paper
    tagged = for_family(paper, "apriltag_36h11")
    assert tagged.detector.dictionary == "apriltag_36h11" and tagged.name == paper.name
    assert tagged.detector.corner_refinement == paper.detector.corner_refinement
    with pytest.raises(ValueError) as info:
        for_family(PRESETS["locus"], "5x5_100")
    assert str(info.value).startswith("pipeline locus: detector locus cannot detect family 5x5_100")
    assert "\n" not in str(info.value)


def _fake_dataset(folder, dictionary: str):
    """A folder whose manifest names the array's family (enough for the family check)."""
    folder.mkdir()
    config = {"array": {"dictionary": dictionary}}
    (folder / "manifest.json").write_text(json.dumps({"kind": "dataset", "config": config}))
    return folder


@pytest.mark.slow  # over a second of CPU: out of `make test-fast`
@pytest.mark.skipif(not available("locus"), reason="locus-tag not installed (the peers extra)")
def test_score_refuses_a_family_the_backend_cannot_detect_before_any_work(tmp_path) -> None:
    data = _fake_dataset(tmp_path / "data", "DICT_5X5_100")
    assert dataset_family(data) == "5x5_100" and dataset_family(tmp_path) is None
    out = tmp_path / "scores"
    run = subprocess.run(
        [sys.executable, "-m", "bench.cli", "score", str(data), "--pipeline", "locus"]
        + ["--out", str(out)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert run.returncode == 2 and len(run.stderr.strip().splitlines()) == 1
    assert "detector locus cannot detect family 5x5_100" in run.stderr
    assert not out.exists()


@pytest.mark.slow
@pytest.mark.usefixtures("figures_not_drawn")  # the scores and the warning are the answer
def test_frames_a_backend_crashed_on_are_counted_and_reported(
    rendered_pair, tmp_path, monkeypatch, capsys
) -> None:
    """Two planted crashes in the first sample scored (the no-branch twin): its row counts
    them, the others none, and ``whiskerbench score`` says so on stderr, naming the backend."""
    import pipeline.track
    from bench.cli.main import main

    detect, calls = pipeline.track.detect_markers, []

    def crashing(*args, **kwargs):
        calls.append(None)
        if len(calls) in (21, 24):  # frames 20 and 23 of the first sample
            raise BackendCrashError("detector opencv crashed (signal 6)")
        return detect(*args, **kwargs)

    monkeypatch.setattr(pipeline.track, "detect_markers", crashing)
    out = tmp_path / "scores"
    assert main(["score", str(rendered_pair), "--out", str(out)]) == 0
    table = pd.read_csv(out / "samples.csv").set_index("branches")
    assert table.loc["none", "failed_frames"] == 2 and table.loc["100", "failed_frames"] == 0
    assert json.loads(table.loc["none", "failed_frame_ids"]) == [20, 23]
    assert np.isnan(table.loc["none", "own_rot_err_deg"])  # opencv has no pose of its own
    warnings = [line for line in capsys.readouterr().err.splitlines() if "crashed" in line]
    sample = table.loc["none", "sample_id"]
    assert warnings == [
        f"warning: {sample}: detector opencv crashed on 2 frames (20, 23); they have no detections"
    ]


@pytest.mark.slow
@pytest.mark.skipif(not available("locus"), reason="locus-tag not installed (the peers extra)")
def test_locus_own_pose_is_scored_on_a_render(rendered_pair, tmp_path_factory, worker_id) -> None:
    from test_compare import peer_compare

    # score_dataset's table of locus on the pair, in the compare of fast and locus that
    # test_compare's peer test reads: scored once for both
    folder, _ = peer_compare(tmp_path_factory, worker_id, rendered_pair)
    table = pd.read_csv(folder / "data" / "scores" / "locus" / "samples.csv")
    assert (table["failed_frames"] == 0).all() and (table["recall"] > 0.9).all()
    for column in ("own_rot_err_deg", "own_trans_err_mm", "rot_err_deg", "trans_err_mm"):
        assert np.isfinite(table[column]).all(), column
    # the project's fisheye pose beats a pinhole's on the fisheye
    assert (table["trans_err_mm"] < table["own_trans_err_mm"]).all()


@pytest.mark.parametrize("command", ["score", "detect"])
def test_a_missing_peer_is_refused_in_one_line_saying_how_to_install(
    tmp_path, monkeypatch, capsys, command
) -> None:
    import pipeline.backends.locus
    from bench.cli.main import main
    from pipeline.backends import PEERS_INSTALL, missing_library

    def load():
        raise missing_library("locus", "locus-tag")

    monkeypatch.setattr(pipeline.backends.locus, "load", load)
    video = tmp_path / "video.mp4"
    video.write_bytes(b"never read")
    where = [str(video), "--camera", "ideal"] if command == "detect" else [str(tmp_path)]
    assert main([command, *where, "--pipeline", "locus", "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and PEERS_INSTALL in err
    assert err.startswith(f"whiskerbench {command}: error: --pipeline locus: detector locus")
    assert not (tmp_path / "o").exists()
