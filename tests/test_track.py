"""Tracking a video: rows for the array's markers, poses against labels, foreign ids counted."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from pipeline.detect import DetectorConfig
from pipeline.track import MarkerSet, Search, pose_arrays, track
from scenes.camera import default_camera
from scenes.profile import load_profile
from scenes.tables import JOIN_KEY, TRUTH_SUFFIX, corners_of, pose_values, translations_of


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
def rendered(variant):
    """A short rendered sample: (frames, labels, camera, markers)."""
    if variant.startswith("scalar"):
        pytest.skip("frame rendering needs a JIT variant")
    from bench.dataset.config import DatasetConfig
    from bench.dataset.sample import sample_recorder, simulate_sample

    config = DatasetConfig(
        camera=load_profile("ideal"),  # pipeline tests on exact pixels, not the twin
        foliage=("soft",),
        distances=("intermediate",),
        branches=((0.0,),),
        protocols=("outdoor",),
        lightings=("lab",),
        passes=1,
        frames_step=6,
    )
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
