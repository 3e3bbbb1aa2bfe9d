"""Per-frame marker detection and pose over a video: the table the branch estimation reads.

One row per frame and detected marker of the array (ids not on the array are dropped and
counted); the columns are :data:`scenes.tables.TRACK`: corners, the pose T_cam_marker and its
quality, the detector backend's own pose where it has one and whether the refinement fell back.
They match the labels' (bench.dataset.labels): detections and truth join on
:data:`scenes.tables.JOIN_KEY`.

A frame on which a peer backend crashes (:class:`pipeline.backends.BackendCrashError`: its
worker died or hung) has no detections and is listed in ``TrackResult.failed_frames``; the run
goes on with a fresh worker.
"""

from __future__ import annotations

import dataclasses
from collections import Counter
from collections.abc import Container, Iterable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from pipeline.backends import BackendCrashError, get_backend
from pipeline.detect import Detection, DetectorConfig, detect_markers
from pipeline.pose import PoseEstimate, estimate_pose
from scenes.camera import FisheyeCamera
from scenes.tables import (
    OWN_POSE_PREFIX,
    TRACK,
    corner_values,
    ordered,
    pose_values,
    rotations_of,
    translations_of,
)

if TYPE_CHECKING:
    import pandas as pd


@dataclass(frozen=True)
class MarkerSet:
    """What the pipeline knows of the array: marker ids in whisker order, and their size."""

    marker_ids: tuple[int, ...]
    size_mm: float

    def __post_init__(self) -> None:
        if len(set(self.marker_ids)) != len(self.marker_ids) or not self.marker_ids:
            raise ValueError(f"marker_ids={self.marker_ids}: need distinct ids")
        if not self.size_mm > 0:
            raise ValueError(f"size_mm={self.size_mm}: must be > 0")


@dataclass
class TrackResult:
    detections: pd.DataFrame
    frames: int
    foreign_ids: int  # detections of ids not on the array, or repeated in a frame (false)
    pose_failures: int
    #: Frames on which a backend crashed, in order (the detector's: no detections there; the
    #: recovery's: only the detector's).
    failed_frames: list[int] = field(default_factory=list)
    #: Why refinement "lines" kept the backend's corners: reason -> detections.
    refine_failures: Counter[str] = field(default_factory=Counter)


SEARCHES = ("full", "roi")


@dataclass(frozen=True)
class Search:
    """Where to look. ``"full"``: the whole frame (its image circle), every frame. ``"roi"``:
    only the box around the markers' last corners (plus ``margin_px``); the whole frame to
    (re)acquire: on the first frame, after a tracked marker is lost, and every
    ``reacquire_every`` frames while fewer than all markers are tracked.

    ``recover``: a second backend (or ``"none"``) that looks again, in its box of the previous
    frame, for each marker the detector lost in this frame. Detectors miss different markers
    (a leaf's edge across the border, a glint), so the second look costs a few small crops on
    the frames where a marker is lost and nothing elsewhere."""

    mode: str = "full"
    margin_px: int = 48
    reacquire_every: int = 15
    recover: str = "none"

    def __post_init__(self) -> None:
        if self.mode not in SEARCHES:
            raise ValueError(f"search={self.mode!r}: choose from {', '.join(SEARCHES)}")
        if self.recover != "none":
            get_backend(self.recover)
        if self.margin_px < 0 or self.reacquire_every < 1:
            raise ValueError("need margin_px >= 0 and reacquire_every >= 1")


def track(
    frames: Iterable[np.ndarray],
    camera: FisheyeCamera,
    markers: MarkerSet,
    detector: DetectorConfig,
    search: Search = Search(),
    pose_method: str = "virtual",
) -> TrackResult:
    """Detect the array's markers and estimate their poses in every frame; the backend's own
    pose is asked for where it has one."""
    whisker_of = {m: i for i, m in enumerate(markers.marker_ids)}
    recover = recovery_detector(detector, search.recover)
    rows: list[_Row] = []
    foreign = failures = n_frames = 0
    crashed: list[int] = []
    refine_failures: Counter[str] = Counter()
    last: dict[int, np.ndarray] = {}  # marker id -> corners in the previous frame
    since_full = 0
    circle = camera.image_circle_box()  # the "full frame": nothing outside it can be seen
    if get_backend(detector.backend).whole_frame:  # a plugin: its own pose needs the frame
        circle = (0, 0, camera.width_px, camera.height_px)
    for f, frame in enumerate(frames):
        n_frames += 1
        if frame.shape[:2] != (camera.height_px, camera.width_px):
            raise ValueError(
                f"frame {f} is {frame.shape[1]}x{frame.shape[0]} px but the camera model is "
                f"{camera.width_px}x{camera.height_px}"
            )
        box = None
        if search.mode == "roi" and last:
            complete = len(last) == len(whisker_of)
            if complete or since_full < search.reacquire_every:
                box = _box(np.concatenate(list(last.values())), frame.shape, search.margin_px)
        roi = box is not None
        since_full = since_full + 1 if roi else 0
        box = box if roi else circle
        candidates: list[tuple[Detection, Container[int]]] = []  # and the ids it may be
        try:
            candidates += [(d, whisker_of) for d in _detect(frame, box, detector, camera, markers)]
            lost = set(last) - {d.marker_id for d, _ in candidates} if recover else ()
            for marker_id in sorted(lost):
                near = _box(last[marker_id], frame.shape, search.margin_px)
                candidates += [
                    (d, (marker_id,)) for d in _detect(frame, near, recover, camera, markers)
                ]
        except BackendCrashError:
            crashed.append(f)
        seen: dict[int, np.ndarray] = {}
        for det, wanted in candidates:
            if det.marker_id not in wanted or det.marker_id in seen:
                foreign += 1  # not on the array, or a second detection of one marker
                continue
            if det.refine_failure is not None:
                refine_failures[det.refine_failure] += 1
            try:
                pose = estimate_pose(det.corners_px, markers.size_mm, camera, pose_method)
            except ValueError:
                failures += 1
                continue
            seen[det.marker_id] = det.corners_px
            rows.append(_Row(f, whisker_of[det.marker_id], det, pose))
        if roi and set(last) - set(seen):
            since_full = search.reacquire_every  # a tracked marker was lost: search it all next
        last = seen
    return TrackResult(_table(rows), n_frames, foreign, failures, crashed, refine_failures)


def recovery_detector(detector: DetectorConfig, backend: str) -> DetectorConfig | None:
    """The detector that looks again for lost markers: ``backend`` on the same family, with the
    same refinement where it offers it (else its own corners, or ``lines`` if asked for)."""
    if backend == "none":
        return None
    keep = backend == "opencv" or detector.corner_refinement == "lines"
    refinement = detector.corner_refinement if keep else "none"
    return dataclasses.replace(detector, backend=backend, corner_refinement=refinement)


def _detect(
    frame: np.ndarray,
    box: tuple[int, int, int, int],
    detector: DetectorConfig,
    camera: FisheyeCamera,
    markers: MarkerSet,
) -> list[Detection]:
    x0, y0, x1, y1 = box
    return detect_markers(
        frame[y0:y1, x0:x1], detector, (x0, y0), camera, own_pose_size_mm=markers.size_mm
    )


def _box(corners: np.ndarray, shape: tuple[int, ...], margin: int) -> tuple[int, int, int, int]:
    """(x0, y0, x1, y1) of the corners plus margin, clipped to the image (x1, y1 exclusive)."""
    lo = np.floor(corners.min(axis=0)).astype(int) - margin
    hi = np.ceil(corners.max(axis=0)).astype(int) + margin + 1
    return (max(lo[0], 0), max(lo[1], 0), min(hi[0], shape[1]), min(hi[1], shape[0]))


class _Row(NamedTuple):
    frame: int
    whisker: int
    detection: Detection
    pose: PoseEstimate


def _table(rows: list[_Row]) -> pd.DataFrame:
    """The rows as a :data:`scenes.tables.TRACK` table (its dtypes even when empty)."""
    import pandas as pd

    n = len(rows)
    none = np.full((4, 4), np.nan)  # a backend without a pose of its own
    own = [none if r.detection.own_T_cam_marker is None else r.detection.own_T_cam_marker
           for r in rows]  # fmt: skip
    values = {
        "frame": [r.frame for r in rows],
        "marker_id": [r.detection.marker_id for r in rows],
        "whisker": [r.whisker for r in rows],
        **corner_values(np.array([r.detection.corners_px for r in rows]).reshape(n, 4, 2)),
        **pose_values(np.array([r.pose.T_cam_marker for r in rows]).reshape(n, 4, 4)),
        "reprojection_err_px": [r.pose.reprojection_err_px for r in rows],
        "ambiguity_ratio": [r.pose.ambiguity_ratio for r in rows],
        **pose_values(np.array(own).reshape(n, 4, 4), OWN_POSE_PREFIX),
        "refine_failed": [r.detection.refine_failure is not None for r in rows],
    }
    return pd.DataFrame(ordered(TRACK, values))


def pose_arrays(
    table: pd.DataFrame, n_frames: int, n_whiskers: int
) -> tuple[np.ndarray, np.ndarray]:
    """(R_cam_marker (F, n, 3, 3), t_cam_marker (F, n, 3) mm) from a detections or labels table;
    NaN where unseen."""
    R_cam_marker = np.full((n_frames, n_whiskers, 3, 3), np.nan)
    t_cam_marker = np.full((n_frames, n_whiskers, 3), np.nan)
    f = table["frame"].to_numpy()
    w = table["whisker"].to_numpy()
    R_cam_marker[f, w] = rotations_of(table)
    t_cam_marker[f, w] = translations_of(table)
    return R_cam_marker, t_cam_marker
