"""Tracking a video: rows for the array's markers, poses against labels, foreign ids counted."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from pipeline.detect import DetectorConfig
from pipeline.track import MarkerSet, pose_arrays, track
from scenes.camera import default_camera


def test_pose_arrays_places_rows_and_leaves_nan_where_unseen() -> None:
    table = pd.DataFrame(
        {
            "frame": [0, 2],
            "whisker": [1, 0],
            **{f"R_CM_{i}{j}": [float(i == j)] * 2 for i in range(3) for j in range(3)},
            "t_CM_x_mm": [1.0, 4.0],
            "t_CM_y_mm": [2.0, 5.0],
            "t_CM_z_mm": [3.0, 6.0],
        }
    )
    R, t = pose_arrays(table, n_frames=3, n_whiskers=2)
    np.testing.assert_array_equal(t[0, 1], [1, 2, 3])
    np.testing.assert_array_equal(t[2, 0], [4, 5, 6])
    assert np.isnan(t[1]).all() and np.isnan(R[0, 0]).all()
    np.testing.assert_array_equal(R[2, 0], np.eye(3))


def test_marker_set_rejects_duplicates() -> None:
    with pytest.raises(ValueError, match="distinct"):
        MarkerSet((1, 1), 13.2)


def test_tracking_a_rendered_sample_matches_its_labels(variant) -> None:
    if variant.startswith("scalar"):
        pytest.skip("frame rendering needs a JIT variant")
    from bench.dataset import DatasetConfig, SampleFrames, simulate_sample

    config = DatasetConfig(
        foliage=("soft",),
        distances=("intermediate",),
        branches=((0.0,),),
        protocols=("outdoor",),
        lightings=("lab",),
        passes=1,
        frames_step=10,
    )
    sample = config.samples()[0]
    sim = simulate_sample(config, sample)
    frames = SampleFrames(config, sample, sim)
    images = (frames.frame(f) for f in range(len(sim.times_s)))
    markers = MarkerSet(config.array.marker_ids, config.array.marker_size_mm)
    result = track(images, default_camera(), markers, DetectorConfig(corner_refinement="lines"))
    assert result.frames == len(sim.times_s) and result.foreign_ids == 0
    joined = result.detections.merge(sim.labels, on=["frame", "marker_id"], suffixes=("", "_gt"))
    assert len(joined) >= 0.98 * sim.labels["visible"].sum()
    err = np.hypot(
        *(joined[f"t_CM_{a}_mm"] - joined[f"t_CM_{a}_mm_gt"] for a in "xy")
    )  # lateral position error of the pose, mm
    assert np.median(err) < 0.2
