"""``whiskerbench detect`` end to end on a rendered sample, every preset, and bad input."""

from __future__ import annotations

import json
import subprocess
import sys

import pandas as pd
import pytest

from pipeline.presets import PRESETS


@pytest.fixture(scope="module")
def sample_video(tmp_path_factory, variant):
    """A rendered sample with a branch at 100 mm (between whiskers 8 and 9), and its
    no-branch twin beside it."""
    if variant.startswith("scalar"):
        pytest.skip("frame rendering needs a JIT variant")
    from bench.dataset import DatasetConfig
    from bench.generate import run_dataset

    config = DatasetConfig(
        foliage=("soft",),
        distances=("intermediate",),
        branches=((), (100.0,)),
        protocols=("outdoor",),
        lightings=("lab",),
        passes=1,
    )
    out = tmp_path_factory.mktemp("detect")
    run_dataset(config, out, variant=variant, progress=False)
    return out / config.samples()[1].sample_id


@pytest.mark.parametrize("name", list(PRESETS))
def test_every_preset_runs_and_paper_finds_the_branch(sample_video, tmp_path, name) -> None:
    from bench.detect import run_detect
    from scenes.camera import FisheyeCamera

    camera = FisheyeCamera.from_dict(json.loads((sample_video / "camera.json").read_text()))
    record = run_detect(sample_video / "video.mp4", camera, PRESETS[name], tmp_path)
    assert record["true_gaps"] == [[8, 9]]
    assert (tmp_path / "branches.png").stat().st_size > 1000
    table = pd.read_parquet(tmp_path / "detections.parquet")
    assert {"deflection_mm", "contact", "t_CM_x_mm", "c0_x_px"} <= set(table.columns)
    assert record["frames"] == table["frame"].max() + 1
    if name == "paper":
        gaps = [b["gap"] for b in record["branches"]]
        assert len(gaps) == 1 and abs(gaps[0][0] - 8) <= 1


def _run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "bench.cli", "detect", *args],
        capture_output=True,
        text=True,
        timeout=120,
    )


def test_unreadable_video_and_bad_camera_one_line_exit_2(tmp_path) -> None:
    camera = tmp_path / "camera.json"
    from scenes.camera import default_camera

    camera.write_text(json.dumps(default_camera().to_dict()))
    video = tmp_path / "v.mp4"
    video.write_bytes(b"\x00not a video" * 100)
    bad = _run(str(video), "--camera", str(camera), "--out", str(tmp_path / "o"))
    assert bad.returncode == 2 and len(bad.stderr.strip().splitlines()) == 1
    assert "not a readable video" in bad.stderr and not (tmp_path / "o").exists()
    (tmp_path / "c.json").write_text("{}")
    worse = _run(str(video), "--camera", str(tmp_path / "c.json"))
    assert worse.returncode == 2 and "--camera" in worse.stderr
    assert len(worse.stderr.strip().splitlines()) == 1


def test_score_dataset_uses_the_twin_threshold_and_scores_every_sample(sample_video, tmp_path):
    from bench.score import score_dataset

    table = score_dataset(sample_video.parent, PRESETS["paper"], tmp_path)
    assert len(table) == 2 and (tmp_path / "samples.csv").exists()
    assert (tmp_path / "grid-outdoor-lab.png").stat().st_size > 1000
    branch = table[table["branches"] == "100"].iloc[0]
    assert branch["threshold_source"] == "none-sample twin"
    assert branch["outcome"] == "correct" and branch["recall"] > 0.98
    assert table[table["branches"] == "none"].iloc[0]["false_positives"] == 0
