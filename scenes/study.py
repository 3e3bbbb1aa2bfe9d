"""Where the detectability study puts its marker (SPEC section 4).

The marker sits at angular position ``alpha`` in the horizontal plane through the optical axis
(positive alpha towards +x, image right), ``distance_mm`` from the camera, facing the camera
with its top up. It is then tilted by ``phi`` about both of its in-plane axes: first about its
own y axis, then about its own x axis (intrinsic rotations), so its normal leans towards the
marker's right and down.
"""

from __future__ import annotations

import math

import numpy as np

from scenes.conventions import UP_CAM, make_T, rot_x, rot_y

MAX_PHI_DEG = 89.0


def facing_rotation(position_cam: np.ndarray) -> np.ndarray:
    """R_cam_marker of a marker at ``position_cam`` facing the camera, top towards the zenith."""
    z = -np.asarray(position_cam, dtype=float)
    z /= np.linalg.norm(z)
    y = UP_CAM - (UP_CAM @ z) * z
    y /= np.linalg.norm(y)
    return np.column_stack([np.cross(y, z), y, z])


def study_pose(alpha_deg: float, phi_deg: float, distance_mm: float) -> np.ndarray:
    """T_cam_marker of the study's marker at (alpha, phi, distance)."""
    a = math.radians(alpha_deg)
    position = distance_mm * np.array([math.sin(a), 0.0, math.cos(a)])
    phi = math.radians(phi_deg)
    R = facing_rotation(position) @ rot_y(phi) @ rot_x(phi)
    return make_T(R, position)
