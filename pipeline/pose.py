"""Marker pose from detected corners through a fisheye, valid past 90 degrees.

The corners are unprojected to rays with the exact camera model, rotated into a virtual
pinhole camera looking straight at the marker, and solved there with ``SOLVEPNP_IPPE_SQUARE``.
Both IPPE solutions are kept: the ratio of their reprojection errors (second / best) says how
ambiguous the pose is (near 1: the two are equally good, the classic flip of small markers).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from scenes.camera import FisheyeCamera
from scenes.conventions import make_T, marker_corners_marker


@dataclass(frozen=True)
class PoseEstimate:
    T_cam_marker: np.ndarray  # (4, 4), mm
    reprojection_err_px: float  # of the chosen solution, in virtual-view pixels
    ambiguity_ratio: float  # second-best / best reprojection error; inf if only one solution


def virtual_view_rotation(axis_cam: np.ndarray) -> np.ndarray:
    """R_virt_cam of a virtual pinhole camera whose optical axis is ``axis_cam``."""
    z = axis_cam / np.linalg.norm(axis_cam)
    helper = np.array([0.0, 1.0, 0.0]) if abs(z[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    return np.stack([x, np.cross(z, x), z])


def estimate_pose(corners_px: np.ndarray, size_mm: float, camera: FisheyeCamera) -> PoseEstimate:
    """Pose of a square marker of side ``size_mm`` from its 4 corners (ArUco order, pixels)."""
    rays, valid = camera.unproject(np.asarray(corners_px, dtype=float).reshape(4, 2))
    if not valid.all():
        raise ValueError("a corner lies outside the image circle")
    R_virt_cam = virtual_view_rotation(rays.sum(axis=0))
    q = rays @ R_virt_cam.T
    f = camera.fx_px  # keeps reprojection errors in (about) image pixels
    image_points = (f * q[:, :2] / q[:, 2:]).reshape(4, 1, 2)
    K = np.array([[f, 0.0, 0.0], [0.0, f, 0.0], [0.0, 0.0, 1.0]])
    n, rvecs, tvecs, errors = cv2.solvePnPGeneric(
        marker_corners_marker(size_mm), image_points, K, None, flags=cv2.SOLVEPNP_IPPE_SQUARE
    )
    if n < 1:
        raise ValueError("solvePnP found no pose")
    errors = np.asarray(errors, dtype=float).ravel()
    best = int(np.argmin(errors))
    R_virt_marker = cv2.Rodrigues(rvecs[best])[0]
    T_cam_marker = make_T(R_virt_cam.T @ R_virt_marker, R_virt_cam.T @ tvecs[best].ravel())
    others = np.delete(errors, best)
    ratio = float(others.min() / max(errors[best], 1e-12)) if len(others) else float("inf")
    return PoseEstimate(T_cam_marker, float(errors[best]), ratio)
