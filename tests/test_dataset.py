"""Dataset generation end to end: files, labels against pixels, resume, determinism, bad options."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pandas as pd
import pytest

from bench.dataset import DatasetConfig, DatasetConfigError, SampleSpec, simulate_sample
from bench.labels import corners_of_frame

SMALL = {
    "foliage": ("soft",),
    "distances": ("intermediate",),
    "branches": ((0.0,),),
    "protocols": ("outdoor",),
    "lightings": ("lab",),
    "passes": 1,
    "frames_step": 2,
}


@pytest.fixture(scope="module")
def dataset(tmp_path_factory, variant):
    if variant.startswith("scalar"):
        pytest.skip("frame rendering needs a JIT variant")
    from bench.generate import run_dataset

    out = tmp_path_factory.mktemp("data")
    config = DatasetConfig(**SMALL)
    manifest = run_dataset(config, out, variant=variant, progress=False)
    return config, out, manifest


def test_sample_files_and_manifest(dataset) -> None:
    from bench.dataset import sha256
    from bench.video import video_info

    config, out, manifest = dataset
    sample = config.samples()[0]
    folder = out / sample.sample_id
    record = json.loads((folder / "sample.json").read_text())
    labels = pd.read_parquet(folder / "labels.parquet")
    info = video_info(folder / "video.mp4")
    assert info.frame_count == labels["frame"].nunique() == record["frames"]
    assert (info.width, info.height, info.fps) == (2592, 1944, 15.0)
    assert video_info(folder / "preview.mp4").frame_count == record["frames"]
    assert len(labels) == 13 * record["frames"]
    assert record["branch_gaps"] == [[6, 7]] and record["branches_mm"] == [0.0]
    for name, digest in record["files"].items():
        assert sha256(folder / name) == digest == manifest["files"][f"{sample.sample_id}/{name}"]
    camera = json.loads((folder / "camera.json").read_text())
    assert set(camera) >= {"model", "opencv_fisheye"}
    assert manifest["variant"] and manifest["frames_per_s"] > 0


def test_markers_are_detected_where_the_labels_say(dataset) -> None:
    """Median corner error <= 0.3 px on the decoded video, lab lighting, sub-pixel refinement."""
    from bench.video import read_video
    from pipeline.detect import DetectorConfig, detect_markers

    config, out, _ = dataset
    folder = out / config.samples()[0].sample_id
    labels = pd.read_parquet(folder / "labels.parquet")
    detector = DetectorConfig(corner_refinement="lines")
    errors, found, expected = [], 0, 0
    for f, frame in enumerate(read_video(folder / "video.mp4")):
        if f % 4:
            continue
        corners, ids, visible = corners_of_frame(labels, f)
        got = {
            d.marker_id: d.corners_px for d in detect_markers(frame, detector, camera=config.camera)
        }
        assert set(got) <= set(ids.tolist())  # no wrong ids
        expected += int(visible.sum())
        for i, marker_id in enumerate(ids):
            if marker_id in got:
                found += 1
                errors.append(np.linalg.norm(got[marker_id] - corners[i], axis=1))
    assert found >= 0.98 * expected
    assert np.median(np.concatenate(errors)) <= 0.3


def test_lead_in_has_no_contact_and_zero_deflection(dataset) -> None:
    config, out, _ = dataset
    labels = pd.read_parquet(out / config.samples()[0].sample_id / "labels.parquet")
    lead = labels[labels["time_s"] < config.motion("outdoor").lead_in_s]
    assert len(lead) >= 13 * 3
    assert (lead["deflection_mm"] == 0).all() and not lead["contact"].any()
    assert labels["deflection_mm"].max() > 2.0  # the branch does deflect a whisker later


def test_rerun_skips_verified_samples_and_redoes_broken_ones(dataset) -> None:
    from bench.generate import run_dataset

    config, out, manifest = dataset
    again = run_dataset(config, out, progress=False)
    assert again["skipped"] == 1 and again["frames_rendered"] == 0
    assert again["files"] == manifest["files"]
    other = DatasetConfig(**{**SMALL, "exposure_ms": 4.0})
    with pytest.raises(DatasetConfigError, match="other settings"):
        run_dataset(other, out, progress=False)


def test_same_seed_same_labels_other_seed_other_foliage() -> None:
    config = DatasetConfig(**SMALL)
    sample = config.samples()[0]
    a = simulate_sample(config, sample).labels
    b = simulate_sample(config, sample).labels
    pd.testing.assert_frame_equal(a, b)
    c = simulate_sample(DatasetConfig(**{**SMALL, "seed": 1}), sample).labels
    assert not np.allclose(a["deflection_mm"], c["deflection_mm"])


def test_sample_ids_are_unique_over_the_default_grid() -> None:
    samples = DatasetConfig().samples()
    assert len(samples) == 4 * 3 * 7 * 2
    assert len({s.sample_id for s in samples}) == len(samples)
    assert SampleSpec("soft", "far", (0.0, 50.0), "indoor", "sun").sample_id == (
        "soft-far-0+50-indoor-sun"
    )


@pytest.mark.parametrize(
    ("args", "option"),
    [
        (["--foliage", "moss"], "--foliage"),
        (["--speed", "-4"], "--speed"),
        (["--branches", "400"], "--branches"),
        (["--distance", "touching"], "--distance"),
        (["--out", "/proc/whiskerbench/x"], "--out"),
    ],
)
def test_bad_options_one_line_exit_2_nothing_written(tmp_path, args, option) -> None:
    out = tmp_path / "never"
    cmd = [sys.executable, "-m", "bench.cli", "dataset", "--quick"]
    if "--out" not in args:
        cmd += ["--out", str(out)]
    proc = subprocess.run(cmd + args, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and option in lines[0]
    assert not out.exists()


def test_vignetting_darkens_the_frame_edges(variant) -> None:
    """The per-pixel ray angle reaches the camera response (computed once per window)."""
    if variant.startswith("scalar"):
        pytest.skip("frame rendering needs a JIT variant")
    import dataclasses

    from bench.dataset import SampleFrames
    from renderers.response import CameraResponse

    plain = DatasetConfig(**SMALL)
    vignetted = dataclasses.replace(plain, response=CameraResponse(vignetting=0.6, read_noise_e=0))
    sample = plain.samples()[0]
    sim = simulate_sample(plain, sample)
    a = SampleFrames(plain, sample, sim).frame(0).astype(float)
    b = SampleFrames(vignetted, sample, sim).frame(0).astype(float)
    row = 971
    centre, edge = slice(1200, 1400), slice(400, 600)
    assert b[row, centre].mean() == pytest.approx(a[row, centre].mean(), rel=0.1)
    assert b[row, edge].mean() < 0.85 * a[row, edge].mean()
