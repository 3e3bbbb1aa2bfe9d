"""Frames, transforms and the study's marker placement, against independent computations."""

import math
import subprocess
import sys

import numpy as np
import pytest

from scenes.camera import default_camera
from scenes.conventions import (
    invert_T,
    make_T,
    marker_corners_marker,
    rot_x,
    rot_y,
    rotation_angle_deg,
    transform_points,
)
from scenes.marker import MarkerSpec, carrier_mesh, marker_albedo, print_mesh
from scenes.study import study_pose


def random_T(rng):
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    w, x, y, z = q  # quaternion -> rotation, an independent route to a rotation matrix
    R = np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )
    return make_T(R, rng.normal(size=3) * 100)


def test_composition_and_inverse():
    rng = np.random.default_rng(0)
    T_a_b, T_b_c = random_T(rng), random_T(rng)
    p_c = rng.normal(size=(10, 3))
    chained = transform_points(T_a_b, transform_points(T_b_c, p_c))
    assert np.allclose(transform_points(T_a_b @ T_b_c, p_c), chained, atol=1e-9)
    assert np.allclose(invert_T(T_a_b) @ T_a_b, np.eye(4), atol=1e-12)


def test_rotations_are_right_handed():
    assert np.allclose(rot_x(math.pi / 2) @ [0, 1, 0], [0, 0, 1])
    assert np.allclose(rot_y(math.pi / 2) @ [0, 0, 1], [1, 0, 0])


@pytest.mark.parametrize("alpha", [0.0, 20.0, 45.0, 85.0, 90.0])
@pytest.mark.parametrize("phi", [0.0, 30.0, 70.0])
def test_study_pose(alpha, phi):
    T = study_pose(alpha, phi, 200.0)
    R, t = T[:3, :3], T[:3, 3]
    assert np.allclose(R.T @ R, np.eye(3), atol=1e-12) and np.linalg.det(R) == pytest.approx(1.0)
    # Centre at angle alpha from the axis, in the horizontal plane, 200 mm away.
    assert np.linalg.norm(t) == pytest.approx(200.0)
    assert t[1] == pytest.approx(0.0, abs=1e-12)
    assert math.degrees(math.atan2(t[0], t[2])) == pytest.approx(alpha)
    # The normal's angle to the line of sight is acos(cos(phi)^2) for equal tilts about x and y.
    to_camera = -t / np.linalg.norm(t)
    expected = math.degrees(math.acos(math.cos(math.radians(phi)) ** 2))
    assert math.degrees(math.acos(np.clip(R[:, 2] @ to_camera, -1, 1))) == pytest.approx(expected)


def test_untilted_marker_is_upright_in_the_image():
    cam = default_camera()
    px = cam.project(transform_points(study_pose(0.0, 0.0, 200.0), marker_corners_marker(13.2)))
    tl, tr, br, bl = px
    assert tl[0] < tr[0] and tl[1] < bl[1] and br[0] > bl[0] and br[1] > tr[1]
    # Corner (+-6.6, -6.6, 200) mm: theta = atan(|(6.6, 6.6)| / 200), x offset f theta cos(45 deg)
    theta = math.atan2(math.hypot(6.6, 6.6), 200.0)
    assert tr[0] - tl[0] == pytest.approx(2 * cam.fx_px * theta / math.sqrt(2), abs=1e-9)


def test_rotation_angle():
    assert rotation_angle_deg(np.eye(3), rot_x(math.radians(30))) == pytest.approx(30.0)


def test_marker_print_and_carrier():
    spec = MarkerSpec("4x4_50", 3, 12.0)
    albedo = marker_albedo(spec)
    assert albedo.shape == (8, 8)  # 4 bits + black border + white quiet zone on each side
    assert (albedo[0] > 0.5).all() and (albedo[:, 0] > 0.5).all()  # quiet zone
    assert (albedo[1, 1:-1] < 0.5).all()  # black border
    assert np.abs(print_mesh(spec).vertices).max() == pytest.approx(6.0 + 2.0)
    assert carrier_mesh(spec).vertices[:, 2].max() < 0  # carrier behind the print


@pytest.mark.parametrize(
    "kwargs, field",
    [
        (dict(size_mm=0), "size_mm"),
        (dict(size_mm=-2), "size_mm"),
        (dict(dictionary="4x4_7"), "dictionary"),
        (dict(marker_id=50), "marker_id"),
    ],
)
def test_bad_marker_spec(kwargs, field):
    with pytest.raises(ValueError, match=field):
        MarkerSpec(**kwargs)


@pytest.mark.slow
def test_scenes_do_not_import_mitsuba():
    code = (
        "import sys, scenes.camera, scenes.marker, scenes.lighting, scenes.study; "
        "assert 'mitsuba' not in sys.modules and 'drjit' not in sys.modules"
    )
    subprocess.run([sys.executable, "-c", code], check=True)
