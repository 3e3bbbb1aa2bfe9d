"""Exact per-frame, per-marker ground truth of a sample: the rows of ``labels.parquet``.

Everything is computed from the same numbers the renderer used (the array spec, the camera
model and the simulated deflection angles at the frame's timestamp, the middle of its exposure),
so the labels are exact, not measured. The columns are :data:`scenes.tables.LABELS`: the
detections' corners and pose T_cam_marker, plus the marker's displacement T_marker0_marker from
its no-contact pose, deflection (SPEC 3), angles, contact flags and visibility (all four corners
inside the image and the face turned towards the camera).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from scenes.array import ArraySpec, T_cam_marker, T_marker0_marker
from scenes.camera import FisheyeCamera
from scenes.conventions import marker_corners_marker
from scenes.tables import (
    LABELS,
    corner_values,
    corners_of,
    displacement_values,
    ordered,
    pose_values,
)


def corners_px(camera: FisheyeCamera, spec: ArraySpec, T_cam_marker_: np.ndarray) -> np.ndarray:
    """(..., 4, 2) projected marker corners for (..., 4, 4) marker poses."""
    local = marker_corners_marker(spec.marker_size_mm)
    R, t = T_cam_marker_[..., :3, :3], T_cam_marker_[..., :3, 3]
    points = np.einsum("...ij,kj->...ki", R, local) + t[..., None, :]
    return camera.project(points)


def visible(camera: FisheyeCamera, corners: np.ndarray, T_cam_marker_: np.ndarray) -> np.ndarray:
    """(...,) bool: every corner inside the image and the printed face towards the camera."""
    w, h = camera.width_px, camera.height_px
    x, y = corners[..., 0], corners[..., 1]
    inside = (x >= -0.5) & (x <= w - 0.5) & (y >= -0.5) & (y <= h - 0.5)
    inside = np.where(np.isnan(x) | np.isnan(y), False, inside).all(axis=-1)
    normal = T_cam_marker_[..., :3, 2]
    facing = np.einsum("...i,...i->...", normal, -T_cam_marker_[..., :3, 3]) > 0
    return inside & facing


def label_table(
    camera: FisheyeCamera,
    spec: ArraySpec,
    angles_rad: np.ndarray,
    contact: np.ndarray,
    branch_contact: np.ndarray,
    times_s: np.ndarray,
    source_frames: np.ndarray,
) -> pd.DataFrame:
    """One row per frame and marker from (F, n, 2) angles and (F, n) contact flags."""
    n_frames, n = angles_rad.shape[:2]
    T = T_cam_marker(spec, angles_rad)  # (F, n, 4, 4)
    corners = corners_px(camera, spec, T)
    t_marker0_marker = T_marker0_marker(spec, angles_rad)[..., :3, 3]
    values = {
        "frame": np.repeat(np.arange(n_frames), n),
        "source_frame": np.repeat(np.asarray(source_frames), n),
        "time_s": np.repeat(np.asarray(times_s, dtype=float), n),
        "marker_id": np.tile(np.asarray(spec.marker_ids), n_frames),
        "whisker": np.tile(np.arange(n), n_frames),
        **corner_values(corners),
        **pose_values(T),
        **displacement_values(t_marker0_marker),
        "deflection_mm": np.hypot(t_marker0_marker[..., 0], t_marker0_marker[..., 1]),
        "theta_h_rad": angles_rad[..., 0],
        "theta_v_rad": angles_rad[..., 1],
        "contact": np.asarray(contact, bool),
        "branch_contact": np.asarray(branch_contact, bool),
        "visible": visible(camera, corners, T),
    }
    return pd.DataFrame(ordered(LABELS, values))


def corners_of_frame(labels: pd.DataFrame, frame: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(corners (n, 4, 2), marker ids (n,), visible (n,)) of one frame of a label table."""
    rows = labels[labels["frame"] == frame]
    return corners_of(rows), rows["marker_id"].to_numpy(), rows["visible"].to_numpy()
