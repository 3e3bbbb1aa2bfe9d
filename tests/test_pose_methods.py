"""Pose variants: exact where their model holds, naive pinhole wrong off-axis, clear refusals."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.pose import estimate_pose
from scenes.camera import default_camera
from scenes.conventions import marker_corners_marker, rotation_angle_deg, transform_points
from scenes.study import study_pose


def _corners(alpha: float, phi: float = 20.0):
    T = study_pose(alpha, phi, 200.0)
    return T, default_camera().project(transform_points(T, marker_corners_marker(13.2)))


@pytest.mark.parametrize("method", ["virtual", "fisheye"])
@pytest.mark.parametrize("alpha", [0.0, 30.0, 60.0, 85.0])
def test_fisheye_aware_methods_recover_the_pose_exactly(method: str, alpha: float) -> None:
    T, corners = _corners(alpha)
    pose = estimate_pose(corners, 13.2, default_camera(), method)
    assert np.linalg.norm(pose.T_cam_marker[:3, 3] - T[:3, 3]) < 1e-6
    assert rotation_angle_deg(pose.T_cam_marker[:3, :3], T[:3, :3]) < 1e-4


def test_naive_pinhole_is_right_on_axis_and_wrong_off_axis() -> None:
    camera = default_camera()
    T0, c0 = _corners(0.0)
    T60, c60 = _corners(60.0)
    on = estimate_pose(c0, 13.2, camera, "pinhole").T_cam_marker
    off = estimate_pose(c60, 13.2, camera, "pinhole").T_cam_marker
    assert np.linalg.norm(on[:3, 3] - T0[:3, 3]) < 1.0
    assert np.linalg.norm(off[:3, 3] - T60[:3, 3]) > 20.0


def test_fisheye_undistortion_refuses_beyond_90_degrees_virtual_does_not() -> None:
    T, corners = _corners(93.0, 0.0)
    with pytest.raises(ValueError, match="90 degrees"):
        estimate_pose(corners, 13.2, default_camera(), "fisheye")
    pose = estimate_pose(corners, 13.2, default_camera(), "virtual")
    assert np.linalg.norm(pose.T_cam_marker[:3, 3] - T[:3, 3]) < 1e-6


def test_unknown_method() -> None:
    with pytest.raises(ValueError, match="choose from"):
        estimate_pose(_corners(0.0)[1], 13.2, default_camera(), "magic")


def test_integer_corners_of_a_facing_marker_give_a_finite_pose():
    """IPPE_SQUARE returns NaN for these (unrefined corners, marker at alpha 70, phi 0): the
    pose falls back to the general IPPE instead of returning NaN as if it were a pose."""
    corners = np.array([[2031, 946], [2071, 945], [2071, 998], [2031, 997]], float)
    pose = estimate_pose(corners, 13.2, default_camera(), "virtual")
    assert np.isfinite(pose.T_cam_marker).all()
    assert abs(np.linalg.norm(pose.T_cam_marker[:3, 3]) - 204.0) < 10.0


@pytest.mark.parametrize("method", ["virtual", "fisheye", "pinhole"])
def test_a_facing_marker_centred_on_the_axis_is_not_mirrored(method: str) -> None:
    """Both IPPE methods return the mirror image of a square centred on the view's axis
    (reprojection error ~0.7 of its side); the pose must be the marker facing the camera."""
    camera = default_camera()
    centre = np.array([camera.cx_px, camera.cy_px])
    corners = centre + 47.5 * np.array([[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]])
    pose = estimate_pose(corners, 13.2, camera, method)
    assert pose.reprojection_err_px < 0.01
    assert rotation_angle_deg(pose.T_cam_marker[:3, :3], np.diag([1.0, -1.0, -1.0])) < 0.01
