"""Per-frame marker detection and pose over a video: the table the branch estimation reads.

One row per frame and detected marker of the array (ids not on the array are dropped and
counted): ``frame``, ``marker_id``, ``whisker``, ``c{0..3}_{x,y}_px`` (ArUco order),
``R_CM_{ij}``, ``t_CM_{x,y,z}_mm`` (T_cam_marker), ``reprojection_err_px``,
``ambiguity_ratio``. The column names match :mod:`bench.labels`, so detections and ground truth
join on (frame, marker_id).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np
import pandas as pd

from pipeline.detect import DetectorConfig, detect_markers
from pipeline.pose import estimate_pose
from scenes.camera import FisheyeCamera


@dataclass(frozen=True)
class MarkerSet:
    """What the pipeline knows of the array: marker ids in whisker order, and their size."""

    marker_ids: tuple[int, ...]
    size_mm: float

    def __post_init__(self) -> None:
        if len(set(self.marker_ids)) != len(self.marker_ids) or not self.marker_ids:
            raise ValueError(f"marker_ids={self.marker_ids}: need distinct ids")
        if not self.size_mm > 0:
            raise ValueError(f"size_mm={self.size_mm}: must be > 0")


@dataclass
class TrackResult:
    detections: pd.DataFrame
    frames: int
    foreign_ids: int  # detections with an id that is not on the array (false detections)
    pose_failures: int


def track(
    frames: Iterable[np.ndarray],
    camera: FisheyeCamera,
    markers: MarkerSet,
    detector: DetectorConfig,
) -> TrackResult:
    """Detect the array's markers and estimate their poses in every frame."""
    whisker_of = {m: i for i, m in enumerate(markers.marker_ids)}
    rows: list[dict] = []
    foreign = failures = n_frames = 0
    for f, frame in enumerate(frames):
        n_frames += 1
        for det in detect_markers(frame, detector, camera=camera):
            if det.marker_id not in whisker_of:
                foreign += 1
                continue
            try:
                pose = estimate_pose(det.corners_px, markers.size_mm, camera)
            except ValueError:
                failures += 1
                continue
            rows.append(_row(f, det.marker_id, whisker_of[det.marker_id], det.corners_px, pose))
    return TrackResult(_table(rows), n_frames, foreign, failures)


def _row(frame: int, marker_id: int, whisker: int, corners: np.ndarray, pose) -> dict:
    row = {"frame": frame, "marker_id": marker_id, "whisker": whisker}
    for k in range(4):
        row[f"c{k}_x_px"], row[f"c{k}_y_px"] = corners[k]
    T = pose.T_cam_marker
    for i in range(3):
        for j in range(3):
            row[f"R_CM_{i}{j}"] = T[i, j]
    for i, axis in enumerate("xyz"):
        row[f"t_CM_{axis}_mm"] = T[i, 3]
    row["reprojection_err_px"] = pose.reprojection_err_px
    row["ambiguity_ratio"] = pose.ambiguity_ratio
    return row


COLUMNS = (
    ["frame", "marker_id", "whisker"]
    + [f"c{k}_{a}_px" for k in range(4) for a in "xy"]
    + [f"R_CM_{i}{j}" for i in range(3) for j in range(3)]
    + [f"t_CM_{a}_mm" for a in "xyz"]
    + ["reprojection_err_px", "ambiguity_ratio"]
)


def _table(rows: list[dict]) -> pd.DataFrame:
    return pd.DataFrame(rows, columns=COLUMNS)


def pose_arrays(table: pd.DataFrame, n_frames: int, n_whiskers: int):
    """(R_CM (F, n, 3, 3), t_CM (F, n, 3)) from a detections or labels table; NaN where unseen."""
    R = np.full((n_frames, n_whiskers, 3, 3), np.nan)
    t = np.full((n_frames, n_whiskers, 3), np.nan)
    f = table["frame"].to_numpy()
    w = table["whisker"].to_numpy()
    R[f, w] = (
        table[[f"R_CM_{i}{j}" for i in range(3) for j in range(3)]].to_numpy().reshape(-1, 3, 3)
    )
    t[f, w] = table[[f"t_CM_{a}_mm" for a in "xyz"]].to_numpy()
    return R, t
