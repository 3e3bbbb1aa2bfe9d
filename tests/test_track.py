"""Tracking a video: rows for the array's markers, poses against labels, foreign ids counted,
a backend's own pose beside the project's, a backend's crash costing its frame only."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from test_tables import SPEC, frame_with_marker

from pipeline.backends import BACKENDS, Backend, available
from pipeline.backends.isolated import stop_workers
from pipeline.detect import DetectorConfig
from pipeline.track import MarkerSet, Search, pose_arrays, recovery_detector, track
from scenes.camera import default_camera
from scenes.tables import (
    JOIN_KEY,
    OWN_POSE_PREFIX,
    TRUTH_SUFFIX,
    corners_of,
    pose_values,
    rotations_of,
    translations_of,
)

ROOT = Path(__file__).resolve().parents[1]
MARKERS = MarkerSet(SPEC.marker_ids, SPEC.marker_size_mm)


def test_pose_arrays_places_rows_and_leaves_nan_where_unseen() -> None:
    T = np.tile(np.eye(4), (2, 1, 1))
    T[:, :3, 3] = [[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]
    table = pd.DataFrame({"frame": [0, 2], "whisker": [1, 0], **pose_values(T)})
    R, t = pose_arrays(table, n_frames=3, n_whiskers=2)
    np.testing.assert_array_equal(t[0, 1], [1, 2, 3])
    np.testing.assert_array_equal(t[2, 0], [4, 5, 6])
    assert np.isnan(t[1]).all() and np.isnan(R[0, 0]).all()
    np.testing.assert_array_equal(R[2, 0], np.eye(3))


def test_marker_set_rejects_duplicates() -> None:
    with pytest.raises(ValueError, match="distinct"):
        MarkerSet((1, 1), 13.2)


@pytest.fixture(scope="module")
def rendered(variant, pair_config):
    """A short rendered sample (the pair's setting, ideal camera, a branch at 0 mm, every 6th
    frame): (frames, labels, camera, markers)."""
    if variant.startswith("scalar"):
        pytest.skip("frame rendering needs a JIT variant")
    import dataclasses

    from bench.dataset.sample import sample_recorder, simulate_sample

    config = dataclasses.replace(pair_config, branches=((0.0,),), frames_step=6)
    sample = config.samples()[0]
    sim = simulate_sample(config, sample)
    frames = sample_recorder(config, sample, sim)
    images = [frames.frame(f) for f in range(len(sim.times_s))]
    markers = MarkerSet(config.array.marker_ids, config.array.marker_size_mm)
    return images, sim.labels, default_camera(), markers


@pytest.mark.slow
def test_tracking_a_rendered_sample_matches_its_labels(rendered) -> None:
    images, labels, camera, markers = rendered
    result = track(images, camera, markers, DetectorConfig(corner_refinement="lines"))
    assert result.frames == len(images) and result.foreign_ids == 0
    joined = result.detections.merge(labels, on=list(JOIN_KEY), suffixes=("", TRUTH_SUFFIX))
    assert len(joined) >= 0.98 * labels["visible"].sum()
    t, t_gt = translations_of(joined), translations_of(joined, TRUTH_SUFFIX)
    err = np.hypot(*(t - t_gt)[:, :2].T)
    assert np.median(err) < 0.2  # lateral position of the pose, mm


@pytest.mark.slow
def test_roi_tracking_finds_what_full_frame_search_finds(rendered) -> None:
    images, _, camera, markers = rendered
    detector = DetectorConfig(corner_refinement="subpix")
    full = track(images, camera, markers, detector).detections
    roi = track(images, camera, markers, detector, Search("roi")).detections
    assert abs(len(roi) - len(full)) <= 0.01 * len(full)
    both = full.merge(roi, on=list(JOIN_KEY), suffixes=("", "_roi"))
    diff = np.abs(corners_of(both)[:, 0, 0] - corners_of(both, "_roi")[:, 0, 0])
    assert len(both) >= 0.99 * len(full) and np.median(diff) < 0.01


def test_search_rejects_unknown_mode() -> None:
    with pytest.raises(ValueError, match="choose from"):
        Search("everywhere")


# -- backends: own poses and crashes ----------------------------------------------------------


def test_opencv_has_no_own_pose_and_nothing_fell_back() -> None:
    frame = frame_with_marker(SPEC.marker_ids[2])
    result = track([frame], default_camera(), MARKERS, DetectorConfig())
    table = result.detections
    assert len(table) == 1 and np.isfinite(translations_of(table)).all()
    assert np.isnan(translations_of(table, prefix=OWN_POSE_PREFIX)).all()
    assert np.isnan(rotations_of(table, prefix=OWN_POSE_PREFIX)).all()
    assert not table["refine_failed"].any() and not result.refine_failures
    assert result.failed_frames == []


@pytest.mark.skipif(not available("locus"), reason="locus-tag not installed (the peers extra)")
def test_locus_reports_its_own_pose_beside_the_projects() -> None:
    """A marker facing the camera near the image centre: locus' pinhole pose agrees with the
    project's fisheye pose to within the lens' difference there (a few mm, a few degrees).
    Moved off the optical axis: there every pose method finds a half-turned pose."""
    frame = np.roll(frame_with_marker(SPEC.marker_ids[4]), (37, 53), axis=(0, 1))
    detector = DetectorConfig(backend="locus", corner_refinement="none")
    table = track([frame], default_camera(), MARKERS, detector).detections
    assert len(table) == 1
    own_t = translations_of(table, prefix=OWN_POSE_PREFIX)[0]
    own_R = rotations_of(table, prefix=OWN_POSE_PREFIX)[0]
    assert np.isfinite(own_t).all() and np.isfinite(own_R).all()
    np.testing.assert_allclose(own_R @ own_R.T, np.eye(3), atol=1e-6)
    t = translations_of(table)[0]
    assert np.linalg.norm(own_t - t) < 0.1 * np.linalg.norm(t)
    cos = (np.trace(own_R.T @ rotations_of(table)[0]) - 1) / 2
    assert np.degrees(np.arccos(np.clip(cos, -1, 1))) < 10


@pytest.fixture
def crashing(monkeypatch):
    """A peer that aborts its worker process on an all-black image (tests/crashing_backend.py)."""
    from crashing_backend import MODULE

    monkeypatch.syspath_prepend(str(ROOT))  # the parent imports it by the worker's name too
    row = Backend("crashing", MODULE, ("4x4_50",), "test", own_pose=False, isolated=True)
    monkeypatch.setitem(BACKENDS, row.name, row)
    yield DetectorConfig(backend=row.name, corner_refinement="none")
    stop_workers()


@pytest.mark.slow  # over a second of CPU: out of `make test-fast`
def test_a_backend_crash_costs_its_frame_and_the_run_goes_on(crashing) -> None:
    marked = frame_with_marker(SPEC.marker_ids[5])
    black = np.zeros_like(marked)
    frames = [marked, black, marked, black, marked]
    result = track(frames, default_camera(), MARKERS, crashing)
    assert result.frames == 5 and result.failed_frames == [1, 3]
    assert result.detections["frame"].tolist() == [0, 2, 4]
    assert set(result.detections["whisker"]) == {5}
    roi = track(frames, default_camera(), MARKERS, crashing, Search("roi"))
    assert roi.failed_frames == [1, 3] and roi.detections["frame"].tolist() == [0, 2, 4]


def test_a_marker_found_twice_in_a_frame_counts_once(monkeypatch) -> None:
    """A backend that reports one marker twice (AprilTag 3 does on some frames): one row, the
    second a false detection, so recall cannot pass 1."""
    import pipeline.track as track_module

    frame = frame_with_marker(SPEC.marker_ids[2])
    once = track_module.detect_markers(frame, DetectorConfig(), camera=default_camera())
    assert len(once) == 1
    monkeypatch.setattr(track_module, "detect_markers", lambda *a, **k: once + once)
    result = track([frame], default_camera(), MARKERS, DetectorConfig())
    assert len(result.detections) == 1 and result.foreign_ids == 1


def test_a_lost_marker_is_looked_for_again_by_the_recovery_backend(monkeypatch) -> None:
    """The detector loses the marker on the second frame; ``recover`` finds it again in its box
    of the first frame, and only there (no recovery: one row)."""
    import pipeline.track as track_module

    frame = frame_with_marker(SPEC.marker_ids[2])
    real = track_module._detect
    calls: list[tuple[str, tuple]] = []

    def flaky(frame_, box, detector, camera, markers):
        calls.append((detector.backend, box))
        if box == default_camera().image_circle_box() and len(calls) > 1:
            return []  # the main (full-frame) search misses the marker from the second frame on
        return real(frame_, box, detector, camera, markers)

    monkeypatch.setattr(track_module, "_detect", flaky)
    lone = track([frame, frame], default_camera(), MARKERS, DetectorConfig())
    assert lone.detections["frame"].tolist() == [0]
    calls.clear()
    search = Search("full", recover="opencv")
    again = track([frame, frame], default_camera(), MARKERS, DetectorConfig(), search)
    assert again.detections["frame"].tolist() == [0, 1]
    first_corners = corners_of(again.detections)[0]
    (x0, y0, x1, y1) = calls[-1][1]  # the recovery's box: around the first frame's corners
    assert x1 - x0 < 300 and (first_corners >= [x0, y0]).all() and (first_corners < [x1, y1]).all()
    assert recovery_detector(DetectorConfig(), "opencv").corner_refinement == "subpix"
    assert (
        recovery_detector(DetectorConfig(corner_refinement="lines"), "locus").corner_refinement
        == "lines"
    )
    assert recovery_detector(DetectorConfig(), "none") is None
