"""Marker detection through any backend (:mod:`pipeline.backends`), its settings as data.

:class:`DetectorConfig` names the backend (``opencv``, ``locus``, ``apriltag``), the marker
family and the corner refinement; the other fields are OpenCV's ``DetectorParameters`` and only
the ``opencv`` backend reads them. :func:`detect_markers` runs the backend (peers in a worker
process), keeps the detections within the size limits, moves crop coordinates to the full frame
and refines the corners.

Size limits are rates of the full frame's longer side, as OpenCV's are of its image's (0.03 and
4.0, OpenCV's defaults): a crop is searched as the full frame would be, and the limits follow
the camera rather than one camera's pixels. The full frame is the camera model's when it is
given, else the image's own.

Corner refinement ``"lines"`` is this project's own, on any backend: its corners are refined by
:func:`pipeline.refine.refine_corners_by_edges`, which fits straight lines to the marker's 4
border edges in a virtual pinhole view aimed at the marker (where they are exactly straight) and
intersects them. It needs the camera model (``detect_markers(..., camera=...)``). Why: on
noise-free anti-aliased renders OpenCV's ``"subpix"`` (cornerSubPix) puts the outer, L-shaped
corners 0.35-0.5 px inside the true corner at every window size, and ``"contour"`` and
``"apriltag"`` are off by 0.5-1 px; on the same renders ``"lines"`` has a median error of
0.02 px and a maximum of 0.11 px over alpha 0-85 deg and phi 0-60 deg (see
:mod:`pipeline.refine`). It costs about 1 ms per marker. Where it fails for a detection, that
detection keeps the backend's corners and says why (``Detection.refine_failure``). The other
refinements are OpenCV's own; a peer offers ``"none"`` (its own corners) or ``"lines"``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from pipeline.backends import PoseRequest, check_family, get_backend
from pipeline.backends.isolated import run_backend
from pipeline.backends.opencv import REFINEMENTS
from pipeline.refine import TRANSFERS, refine_corners_by_edges
from scenes.camera import FisheyeCamera
from scenes.marker import check_dictionary, get_dictionary

#: The refinements a peer backend offers: its own corners, or the project's edge lines.
PEER_REFINEMENTS = ("none", "lines")
#: Largest adaptive-threshold window (px): wider than any marker's image in a full frame.
MAX_WINDOW_PX = 1001
#: Most threshold windows: each is one thresholding pass over the frame (OpenCV's default: 3).
MAX_WINDOWS = 32
#: The adaptive threshold's constant, at most this many grey levels either way.
MAX_THRESH_CONSTANT = 255.0


def window_problem(lo: int, hi: int, step: int) -> str | None:
    """What is wrong with adaptive-threshold windows ``lo..hi`` by ``step`` px, or None: OpenCV
    asserts windows of at least 3 px, ``hi >= lo`` and a positive step; the bounds above keep
    the work finite."""
    if lo < 3 or hi < lo or step < 1 or hi > MAX_WINDOW_PX:
        return f"need 3 <= MIN <= MAX <= {MAX_WINDOW_PX} and STEP >= 1"
    if (hi - lo) // step + 1 > MAX_WINDOWS:
        return (
            f"{(hi - lo) // step + 1} windows: at most {MAX_WINDOWS} (each is one thresholding "
            "pass over the frame)"
        )
    return None


def constant_problem(value: float) -> str | None:
    """What is wrong with an adaptive-threshold constant (grey levels), or None."""
    if not (math.isfinite(value) and abs(value) <= MAX_THRESH_CONSTANT):
        limit = f"{MAX_THRESH_CONSTANT:g}"
        return f"allowed range is -{limit}..{limit} grey levels"
    return None


@dataclass(frozen=True)
class DetectorConfig:
    """The detector's settings; the OpenCV fields are documented by its DetectorParameters."""

    dictionary: str = "4x4_50"
    corner_refinement: str = "subpix"
    min_marker_perimeter_rate: float = 0.03  # of the full frame's longer side
    max_marker_perimeter_rate: float = 4.0
    adaptive_thresh_win_size_min: int = 3
    adaptive_thresh_win_size_max: int = 23
    adaptive_thresh_win_size_step: int = 10
    adaptive_thresh_constant: float = 7.0
    use_aruco3_detection: bool = False
    #: Pixels per code cell when OpenCV reads the bits (its perspectiveRemovePixelPerCell,
    #: default 4). Under a lens blur of about a fifth of a cell, 4 samples per cell misread bits
    #: (see docs/detectability.md); more samples read the cell's centre.
    cell_px: int = 4
    #: Which library finds the markers (:data:`pipeline.backends.BACKENDS`, or a plugin's
    #: ``plugin:SPEC``, :mod:`pipeline.backends.plugin`).
    backend: str = "opencv"
    #: The curve that encoded the image, for ``"lines"`` (:data:`pipeline.refine.TRANSFERS`).
    transfer: str = "auto"

    def __post_init__(self) -> None:
        get_backend(self.backend)  # ValueError naming the choices, or why a plugin is refused
        object.__setattr__(self, "dictionary", check_dictionary(self.dictionary))
        check_family(self.backend, self.dictionary)
        allowed = REFINEMENTS if self.backend == "opencv" else PEER_REFINEMENTS
        if self.corner_refinement not in allowed:
            raise ValueError(
                f"corner_refinement={self.corner_refinement!r}: detector {self.backend} "
                f"offers {', '.join(allowed)}"
            )
        if self.transfer not in TRANSFERS:
            raise ValueError(f"transfer={self.transfer!r}: choose from {', '.join(TRANSFERS)}")
        if not 0 < self.min_marker_perimeter_rate < self.max_marker_perimeter_rate <= 4.0:
            raise ValueError(
                "need 0 < min_marker_perimeter_rate < max_marker_perimeter_rate <= 4 "
                "(rates of the full frame's longer side)"
            )
        if isinstance(self.cell_px, bool) or not isinstance(self.cell_px, int):
            raise ValueError(f"cell_px={self.cell_px!r}: must be an integer in 2..32")
        if not 2 <= self.cell_px <= 32:
            raise ValueError(f"cell_px={self.cell_px}: allowed range is 2..32")
        windows = (
            self.adaptive_thresh_win_size_min,
            self.adaptive_thresh_win_size_max,
            self.adaptive_thresh_win_size_step,
        )
        if any(isinstance(w, bool) or not isinstance(w, int) for w in windows):
            raise ValueError(f"adaptive threshold windows {windows}: must be integers")
        problem = window_problem(*windows)
        if problem:
            lo, hi, step = windows
            raise ValueError(f"adaptive threshold windows {lo}..{hi} step {step}: {problem}")
        problem = constant_problem(self.adaptive_thresh_constant)
        if problem:
            raise ValueError(
                f"adaptive_thresh_constant={self.adaptive_thresh_constant!r}: {problem}"
            )


@dataclass(frozen=True)
class Detection:
    """One detected marker: id and corners (4, 2) in full-image pixels, ArUco order; the
    backend's own pose where asked for and offered; why ``"lines"`` kept the backend's corners
    (None where it refined them or was not asked)."""

    marker_id: int
    corners_px: np.ndarray
    own_T_cam_marker: np.ndarray | None = None
    refine_failure: str | None = None


def detect_markers(
    image: np.ndarray,
    config: DetectorConfig,
    offset_px: tuple[int, int] = (0, 0),
    camera: FisheyeCamera | None = None,
    own_pose_size_mm: float | None = None,
) -> list[Detection]:
    """Detect markers in an 8-bit grey image (or crop whose top-left pixel is ``offset_px``).

    ``camera`` is required by ``corner_refinement="lines"`` and by ``own_pose_size_mm`` (the
    marker side for the backend's own pose, which it is then asked for). A peer that crashes
    raises :class:`pipeline.backends.BackendCrashError`; one not installed
    :class:`pipeline.backends.BackendUnavailableError`.
    """
    if not isinstance(image, np.ndarray):
        raise ValueError(f"need an 8-bit grey image (a NumPy array), got {type(image).__name__}")
    if image.ndim != 2 or image.dtype != np.uint8 or image.size == 0:
        raise ValueError(f"need an 8-bit grey image, got {image.dtype} of shape {image.shape}")
    lines = config.corner_refinement == "lines"
    if (lines or own_pose_size_mm is not None) and camera is None:
        raise ValueError("corner_refinement='lines' and own poses need the camera: camera=...")
    offset = np.asarray(offset_px, dtype=float).reshape(2)
    side = max(camera.width_px, camera.height_px) if camera is not None else max(image.shape)
    pose = None
    if own_pose_size_mm is not None and get_backend(config.backend).own_pose:
        whole = not offset.any() and image.shape == (camera.height_px, camera.width_px)
        pose = PoseRequest(
            camera.fx_px, camera.fy_px, camera.cx_px - offset[0], camera.cy_px - offset[1],
            float(own_pose_size_mm), whole,
        )  # fmt: skip
    found = run_backend(np.ascontiguousarray(image), config, side, pose)
    keep = _within_size_limits(found.corners_px, config, side)
    modules = int(get_dictionary(config.dictionary).markerSize) + 2
    detections = []
    for k in np.flatnonzero(keep):
        corners, failure = found.corners_px[k] + offset, None
        if lines:
            corners, failure = refine_corners_by_edges(
                image, corners, camera, modules, (int(offset[0]), int(offset[1])),
                transfer=config.transfer,
            )  # fmt: skip
        own = None if found.own_T_cam_marker is None else found.own_T_cam_marker[k]
        detections.append(Detection(int(found.ids[k]), corners, own, failure))
    return detections


def _within_size_limits(corners_px: np.ndarray, config: DetectorConfig, side: int) -> np.ndarray:
    """(N,) whether each quad's perimeter is within the limits; OpenCV applies them itself."""
    if config.backend == "opencv":
        return np.ones(len(corners_px), bool)
    perimeter = np.linalg.norm(corners_px - np.roll(corners_px, 1, axis=1), axis=2).sum(axis=1)
    return (perimeter >= config.min_marker_perimeter_rate * side) & (
        perimeter <= config.max_marker_perimeter_rate * side
    )
