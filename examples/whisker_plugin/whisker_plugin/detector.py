"""A detector plugin: OpenCV's ArucoDetector with its default settings on the 4x4_50 family.

``detect(image)`` takes an (H, W) uint8 grey image and returns ``[(marker_id, corners), ...]``
with ``corners`` a (4, 2) array of (x, y) pixels in ArUco order, the centre of the top-left
pixel at (0, 0) (OpenCV's convention already, so nothing is shifted).
"""

from __future__ import annotations

from functools import cache

import cv2
import numpy as np


@cache
def _detector() -> cv2.aruco.ArucoDetector:
    family = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50)
    return cv2.aruco.ArucoDetector(family, cv2.aruco.DetectorParameters())


def detect(image: np.ndarray) -> list[tuple[int, np.ndarray]]:
    """The markers OpenCV finds in ``image``."""
    corners, ids, _ = _detector().detectMarkers(image)
    if ids is None:
        return []
    return [
        (int(i), np.asarray(c, float).reshape(4, 2))
        for i, c in zip(ids.ravel(), corners, strict=True)
    ]
