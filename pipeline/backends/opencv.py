"""The OpenCV 5 backend: ``cv2.aruco.ArucoDetector`` with the project's detector settings.

OpenCV's corners already follow the project's conventions (they are OpenCV's): no mapping. Its
size limits are rates of the image's longer side; the config's rates are of the full frame's,
so a crop is searched with the limits the full frame would have.
"""

from __future__ import annotations

from functools import lru_cache
from typing import TYPE_CHECKING

import cv2
import numpy as np

from pipeline.backends import Found, PoseRequest
from scenes.marker import get_dictionary

if TYPE_CHECKING:
    from pipeline.detect import DetectorConfig

REFINEMENTS = {
    "none": cv2.aruco.CORNER_REFINE_NONE,
    "subpix": cv2.aruco.CORNER_REFINE_SUBPIX,
    "contour": cv2.aruco.CORNER_REFINE_CONTOUR,
    "apriltag": cv2.aruco.CORNER_REFINE_APRILTAG,
    "lines": cv2.aruco.CORNER_REFINE_NONE,  # then pipeline.refine, see pipeline.detect
}


def load() -> None:
    """OpenCV is a core dependency: always there."""


@lru_cache(maxsize=64)
def _detector(config: DetectorConfig, scale: float) -> cv2.aruco.ArucoDetector:
    """The detector for images whose longer side is ``1 / scale`` of the full frame's."""
    p = cv2.aruco.DetectorParameters()
    p.minMarkerPerimeterRate = config.min_marker_perimeter_rate * scale
    p.maxMarkerPerimeterRate = config.max_marker_perimeter_rate * scale
    p.cornerRefinementMethod = REFINEMENTS[config.corner_refinement]
    p.adaptiveThreshWinSizeMin = config.adaptive_thresh_win_size_min
    p.adaptiveThreshWinSizeMax = config.adaptive_thresh_win_size_max
    p.adaptiveThreshWinSizeStep = config.adaptive_thresh_win_size_step
    p.adaptiveThreshConstant = config.adaptive_thresh_constant
    p.useAruco3Detection = config.use_aruco3_detection
    p.perspectiveRemovePixelPerCell = config.cell_px
    return cv2.aruco.ArucoDetector(get_dictionary(config.dictionary), p)


def detect(
    image: np.ndarray, config: DetectorConfig, frame_side_px: int, pose: PoseRequest | None
) -> Found:
    """OpenCV's ids and corners; it has no pose of its own (``pose`` is unused)."""
    corners, ids, _ = _detector(config, frame_side_px / max(image.shape)).detectMarkers(image)
    if ids is None:
        return Found(np.zeros(0, int), np.zeros((0, 4, 2)))
    return Found(ids.ravel().astype(int), np.array(corners, dtype=float).reshape(-1, 4, 2))
