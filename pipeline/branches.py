"""Branch finding from marker poses: the stages of SPEC 3 after per-marker pose estimation.

Every stage is a small vectorized NumPy function over plain arrays. Axis conventions:

``F``
    frames of one sample, in time order;
``n``
    whiskers in array order, left to right in the image (index 0 .. n-1);
``R_cam_marker`` (F, n, 3, 3), ``t_cam_marker`` (F, n, 3) in mm
    the marker poses T_cam_marker (frames and notation: :mod:`scenes.conventions`), NaN where
    the marker was not seen in that frame.

Stages: from :mod:`pipeline.deflection` ``no_contact_pose`` (T_cam_marker0, online),
``deflection_vectors`` (translation of T_marker0_marker) and ``deflection_mm`` (SPEC 3.1),
``contact`` (3.2); here :func:`aggregate` (3.3), :func:`candidates` (3.4), :func:`peaks`,
:func:`refine` (3.5); :func:`estimate_branches` composes them. :func:`foliage_threshold` is
the paper's fixed threshold and :func:`online_threshold` infers one from the sample itself.

Sign of the marker x axis: a marker's +x points towards increasing whisker index (to the right
along the arc, the whisking direction). The marker sits behind the pivot, so it moves opposite to
the tip: a tip pushed left (towards lower indices) by ``theta`` moves its marker by
``+8 mm * sin(theta)`` along x (:mod:`scenes.array`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from pipeline.deflection import (
    check_baseline,
    contact,
    deflection_mm,
    deflection_vectors,
    no_contact_pose,
)

#: Names accepted by :func:`aggregate`.
AGGREGATIONS = ("integration", "max", "mean", "median", "laplacian", "gaussian")

#: Scale of the median absolute deviation to a standard deviation for normal data.
MAD_TO_SIGMA = 1.4826


def _contact_values(deflection: np.ndarray, in_contact: np.ndarray) -> np.ndarray:
    """(F, n) deflections of contact frames, NaN elsewhere; all 0 for a whisker never in it."""
    values = np.where(in_contact, deflection, np.nan)
    values[:, ~in_contact.any(axis=0)] = 0.0
    return values


def max_in_contact(deflection: np.ndarray, in_contact: np.ndarray) -> np.ndarray:
    """(n,) mm: per whisker the maximum deflection over its contact frames; 0 if none."""
    return np.nanmax(_contact_values(deflection, in_contact), axis=0)


def _integration(deflection: np.ndarray, in_contact: np.ndarray) -> np.ndarray:
    """SPEC 3.3: per-whisker sums over contact frames, scaled so their max is the max deflection."""
    sums = np.where(in_contact, deflection, 0.0).sum(axis=0)
    peak = sums.max()
    if peak <= 0:
        return np.zeros_like(sums)
    return sums * (max_in_contact(deflection, in_contact).max() / peak)


def _laplacian(per_whisker: np.ndarray) -> np.ndarray:
    """Negated discrete 1-D Laplacian 2 m_i - m_(i-1) - m_(i+1) across whiskers, clipped at 0.

    Negated so that a peak stays a positive peak; the edges repeat the end value (a missing
    neighbour equals the whisker itself), so an end whisker scores m_0 - m_1.
    """
    padded = np.pad(per_whisker, 1, mode="edge")
    return np.clip(2.0 * per_whisker - padded[:-2] - padded[2:], 0.0, None)


def _gaussian(per_whisker: np.ndarray, sigma: float = 1.0) -> np.ndarray:
    """Gaussian smoothing across whiskers (sigma in whiskers, untruncated kernel).

    At the ends the kernel's weights outside the array are dropped and the rest renormalized
    to sum 1, so a constant curve stays constant.
    """
    index = np.arange(per_whisker.size)
    weights = np.exp(-0.5 * ((index[:, None] - index[None, :]) / sigma) ** 2)
    return (weights / weights.sum(axis=1, keepdims=True)) @ per_whisker


def aggregate(deflection: np.ndarray, in_contact: np.ndarray, method: str) -> np.ndarray:
    """(n,) curve across whiskers from (F, n) deflections in mm and (F, n) contact (SPEC 3.3).

    ``integration``: per whisker the sum of deflections over contact frames, scaled so that the
    curve's maximum equals the largest per-whisker maximum deflection in contact (all 0 if no
    contact at all). ``max``, ``mean``, ``median``: over contact frames, 0 for a whisker never in
    contact. ``laplacian``: :func:`_laplacian` of the per-whisker max. ``gaussian``:
    :func:`_gaussian` (sigma 1 whisker) of the per-whisker max.
    """
    if method not in AGGREGATIONS:
        raise ValueError(f"unknown aggregation {method!r}; choose one of {', '.join(AGGREGATIONS)}")
    if method == "integration":
        return _integration(deflection, in_contact)
    if method == "mean":
        return np.nanmean(_contact_values(deflection, in_contact), axis=0)
    if method == "median":
        return np.nanmedian(_contact_values(deflection, in_contact), axis=0)
    per_whisker_max = max_in_contact(deflection, in_contact)
    if method == "laplacian":
        return _laplacian(per_whisker_max)
    if method == "gaussian":
        return _gaussian(per_whisker_max)
    return per_whisker_max


def candidates(max_deflection: np.ndarray, curve: np.ndarray, threshold_mm: float) -> np.ndarray:
    """(n,) bool, SPEC 3.4: the maximum deflection or the curve value exceeds the threshold."""
    return (max_deflection > threshold_mm) | (curve > threshold_mm)


def peaks(curve: np.ndarray, candidate: np.ndarray) -> list[int]:
    """Whisker indices of the local maxima of ``curve`` that are candidates, left to right.

    Local maxima of the whole curve: a plateau (a run of equal values, possibly one whisker)
    is a peak when each neighbour it has is strictly lower; an end of the array counts as a
    missing neighbour, so endpoints can be peaks, but a constant curve has none. A plateau
    counts once, kept if any of its whiskers is a candidate and reported at its middle whisker
    (the left one of the two middles for an even length).
    """
    curve = np.asarray(curve, dtype=float)
    starts = np.flatnonzero(np.r_[True, curve[1:] != curve[:-1]])
    if starts.size < 2:
        return []
    ends = np.r_[starts[1:], curve.size] - 1
    level = curve[starts]
    higher_than_left = np.r_[True, level[1:] > level[:-1]]
    higher_than_right = np.r_[level[:-1] > level[1:], True]
    has_candidate = np.logical_or.reduceat(np.asarray(candidate, bool), starts)
    keep = higher_than_left & higher_than_right & has_candidate
    return [int(i) for i in (starts[keep] + ends[keep]) // 2]


def contact_x_integrals(vectors: np.ndarray, in_contact: np.ndarray) -> np.ndarray:
    """(n,) mm: per whisker the sum over contact frames of the marker-frame x deflection."""
    return np.where(in_contact, vectors[..., 0], 0.0).sum(axis=0)


def refine(peak_indices: Sequence[int], x_integrals: np.ndarray) -> list[tuple[int, int]]:
    """SPEC 3.5: move each peak whisker to the gap between two whiskers; sorted, no duplicates.

    The gap (i, i+1) scores ``d_i = x_integrals[i+1] - x_integrals[i]`` (``np.diff``, right
    minus left) of the *marker* x integrals. Across a branch the left tip is pushed left and
    the right tip right (apart); the markers, behind the pivots, move the other way, so the
    left marker's integral is positive and the right one's negative: d_i < 0. That is SPEC's
    "negative difference (pushed apart)", read as right minus left in marker coordinates
    (equivalently left minus right of the tip displacements, which are minus the marker's).
    A peak whisker p takes the more negative of its gaps (p-1, p) and (p, p+1) that exist
    (the left one on a tie); it is moved even when neither difference is negative, since a
    branch always lies between two whiskers.
    """
    d = np.diff(np.asarray(x_integrals, dtype=float))
    gaps = set()
    for p in peak_indices:
        options = [i for i in (p - 1, p) if 0 <= i < d.size]
        left = min(options, key=lambda i: d[i])
        gaps.add((left, left + 1))
    return sorted(gaps)


@dataclass(frozen=True)
class BranchEstimate:
    """The result of :func:`estimate_branches` for one sample (arrays over whiskers n, frames F)."""

    gaps: list[tuple[int, int]]  # refined branch estimates: between whiskers (i, i+1)
    peaks: list[int]  # peak whiskers of the curve among candidates
    curve: np.ndarray  # (n,) aggregated curve, mm
    max_deflection: np.ndarray  # (n,) max deflection in contact, mm
    candidate: np.ndarray  # (n,) bool
    x_integrals: np.ndarray  # (n,) sum of marker x deflection over contact frames, mm
    contact: np.ndarray  # (F, n) bool
    deflection: np.ndarray  # (F, n) mm, NaN where unseen
    unseen_markers: list[int]  # whiskers whose marker was never seen
    threshold_mm: float
    aggregation: str


def estimate_branches(
    R_cam_marker: np.ndarray,
    t_cam_marker: np.ndarray,
    threshold_mm: float,
    aggregation: str = "integration",
    baseline_frames: int = 10,
    contact_threshold_mm: float = 1.0,
    contact_window: int = 4,
) -> BranchEstimate:
    """SPEC 3 from marker poses R_cam_marker (F, n, 3, 3), t_cam_marker (F, n, 3) mm (NaN where
    unseen).

    ValueError when there are no no-contact frames to start from (:func:`check_baseline`).
    """
    pose = no_contact_pose(R_cam_marker, t_cam_marker, baseline_frames)
    vectors = deflection_vectors(t_cam_marker, pose.R0, pose.t0)
    deflection = deflection_mm(vectors)
    check_baseline(vectors, baseline_frames, contact_threshold_mm)
    in_contact = contact(vectors, contact_threshold_mm, contact_window)
    curve = aggregate(deflection, in_contact, aggregation)
    max_deflection = max_in_contact(deflection, in_contact)
    candidate = candidates(max_deflection, curve, threshold_mm)
    peak_whiskers = peaks(curve, candidate)
    x_int = contact_x_integrals(vectors, in_contact)
    return BranchEstimate(
        gaps=refine(peak_whiskers, x_int),
        peaks=peak_whiskers,
        curve=curve,
        max_deflection=max_deflection,
        candidate=candidate,
        x_integrals=x_int,
        contact=in_contact,
        deflection=deflection,
        unseen_markers=[int(i) for i in np.flatnonzero(pose.unseen)],
        threshold_mm=float(threshold_mm),
        aggregation=aggregation,
    )


def foliage_threshold(deflection: np.ndarray) -> float:
    """The paper's fixed threshold (SPEC 3.4) from a foliage-only sample, in mm.

    "The highest deflection measured when sampling the same foliage with no branch": the
    largest of (F, n) ``deflection`` over every seen frame and whisker, in contact or not (soft
    foliage may never pass the 1 mm contact filter, and a threshold of 0 would make every
    touch a candidate); 0.0 if no marker was seen. Concatenate the frames of several foliage
    samples to pool them.
    """
    deflection = np.asarray(deflection, dtype=float)
    seen = deflection[np.isfinite(deflection)]
    return float(seen.max()) if seen.size else 0.0


def online_threshold(
    deflection: np.ndarray,
    *,
    k: float = 3.0,
    min_relative_spread: float = 0.1,
    floor_mm: float = 1.0,
) -> float:
    """A threshold inferred from the sample itself, in mm (the paper's future work).

    Most whiskers touch only foliage; a branch touches one or two neighbours. So across the
    whiskers, each one's foliage level is mostly foliage, and branch whiskers are high outliers.
    A whisker's level is its maximum deflection over all frames in which it was seen (whiskers
    never seen are left out): unlike the maximum in contact it is not censored to 0 for a
    whisker whose foliage stayed just under the contact filter, which would drag the median
    to 0 and inflate the MAD. The threshold is an outlier fence with robust statistics, which
    the outliers barely move (the median breaks down only at half the whiskers)::

        max(floor_mm, median + k * max(1.4826 * MAD, min_relative_spread * median))

    1.4826 * MAD estimates the foliage's standard deviation across whiskers;
    ``min_relative_spread`` keeps the fence above the median when the foliage is so uniform
    that the MAD is near 0 (else half of the foliage whiskers would become candidates);
    ``floor_mm`` (default: SPEC's 1 mm contact threshold) keeps the fence from collapsing when
    the whiskers barely move. On a foliage-only sample no whisker is expected above the fence,
    so the sample gives no estimate. It cannot tell a branch from foliage that hits only one or
    two whiskers much harder than all the others.
    """
    seen = np.isfinite(deflection).any(axis=0)
    if not seen.any():
        return float(floor_mm)
    levels = np.nanmax(deflection[:, seen], axis=0)
    median = float(np.median(levels))
    mad = float(np.median(np.abs(levels - median)))
    spread = max(MAD_TO_SIGMA * mad, min_relative_spread * median)
    return max(float(floor_mm), median + k * spread)


def whisker_of_marker(marker_ids: Sequence[int], array_marker_ids: Sequence[int]) -> np.ndarray:
    """(m,) int whisker index of each marker id; ValueError for an id not on the array."""
    ids = np.asarray(marker_ids, dtype=int).reshape(-1)
    matches = ids[:, None] == np.asarray(array_marker_ids, dtype=int)[None, :]
    missing = ids[~matches.any(axis=1)]
    if missing.size:
        raise ValueError(f"marker ids not on the array: {sorted(set(missing.tolist()))}")
    return np.argmax(matches, axis=1)
