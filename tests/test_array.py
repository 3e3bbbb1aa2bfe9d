"""The array's geometry against independent constructions (rotations about axes through points)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from trimesh.transformations import rotation_matrix

from bench.dataset.labels import corners_px
from scenes.array import (
    ArraySpec,
    ArraySpecError,
    T_cam_marker,
    T_marker0_marker,
    outward_cam,
    tip_cam,
)
from scenes.camera import default_camera

SPEC = ArraySpec()
UP = np.array([0.0, -1.0, 0.0])


def _equidistant(camera, p: np.ndarray) -> np.ndarray:
    """Independent equidistant projection: r = f * theta along the point's azimuth."""
    rho = np.hypot(p[..., 0], p[..., 1])
    theta = np.arctan2(rho, p[..., 2])
    return np.stack(
        [
            camera.cx_px + camera.fx_px * theta * p[..., 0] / rho,
            camera.cy_px + camera.fy_px * theta * p[..., 1] / rho,
        ],
        axis=-1,
    )


def _rest_corners(i: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Coupling, lateral axis and marker corners of whisker i at rest, from the SPEC's words."""
    psi = math.radians(-45 + 7.5 * i)
    u = np.array([math.sin(psi), 0.0, math.cos(psi)])
    e = np.array([math.cos(psi), 0.0, -math.sin(psi)])  # horizontal, towards increasing psi
    coupling = 210.0 * u
    centre = coupling - 8.0 * u
    h = 13.2 / 2
    # ArUco order TL, TR, BR, BL seen by the camera: the marker's right is +e, its top is up.
    corners = centre + np.array([[-h, h], [h, h], [h, -h], [-h, -h]]) @ np.stack([e, UP])
    return coupling, e, corners


def test_rest_markers_on_the_horizontal_line_from_minus_to_plus_45_degrees() -> None:
    camera = default_camera()
    T = T_cam_marker(SPEC, np.zeros((13, 2)))
    centres = T[:, :3, 3]
    np.testing.assert_allclose(np.linalg.norm(centres, axis=1), 202.0, atol=1e-12)
    px = camera.project(centres)
    np.testing.assert_allclose(px[:, 1], camera.cy_px, atol=1e-9)
    theta = np.degrees(np.arctan2(centres[:, 0], centres[:, 2]))
    np.testing.assert_allclose(theta, np.linspace(-45, 45, 13), atol=1e-12)
    assert np.all(np.diff(px[:, 0]) > 0)  # whisker 0 is leftmost
    # every marker faces the camera
    assert np.all(np.einsum("ni,ni->n", T[:, :3, 2], -centres) > 0)


@pytest.mark.parametrize("whisker", [0, 4, 6, 12])
@pytest.mark.parametrize("angles", [(0.0, 0.0), (0.4, 0.0), (-0.7, 0.1), (0.2, -0.3)])
def test_label_corners_match_an_independent_rotation_and_projection(whisker, angles) -> None:
    camera = default_camera()
    a = np.zeros((13, 2))
    a[whisker] = angles
    got = corners_px(camera, SPEC, T_cam_marker(SPEC, a))[whisker]
    coupling, e, rest = _rest_corners(whisker)
    theta_h, theta_v = angles
    # R = R_y(-theta_h) R_x(theta_v) in the whisker frame: first about its x (= e), then its y
    M = rotation_matrix(-theta_h, UP, coupling) @ rotation_matrix(theta_v, e, coupling)
    moved = rest @ M[:3, :3].T + M[:3, 3]
    np.testing.assert_allclose(got, _equidistant(camera, moved), atol=1e-6)


def test_tip_and_marker_move_opposite_ways_by_the_lever_ratio() -> None:
    theta = 0.3
    a = np.zeros((13, 2))
    a[:, 0] = theta
    tip = tip_cam(SPEC, a)
    rest_tip = tip_cam(SPEC, np.zeros((13, 2)))
    t_marker0_marker = T_marker0_marker(SPEC, a)[:, :3, 3]
    lateral = np.stack(
        [np.cos(SPEC.headings_rad), 0 * SPEC.headings_rad, -np.sin(SPEC.headings_rad)], 1
    )
    tip_lateral = np.einsum("ni,ni->n", tip - rest_tip, lateral)
    np.testing.assert_allclose(tip_lateral, 140 * math.sin(theta), atol=1e-9)
    # marker x = lateral
    np.testing.assert_allclose(t_marker0_marker[:, 0], -8 * math.sin(theta), atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(outward_cam(SPEC), axis=1), 1.0)


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"n_whiskers": 1}, "n_whiskers"),
        ({"arc_deg": 200.0}, "arc_deg"),
        ({"frame_radius_mm": -1.0}, "frame_radius_mm"),
        ({"marker_ids": (1, 2)}, "marker_ids"),
        ({"rod_modulus_MPa": 0.0}, "rod_modulus_MPa"),
    ],
)
def test_bad_array_parameters_name_the_field(kwargs, field) -> None:
    with pytest.raises(ArraySpecError, match=field):
        ArraySpec(**kwargs)
