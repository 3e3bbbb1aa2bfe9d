"""One camera image of a known marker, detected, posed and scored against its truth.

The one path the detectability study (:mod:`bench.study.cells`) and the sweeps
(:mod:`bench.evaluate.sweeps`) share. An image's corner error is the mean over the 4 corners of
the distance (px) to the projected true corner; the pose errors are the angle (deg) between the
estimated and the true rotation and the distance (mm) between the translations.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.detect import DetectorConfig, detect_markers
from pipeline.pose import estimate_pose
from scenes.camera import FisheyeCamera
from scenes.conventions import marker_corners_marker, rotation_angle_deg, transform_points

#: The per-image error columns :func:`score_corners` fills (NaN where there is no value).
ERRORS = ("corner_err_px", "rot_err_deg", "trans_err_mm", "ambiguity_ratio")


@dataclass(frozen=True)
class MarkerTruth:
    """What was rendered: the marker's id, side (mm), ``T_cam_marker`` and its corners.

    ``corners_px``: (4, 2) float64, (x, y), in the full frame, ArUco corner order.
    """

    marker_id: int
    size_mm: float
    T_cam_marker: np.ndarray
    corners_px: np.ndarray

    @classmethod
    def of(
        cls, lens: FisheyeCamera, marker_id: int, size_mm: float, T_cam_marker: np.ndarray
    ) -> MarkerTruth:
        """The truth of a marker at that pose, its corners projected through ``lens``."""
        corners = lens.project(transform_points(T_cam_marker, marker_corners_marker(size_mm)))
        return cls(marker_id, size_mm, T_cam_marker, corners)


def find_marker(
    image: np.ndarray,
    detector: DetectorConfig,
    origin_px: tuple[int, int],
    truth: MarkerTruth,
    lens: FisheyeCamera,
) -> tuple[int, list[np.ndarray]]:
    """(number of detections of any id, the (4, 2) corners of each detection of the truth's id).

    ``image`` is a crop whose top-left pixel is ``origin_px`` in the full frame.
    """
    detections = detect_markers(image, detector, origin_px, camera=lens)
    return len(detections), [d.corners_px for d in detections if d.marker_id == truth.marker_id]


def score_corners(
    corners_px: np.ndarray, truth: MarkerTruth, lens: FisheyeCamera, pose_method: str = "virtual"
) -> tuple[dict[str, float], bool]:
    """(the :data:`ERRORS` of detected corners, whether a pose was solved).

    Without a pose (:func:`pipeline.pose.estimate_pose` raised, e.g. ``"fisheye"`` at or past
    90 deg, or returned a non-finite pose) the pose columns are NaN.
    """
    nan = float("nan")
    errors = dict.fromkeys(ERRORS, nan)
    errors["corner_err_px"] = float(np.linalg.norm(corners_px - truth.corners_px, axis=1).mean())
    try:
        pose = estimate_pose(corners_px, truth.size_mm, lens, pose_method)
    except ValueError:
        return errors, False
    T, T_gt = pose.T_cam_marker, truth.T_cam_marker
    if not np.isfinite(T).all():  # IPPE can return NaN without raising
        return errors, False
    errors["rot_err_deg"] = rotation_angle_deg(T[:3, :3], T_gt[:3, :3])
    errors["trans_err_mm"] = float(np.linalg.norm(T[:3, 3] - T_gt[:3, 3]))
    errors["ambiguity_ratio"] = pose.ambiguity_ratio
    return errors, True
