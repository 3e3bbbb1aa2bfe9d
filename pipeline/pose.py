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


POSE_METHODS = ("virtual", "fisheye", "pinhole")
#: A solution whose reprojection error exceeds this fraction of the marker's side is a mirror
#: image, not noise (a good fit is under a pixel; the mirror ~0.7 of the side).
MIRROR_SIDES = 0.25


def estimate_pose(
    corners_px: np.ndarray, size_mm: float, camera: FisheyeCamera, method: str = "virtual"
) -> PoseEstimate:
    """Pose of a square marker of side ``size_mm`` from its 4 corners (ArUco order, pixels).

    ``method``: ``"virtual"`` (rays from the exact model, a virtual pinhole view aimed at the
    marker, valid past 90 degrees), ``"fisheye"`` (OpenCV's fisheye undistortion to the
    camera's own pinhole plane, valid below 90 degrees only) or ``"pinhole"`` (a naive baseline:
    the raw pixels as if the lens had no distortion).
    """
    corners = np.asarray(corners_px, dtype=float).reshape(4, 2)
    f = camera.fx_px  # keeps reprojection errors in (about) image pixels
    if method == "virtual":
        rays, valid = camera.unproject(corners)
        if not valid.all():
            raise ValueError("a corner lies outside the image circle")
        R_virt_cam = virtual_view_rotation(rays.sum(axis=0))
        q = rays @ R_virt_cam.T
        return _solve(f * q[:, :2] / q[:, 2:], size_mm, f, R_virt_cam)
    if method == "fisheye":
        cv = camera.to_opencv()
        normalized = cv2.fisheye.undistortPoints(corners.reshape(1, 4, 2), cv["K"], cv["D"])
        if not np.isfinite(normalized).all() or (camera.theta_of_pixel(corners) >= np.pi / 2).any():
            raise ValueError("a corner lies at or beyond 90 degrees: no pinhole image of it")
        return _solve(f * normalized.reshape(4, 2), size_mm, f, np.eye(3))
    if method == "pinhole":
        centred = corners - [camera.cx_px, camera.cy_px]
        return _solve(centred * f / np.array([camera.fx_px, camera.fy_px]), size_mm, f, np.eye(3))
    raise ValueError(f"method={method!r}: choose from {', '.join(POSE_METHODS)}")


def _solve(image_points: np.ndarray, size_mm: float, f: float, R_virt_cam: np.ndarray):
    """IPPE_SQUARE on pinhole points (centred, focal ``f``) of a view rotated by R_virt_cam."""
    K = np.array([[f, 0.0, 0.0], [0.0, f, 0.0], [0.0, 0.0, 1.0]])
    # IPPE_SQUARE returns NaN for some exactly fronto-parallel squares (integer corners of a
    # marker facing the view), and for a square centred on the view's axis both IPPE methods
    # return the mirror image (reprojection error ~0.7 of the side); SQPNP, a global solver,
    # solves those.
    side = np.linalg.norm(np.diff(image_points, axis=0, append=image_points[:1]), axis=1).mean()
    for flags in (cv2.SOLVEPNP_IPPE_SQUARE, cv2.SOLVEPNP_IPPE, cv2.SOLVEPNP_SQPNP):
        _, rvecs, tvecs, errors = cv2.solvePnPGeneric(
            marker_corners_marker(size_mm), image_points.reshape(4, 1, 2), K, None, flags=flags
        )
        finite = [
            k
            for k in range(len(rvecs))
            if np.isfinite(rvecs[k]).all() and np.isfinite(tvecs[k]).all()
        ]
        if finite and np.asarray(errors, float).ravel()[finite].min() < MIRROR_SIDES * side:
            break
    else:
        if not finite:
            raise ValueError("solvePnP found no finite pose")
    rvecs, tvecs = [rvecs[k] for k in finite], [tvecs[k] for k in finite]
    errors = np.asarray(errors, dtype=float).ravel()[finite]
    best = int(np.argmin(errors))
    R_virt_marker = cv2.Rodrigues(rvecs[best])[0]
    T_cam_marker = make_T(R_virt_cam.T @ R_virt_marker, R_virt_cam.T @ tvecs[best].ravel())
    others = np.delete(errors, best)
    ratio = float(others.min() / max(errors[best], 1e-12)) if len(others) else float("inf")
    return PoseEstimate(T_cam_marker, float(errors[best]), ratio)
