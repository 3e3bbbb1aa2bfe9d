"""The project's conventions, stated once. Every other module imports them rather than restating.

Units
    Lengths in millimetres, angles in radians inside the code; names carry ``_mm``, ``_deg``,
    ``_px`` where a number crosses a module boundary, the CLI or disk.

Camera frame (``cam``)
    OpenCV's: origin at the projection centre, +x right in the image, +y down in the image,
    +z forward along the optical axis.

Pixel coordinates (``px``)
    OpenCV's: (x, y) = (column, row); the centre of the top-left pixel is (0, 0), so pixel
    (i, j) covers [i - 0.5, i + 0.5] x [j - 0.5, j + 0.5].

Marker frame (``marker``)
    Origin at the marker centre, +x to the marker's right, +y to its top, +z out of the printed
    face (towards a camera that reads it). Corners in ArUco's order: top-left, top-right,
    bottom-right, bottom-left, i.e. (-L/2, +L/2), (+L/2, +L/2), (+L/2, -L/2), (-L/2, -L/2).

Whisker frame (``whisker``)
    One per whisker, at rest: origin at its coupling on the array, +z towards the camera, +y
    image-up (:func:`scenes.array.T_cam_whisker`).

No-contact marker frame (``marker0``)
    The marker frame where the whisker rests (in the pipeline: the mean of its first frames).

Transforms
    ``T_a_b`` is a 4x4 homogeneous matrix mapping points in frame b into frame a:
    ``p_a = T_a_b @ p_b``; so ``T_a_c = T_a_b @ T_b_c``. Its rotation and translation are
    ``R_a_b`` and ``t_a_b``. E.g. ``T_cam_marker`` (a marker's pose in the camera frame) and
    ``T_marker0_marker`` (the marker's displacement from its no-contact pose; the seed paper's
    T_M0M, ``inv(T_cam_marker0) @ T_cam_marker``). The same words name the columns of the
    per-marker tables (:mod:`scenes.tables`): ``R_cam_marker_{ij}``, ``t_cam_marker_{x,y,z}_mm``.
"""

from __future__ import annotations

import numpy as np

#: World up in the camera frame: the camera is mounted upright, so up is image-up, -y.
UP_CAM = np.array([0.0, -1.0, 0.0])
#: The optical axis in the camera frame.
OPTICAL_AXIS_CAM = np.array([0.0, 0.0, 1.0])

#: Corner signs (x, y) in the marker frame, ArUco order: TL, TR, BR, BL.
CORNER_SIGNS = np.array([[-1.0, 1.0], [1.0, 1.0], [1.0, -1.0], [-1.0, -1.0]])


def marker_corners_marker(size_mm: float) -> np.ndarray:
    """Marker corners in the marker frame: (4, 3) float64, ArUco order, z = 0."""
    half = 0.5 * float(size_mm)
    return np.column_stack([CORNER_SIGNS * half, np.zeros(4)])


def rot_x(angle_rad: float) -> np.ndarray:
    """3x3 rotation about +x by ``angle_rad`` (right-handed)."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(angle_rad: float) -> np.ndarray:
    """3x3 rotation about +y by ``angle_rad`` (right-handed)."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def make_T(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """4x4 homogeneous transform from a 3x3 rotation and a translation (mm)."""
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = np.asarray(t, dtype=float).reshape(3)
    return T


def transform_points(T_a_b: np.ndarray, points_b: np.ndarray) -> np.ndarray:
    """Map (..., 3) points from frame b into frame a."""
    points_b = np.asarray(points_b, dtype=float)
    return points_b @ T_a_b[:3, :3].T + T_a_b[:3, 3]


def invert_T(T_a_b: np.ndarray) -> np.ndarray:
    """``T_b_a`` from ``T_a_b`` for a rigid transform."""
    R = T_a_b[:3, :3]
    return make_T(R.T, -R.T @ T_a_b[:3, 3])


def rotation_angle_deg(R_a: np.ndarray, R_b: np.ndarray) -> float:
    """Angle of the relative rotation between two 3x3 rotations, in degrees."""
    cos = (np.trace(R_a.T @ R_b) - 1.0) / 2.0
    return float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))
