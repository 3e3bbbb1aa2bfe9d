"""The locus-tag backend (PyPI ``locus-tag``, MIT or Apache-2.0; CAMERA_NOTES.md).

Mapping to the project's conventions, checked in ``tests/test_backends.py``:

- corners: locus puts pixel centres at +0.5 (a pixel's top-left corner is integral), in ArUco
  order; subtract 0.5.
- own pose: ``(tx, ty, tz, qw, qx, qy, qz)`` in the units of ``tag_size`` of a tag frame with
  +x right, +y down, +z into the printed face; the project's marker frame has +y up and +z out of
  the face, a half-turn about x. Its pinhole model reads the same +0.5 pixels, so the principal
  point goes in shifted by 0.5 too. This wheel models no lens distortion (locus.HAS_NON_RECTIFIED
  is False), so on the fisheye its pose is a pinhole's. It refuses a principal point outside the
  image, so a crop that does not hold the principal point (ROI tracking, the sweeps' crops) gets
  no own pose.

Size limits are applied by :func:`pipeline.detect.detect_markers` on what it returns. One thread
(the comparison measures single-core speed); the library's ``standard`` profile.
"""

from __future__ import annotations

from functools import cache
from typing import TYPE_CHECKING

import numpy as np

from pipeline.backends import Found, PoseRequest, missing_library

if TYPE_CHECKING:
    from pipeline.detect import DetectorConfig

PIXEL_SHIFT = 0.5  # locus pixel coordinates minus the project's
#: R_tag_marker: the project's marker frame in locus' tag frame (y and z flipped).
R_TAG_MARKER = np.diag([1.0, -1.0, -1.0])
FAMILY_NAMES = {
    "4x4_50": "ArUco4x4_50",
    "4x4_100": "ArUco4x4_100",
    "6x6_250": "ArUco6x6_250",
    "apriltag_16h5": "AprilTag16h5",
    "apriltag_36h11": "AprilTag36h11",
}


def load():
    """The locus module, or BackendUnavailableError saying how to install it."""
    try:
        import locus
    except ImportError:
        raise missing_library("locus", "locus-tag") from None
    return locus


@cache
def _detector(family: str):
    locus = load()
    return locus.Detector(families=[getattr(locus.TagFamily, FAMILY_NAMES[family])], threads=1)


def detect(
    image: np.ndarray, config: DetectorConfig, frame_side_px: int, pose: PoseRequest | None
) -> Found:
    """locus' ids and corners (and own poses when ``pose`` asks) in the project's conventions."""
    detector = _detector(config.dictionary)
    h, w = image.shape
    if pose is not None and not (0 <= pose.cx_px < w and 0 <= pose.cy_px < h):
        pose = None  # locus refuses a principal point outside the image: no own pose on crops
    if pose is None:
        batch = detector.detect(image)
    else:
        intrinsics = load().CameraIntrinsics(
            pose.fx_px, pose.fy_px, pose.cx_px + PIXEL_SHIFT, pose.cy_px + PIXEL_SHIFT
        )
        batch = detector.detect(image, intrinsics=intrinsics, tag_size=pose.size_mm)
    ids = np.asarray(batch.ids, dtype=int).reshape(-1)
    corners = np.asarray(batch.corners, dtype=float).reshape(-1, 4, 2) - PIXEL_SHIFT
    own = None
    if pose is not None and batch.poses is not None and len(ids):
        own = _poses(np.asarray(batch.poses, dtype=float).reshape(-1, 7))
    return Found(ids, corners, own)


def _poses(rows: np.ndarray) -> np.ndarray:
    """(N, 4, 4) T_cam_marker from locus' (tx, ty, tz, qw, qx, qy, qz) rows."""
    w, x, y, z = (rows[:, 3 + k] for k in range(4))
    norm = np.sqrt(w * w + x * x + y * y + z * z)
    w, x, y, z = w / norm, x / norm, y / norm, z / norm
    R_cam_tag = np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        axis=1,
    )
    T = np.tile(np.eye(4), (len(rows), 1, 1))
    T[:, :3, :3] = R_cam_tag @ R_TAG_MARKER
    T[:, :3, 3] = rows[:, :3]
    return T
