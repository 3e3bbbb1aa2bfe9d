"""ArUco marker detection with OpenCV 5's ``cv2.aruco.ArucoDetector``, parameters as data.

Size limits are given in absolute pixels of the full frame, not as OpenCV's rates relative to
the image side, so that detecting in a crop behaves as detecting in the full 2592-px frame
would. The defaults are OpenCV's own (rate 0.03 and 4.0 of a 2592-px side), except the corner
refinement, which is sub-pixel so that corner and pose errors measure the scene, not the
detector's integer corners.

Corner refinement ``"lines"`` is this project's own: OpenCV runs with ``CORNER_REFINE_NONE`` and
each detection's corners are then refined by :func:`pipeline.refine.refine_corners_by_edges`,
which fits straight lines to the marker's 4 border edges in a virtual pinhole view aimed at the
marker (where they are exactly straight) and intersects them. It needs the camera model
(``detect_markers(..., camera=...)``). Why: on noise-free anti-aliased renders OpenCV's
``"subpix"`` (cornerSubPix) puts the outer, L-shaped corners 0.35-0.5 px inside the true corner
at every window size, and ``"contour"`` and ``"apriltag"`` are off by 0.5-1 px; on the same
renders ``"lines"`` has a median error of 0.02 px and a maximum of 0.11 px over alpha 0-85 deg and
phi 0-60 deg (see :mod:`pipeline.refine`). It costs about 1 ms per marker. If it fails for a
detection, that detection keeps OpenCV's unrefined corners.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np

from pipeline.refine import refine_corners_by_edges
from scenes.camera import FisheyeCamera
from scenes.marker import get_dictionary

REFINEMENTS = {
    "none": cv2.aruco.CORNER_REFINE_NONE,
    "subpix": cv2.aruco.CORNER_REFINE_SUBPIX,
    "contour": cv2.aruco.CORNER_REFINE_CONTOUR,
    "apriltag": cv2.aruco.CORNER_REFINE_APRILTAG,
    "lines": cv2.aruco.CORNER_REFINE_NONE,  # then refine_corners_by_edges, see the docstring
}
REFERENCE_SIDE_PX = 2592


@dataclass(frozen=True)
class DetectorConfig:
    """The detector's settings; every field is documented by OpenCV's DetectorParameters."""

    dictionary: str = "4x4_50"
    corner_refinement: str = "subpix"
    min_marker_perimeter_px: float = 0.03 * REFERENCE_SIDE_PX
    max_marker_perimeter_px: float = 4.0 * REFERENCE_SIDE_PX
    adaptive_thresh_win_size_min: int = 3
    adaptive_thresh_win_size_max: int = 23
    adaptive_thresh_win_size_step: int = 10
    adaptive_thresh_constant: float = 7.0
    use_aruco3_detection: bool = False
    #: Pixels per code cell when OpenCV reads the bits (its perspectiveRemovePixelPerCell,
    #: default 4). Under a lens blur of about a fifth of a cell, 4 samples per cell misread bits
    #: (see the detectability study in the README); more samples read the cell's centre.
    cell_px: int = 4

    def __post_init__(self) -> None:
        if self.corner_refinement not in REFINEMENTS:
            raise ValueError(
                f"corner_refinement={self.corner_refinement!r}: "
                f"choose from {', '.join(REFINEMENTS)}"
            )
        if not 0 < self.min_marker_perimeter_px < self.max_marker_perimeter_px:
            raise ValueError("need 0 < min_marker_perimeter_px < max_marker_perimeter_px")
        if isinstance(self.cell_px, bool) or not isinstance(self.cell_px, int):
            raise ValueError(f"cell_px={self.cell_px!r}: must be an integer in 2..32")
        if not 2 <= self.cell_px <= 32:
            raise ValueError(f"cell_px={self.cell_px}: allowed range is 2..32")
        get_dictionary(self.dictionary)


@dataclass(frozen=True)
class Detection:
    """One detected marker: id and corners (4, 2) in full-image pixels, ArUco order."""

    marker_id: int
    corners_px: np.ndarray


@lru_cache(maxsize=64)
def _detector(config: DetectorConfig, side_px: int) -> cv2.aruco.ArucoDetector:
    p = cv2.aruco.DetectorParameters()
    p.minMarkerPerimeterRate = config.min_marker_perimeter_px / side_px
    p.maxMarkerPerimeterRate = config.max_marker_perimeter_px / side_px
    p.cornerRefinementMethod = REFINEMENTS[config.corner_refinement]
    p.adaptiveThreshWinSizeMin = config.adaptive_thresh_win_size_min
    p.adaptiveThreshWinSizeMax = config.adaptive_thresh_win_size_max
    p.adaptiveThreshWinSizeStep = config.adaptive_thresh_win_size_step
    p.adaptiveThreshConstant = config.adaptive_thresh_constant
    p.useAruco3Detection = config.use_aruco3_detection
    p.perspectiveRemovePixelPerCell = config.cell_px
    return cv2.aruco.ArucoDetector(get_dictionary(config.dictionary), p)


def detect_markers(
    image: np.ndarray,
    config: DetectorConfig,
    offset_px: tuple[int, int] = (0, 0),
    camera: FisheyeCamera | None = None,
) -> list[Detection]:
    """Detect markers in an 8-bit grey image (or crop whose top-left pixel is ``offset_px``).

    ``camera`` is required by ``corner_refinement="lines"`` and unused otherwise.
    """
    if image.ndim != 2 or image.dtype != np.uint8:
        raise ValueError(f"need an 8-bit grey image, got {image.dtype} of shape {image.shape}")
    lines = config.corner_refinement == "lines"
    if lines and camera is None:
        raise ValueError("corner_refinement='lines' needs the camera: pass camera=...")
    corners, ids, _ = _detector(config, max(image.shape)).detectMarkers(image)
    if ids is None:
        return []
    offset = np.asarray(offset_px, dtype=float)
    detections = [
        Detection(int(i), c.reshape(4, 2).astype(float) + offset)
        for i, c in zip(ids.ravel(), corners, strict=True)
    ]
    if lines:
        modules = int(get_dictionary(config.dictionary).markerSize) + 2
        detections = [
            Detection(
                d.marker_id,
                refine_corners_by_edges(
                    image, d.corners_px, camera, modules, (int(offset[0]), int(offset[1]))
                ),
            )
            for d in detections
        ]
    return detections
