"""Per-whisker deflection and contact from marker poses: SPEC 3.1 and 3.2.

Axis conventions as in :mod:`pipeline.branches` (``F`` frames, ``n`` whiskers; ``R_cam_marker``
(F, n, 3, 3) and ``t_cam_marker`` (F, n, 3) mm, NaN where a marker was not seen).
:func:`no_contact_pose` estimates each marker's resting pose T_cam_marker0 from the first frames
(refusing a sample already in contact), :func:`deflection_vectors` gives the translation of
T_marker0_marker, :func:`deflection_mm` its size and :func:`contact` the frames in contact.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view


class NoContactPose(NamedTuple):
    """The no-contact pose T_cam_marker0 per marker; unpacks as ``R0, t0, first_frame``."""

    R0: np.ndarray  # (n, 3, 3), NaN for a marker never seen
    t0: np.ndarray  # (n, 3) mm, NaN for a marker never seen
    first_frame: np.ndarray  # (n,) int, first frame the marker was seen in; -1 if never

    @property
    def unseen(self) -> np.ndarray:
        """(n,) bool: markers never seen, which have no no-contact pose."""
        return self.first_frame < 0


def _seen_poses(R_cam_marker: np.ndarray, t_cam_marker: np.ndarray) -> np.ndarray:
    """(F, n) bool: frames in which the marker's full pose is finite."""
    return np.isfinite(t_cam_marker).all(axis=-1) & np.isfinite(R_cam_marker).all(axis=(-2, -1))


def _baseline(seen: np.ndarray, baseline_frames: int) -> np.ndarray:
    """(F, n) bool: each marker's first ``baseline_frames`` seen frames."""
    return seen & (np.cumsum(seen, axis=0) <= baseline_frames)


class NoBaselineError(ValueError):
    """The sample has no no-contact frames at its start to measure deflections from."""


def check_baseline(vectors: np.ndarray, baseline_frames: int, limit_mm: float) -> None:
    """NoBaselineError if a marker drifts more than ``limit_mm`` across its baseline frames.

    The online no-contact pose assumes the sample starts in free air. A video that starts with
    the array moving through foliage has no no-contact frames: its deflections would be measured
    from a bent pose, a silent wrong answer. The drift of a marker is the Theil-Sen slope (the
    median of the pairwise slopes, per axis) of its (x, y) deflection over its baseline frames,
    times their time span: pose noise and single-frame jumps of unrefined corners barely move
    a median slope; a whisker being pushed does. (A video that starts in static contact cannot
    be told from one at rest; only motion gives it away.)
    """
    xy = vectors[..., :2]
    seen = np.isfinite(xy).all(axis=-1)
    base = _baseline(seen, baseline_frames)
    frame = np.argsort(~base, axis=0, kind="stable")[:baseline_frames]  # (B, n) baseline first
    in_base = np.take_along_axis(base, frame, axis=0)
    packed = np.take_along_axis(xy, frame[..., None], axis=0)  # (B, n, 2)
    i, j = np.triu_indices(len(frame), k=1)
    pair = in_base[i] & in_base[j]  # (P, n)
    dt = np.where(pair, frame[j] - frame[i], 1)
    slopes = np.where(pair[..., None], (packed[j] - packed[i]) / dt[..., None], np.nan)
    span = np.where(in_base, frame, 0).max(axis=0) - np.where(in_base, frame, len(xy)).min(axis=0)
    usable = in_base.sum(axis=0) >= 4
    drift = np.zeros(len(usable))
    if usable.any():
        slope = np.nanmedian(slopes[:, usable], axis=0)  # (u, 2) mm per frame
        drift[usable] = np.hypot(slope[:, 0], slope[:, 1]) * span[usable]
    bad = np.flatnonzero(drift > limit_mm)
    if bad.size:
        raise NoBaselineError(
            f"no no-contact frames at the start: the markers of whiskers {bad.tolist()} move "
            f"{drift.max():.1f} mm across their first {baseline_frames} frames (limit "
            f"{limit_mm:g} mm); the pipeline needs the whiskers in free air at the start"
        )


def _project_to_rotation(M: np.ndarray) -> np.ndarray:
    """(..., 3, 3) nearest proper rotations (Frobenius norm) to the matrices ``M``."""
    U, _, Vt = np.linalg.svd(M)
    D = np.ones(M.shape[:-1])
    D[..., 2] = np.sign(np.linalg.det(U @ Vt))
    return (U * D[..., None, :]) @ Vt


def no_contact_pose(
    R_cam_marker: np.ndarray, t_cam_marker: np.ndarray, baseline_frames: int = 10
) -> NoContactPose:
    """T_cam_marker0 per marker from the first ``baseline_frames`` frames the marker was seen in.

    Online (SPEC 3.1): only the start of the sample is used, assumed contact-free (the
    whiskers are in free air before the sweep starts); a marker that appears late takes its
    first frames wherever they are. Translation: the mean of those frames' t_cam_marker.
    Rotation: the chordal L2 mean, i.e. the mean of the rotation matrices projected back onto
    SO(3) by SVD (a proper rotation average, exact for rotations symmetric about a common one).

    R_cam_marker (F, n, 3, 3), t_cam_marker (F, n, 3) mm, NaN where unseen. A marker never seen
    gets NaN and ``first_frame`` -1 (``.unseen``); NoBaselineError if no marker was seen in any
    frame.
    """
    if baseline_frames < 1:
        raise ValueError(f"baseline_frames must be >= 1, got {baseline_frames}")
    seen = _seen_poses(R_cam_marker, t_cam_marker)
    if not seen.any():  # the sample's to refuse, not the run's: a NoBaselineError
        raise NoBaselineError(
            "no marker seen in any frame: no no-contact frames to take T_cam_marker0 from"
        )
    baseline = _baseline(seen, baseline_frames)
    count = baseline.sum(axis=0)  # (n,)
    unseen = count == 0
    weight = baseline / np.maximum(count, 1)  # (F, n), each seen column sums to 1
    t0 = np.einsum("fn,fni->ni", weight, np.where(baseline[..., None], t_cam_marker, 0.0))
    R_mean = np.einsum(
        "fn,fnij->nij", weight, np.where(baseline[..., None, None], R_cam_marker, 0.0)
    )
    R_mean[unseen] = np.eye(3)  # keeps the SVD finite; replaced by NaN below
    R0 = _project_to_rotation(R_mean)
    R0[unseen], t0[unseen] = np.nan, np.nan
    first_frame = np.where(unseen, -1, np.argmax(seen, axis=0))
    return NoContactPose(R0, t0, first_frame)


def deflection_vectors(t_cam_marker: np.ndarray, R0: np.ndarray, t0: np.ndarray) -> np.ndarray:
    """(F, n, 3) mm: translation of T_marker0_marker = inv(T_cam_marker0) @ T_cam_marker, i.e.
    R0^T (t_cam_marker - t0).

    The marker's own rotation R_cam_marker does not enter the translation of T_marker0_marker
    (SPEC 3.1 uses only the translation), so only t_cam_marker is taken. NaN where the marker
    was not seen.
    """
    return np.einsum("nji,fnj->fni", R0, t_cam_marker - t0)


def deflection_mm(vectors: np.ndarray) -> np.ndarray:
    """(...,) deflection sqrt(x^2 + y^2) mm of (..., 3) T_marker0_marker translations (SPEC 3.1)."""
    return np.hypot(vectors[..., 0], vectors[..., 1])


def _trailing_mean_of_seen(values: np.ndarray, window: int) -> np.ndarray:
    """(F, n, k) mean of the last ``window`` seen values (the current one included).

    ``values`` (F, n, k) is NaN where unseen; fewer values are averaged at the start of a
    column. The result is NaN in unseen frames.
    """
    n_frames = values.shape[0]
    seen = np.isfinite(values).all(axis=-1)  # (F, n)
    order = np.argsort(~seen, axis=0, kind="stable")  # seen frames first, in time order
    packed = np.take_along_axis(values, order[..., None], axis=0)
    padded = np.concatenate([np.full((window - 1,) + values.shape[1:], np.nan), packed])
    windows = sliding_window_view(padded, window, axis=0)[:n_frames]  # (F, n, k, window)
    valid = np.isfinite(windows)
    total = np.where(valid, windows, 0.0).sum(axis=-1)
    mean = total / np.maximum(valid.sum(axis=-1), 1)  # (F, n, k) per packed position
    rank = np.maximum(np.cumsum(seen, axis=0) - 1, 0)  # packed position of each frame
    out = np.take_along_axis(mean, rank[..., None], axis=0)
    return np.where(seen[..., None], out, np.nan)


def contact(vectors: np.ndarray, threshold_mm: float = 1.0, window: int = 4) -> np.ndarray:
    """(F, n) bool: SPEC 3.2 contact from (F, n, 3) deflection vectors in mm.

    A frame is contact for a whisker when the norm of the mean (x, y) deflection vector over
    its last ``window`` measurements (this frame and the previous frames in which the marker
    was seen; fewer at the start of the sample) exceeds ``threshold_mm``. Averaging vectors,
    not norms, cancels whisker oscillation; the window filters single-frame jerks. A frame in
    which the marker was not seen is not contact (there is no measurement to count).
    """
    if window < 1:
        raise ValueError(f"window must be >= 1, got {window}")
    mean_xy = _trailing_mean_of_seen(vectors[..., :2], window)
    norm = np.hypot(mean_xy[..., 0], mean_xy[..., 1])
    return np.where(np.isfinite(norm), norm > threshold_mm, False)
