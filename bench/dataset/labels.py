"""Exact per-frame, per-marker ground truth of a sample: the rows of ``labels.parquet``.

Everything is computed from the same numbers the renderer used (the array spec, the camera
model and the simulated deflection angles at the frame's timestamp, the middle of its exposure),
so the labels are exact, not measured. Columns:

``frame`` (index in the video), ``source_frame`` (index at the protocol's full frame rate),
``time_s``, ``marker_id``, ``whisker``, ``c{0..3}_{x,y}_px`` (corners in ArUco order, pixel
convention of :mod:`scenes.conventions`), ``R_CM_{ij}`` and ``t_CM_{x,y,z}_mm`` (T_cam_marker),
``t_M0M_{x,y,z}_mm`` (marker translation in its no-contact frame), ``deflection_mm``
(sqrt(x^2 + y^2) of it, SPEC 3), ``theta_h_rad``, ``theta_v_rad``, ``contact``,
``branch_contact``, ``visible`` (all four corners inside the image and the face turned towards
the camera).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from scenes.array import ArraySpec, T_cam_marker, T_marker0_marker
from scenes.camera import FisheyeCamera
from scenes.conventions import marker_corners_marker


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
    t_M0M = T_marker0_marker(spec, angles_rad)[..., :3, 3]
    cols: dict[str, np.ndarray] = {
        "frame": np.repeat(np.arange(n_frames), n),
        "source_frame": np.repeat(np.asarray(source_frames), n),
        "time_s": np.repeat(np.asarray(times_s, dtype=float), n),
        "marker_id": np.tile(np.asarray(spec.marker_ids), n_frames),
        "whisker": np.tile(np.arange(n), n_frames),
    }
    for k in range(4):
        for i, axis in enumerate("xy"):
            cols[f"c{k}_{axis}_px"] = corners[..., k, i].ravel()
    for i in range(3):
        for j in range(3):
            cols[f"R_CM_{i}{j}"] = T[..., i, j].ravel()
    for i, axis in enumerate("xyz"):
        cols[f"t_CM_{axis}_mm"] = T[..., i, 3].ravel()
    for i, axis in enumerate("xyz"):
        cols[f"t_M0M_{axis}_mm"] = t_M0M[..., i].ravel()
    cols["deflection_mm"] = np.hypot(t_M0M[..., 0], t_M0M[..., 1]).ravel()
    cols["theta_h_rad"] = angles_rad[..., 0].ravel()
    cols["theta_v_rad"] = angles_rad[..., 1].ravel()
    cols["contact"] = np.asarray(contact, bool).ravel()
    cols["branch_contact"] = np.asarray(branch_contact, bool).ravel()
    cols["visible"] = visible(camera, corners, T).ravel()
    return pd.DataFrame(cols)


def corners_of_frame(labels: pd.DataFrame, frame: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(corners (n, 4, 2), marker ids (n,), visible (n,)) of one frame of a label table."""
    rows = labels[labels["frame"] == frame]
    corners = np.stack([rows[[f"c{k}_x_px", f"c{k}_y_px"]].to_numpy() for k in range(4)], axis=1)
    return corners, rows["marker_id"].to_numpy(), rows["visible"].to_numpy()
