"""The stages after detection, run on another tool's detections (``score --detections``).

:func:`run_external` takes one sample's validated rows of a results file
(:mod:`bench.evaluate.results_file`) where :func:`bench.evaluate.detect.run_detect` would run a
detector: ids not on the array are false detections (as the tracker counts them), the pose is
the file's where it has one, else the pipeline's pose method on the file's corners, then
deflection, contact and branches as in ``detect``. It writes the same ``detections.parquet``,
``branches.json`` and ``branches.png``, and returns branches.json's content.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from bench.common.manifest import RunClock
from bench.common.run_folder import claim
from bench.evaluate.detect import write_estimate
from bench.evaluate.results_file import CORNERS, POSE
from pipeline.deflection import NoBaselineError
from pipeline.pose import estimate_pose
from pipeline.presets import PipelineConfig
from scenes.array import ArraySpec
from scenes.camera import FisheyeCamera
from scenes.tables import OWN_POSE_PREFIX, TRACK, corners_of, ordered, pose_values


def track_table(
    rows: pd.DataFrame, camera: FisheyeCamera, array: ArraySpec, pose_method: str
) -> tuple[pd.DataFrame, int, int]:
    """(a :data:`scenes.tables.TRACK` table, false detections, pose failures) of the rows."""
    whisker_of = {m: i for i, m in enumerate(array.marker_ids)}
    on = rows["marker_id"].isin(list(whisker_of)).to_numpy()
    rows = rows[on].reset_index(drop=True)
    corners = corners_of(rows)
    n = len(rows)
    if POSE[0] in rows:
        pose = {name: rows[name].to_numpy(float) for name in POSE}
        error = np.full(n, np.nan)  # the file's pose: no reprojection error of ours
        kept = np.ones(n, bool)
    else:
        T = np.full((n, 4, 4), np.nan)
        error = np.full(n, np.nan)
        kept = np.zeros(n, bool)
        for k in range(n):
            try:
                est = estimate_pose(corners[k], array.marker_size_mm, camera, pose_method)
            except ValueError:  # as track(): a pose failure drops the detection
                continue
            T[k], error[k], kept[k] = est.T_cam_marker, est.reprojection_err_px, True
        pose = pose_values(T)
    values = {
        "frame": rows["frame"].to_numpy(),
        "marker_id": rows["marker_id"].to_numpy(),
        "whisker": rows["marker_id"].map(whisker_of).to_numpy(),
        **{name: rows[name].to_numpy(float) for name in CORNERS},
        **pose,
        "reprojection_err_px": error,
        "ambiguity_ratio": np.full(n, np.nan),
        **pose_values(np.full((n, 4, 4), np.nan), OWN_POSE_PREFIX),
        "refine_failed": np.zeros(n, bool),
    }
    table = pd.DataFrame(ordered(TRACK, values))[kept].reset_index(drop=True)
    return table, int((~on).sum()), int((~kept).sum())


def run_external(
    rows: pd.DataFrame,
    camera: FisheyeCamera,
    config: PipelineConfig,
    out_dir: Path,
    n_frames: int,
    threshold_mm: float | None = None,
    array: ArraySpec | None = None,
    frames_per_s: float | None = None,
    truth: list[list[int]] | None = None,
) -> dict:
    """The stages after detection on ``rows``; outputs as ``detect``'s (the module docstring).

    ``out_dir`` is claimed before any work (ValueError if another command's). Raises
    NoBaselineError where the sample has no no-contact frames, as ``detect`` does.
    """
    out_dir = Path(out_dir)
    clock = RunClock()
    claim(out_dir, "detect")
    array = array or ArraySpec()
    tracked, foreign, failures = track_table(rows, camera, array, config.pose_method)
    if tracked.empty:  # nothing found: no rest pose to measure from (a refused sample)
        raise NoBaselineError("the results hold no marker of the array with a pose, in any frame")
    facts = {
        "frames_per_s": frames_per_s,  # None: the results carry no timing (accuracy only)
        "foreign_ids": foreign,
        "pose_failures": failures,
        "detector": "external",
        "failed_frames": [],
        "refine_failures": {},
    }
    return write_estimate(
        out_dir, clock, tracked, n_frames, camera, config, array, threshold_mm, truth,
        out_dir.name, facts,
    )  # fmt: skip
