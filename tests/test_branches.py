"""Tests of the SPEC 3 branch-finding stages (pipeline.branches) on hand-made inputs.

Whole samples are built from the scene's own physics (:mod:`scenes.array`): deflection angles
per frame and whisker go through ``T_cam_marker`` to marker poses, so the sign of the marker's
x deflection (opposite to the tip) is the renderer's, not this module's.
"""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.branches import (
    AGGREGATIONS,
    aggregate,
    candidates,
    estimate_branches,
    foliage_threshold,
    max_in_contact,
    online_threshold,
    peaks,
    refine,
    whisker_of_marker,
)
from pipeline.deflection import contact, deflection_mm, deflection_vectors, no_contact_pose
from scenes.array import ArraySpec, T_cam_marker, T_marker0_marker
from scenes.conventions import invert_T, make_T, rot_x, rot_y

SPEC = ArraySpec()
N = SPEC.n_whiskers
MARKER_OFFSET_MM = SPEC.marker_offset_mm

# --- Synthetic samples from the scene's physics

N_FRAMES = 100
BASELINE = 10  # frames in free air before the sweep
BRANCH_ANGLE_RAD = 0.6  # 8 mm * sin(0.6) = 4.5 mm of marker travel
PASSES = ((20, 46), (60, 86))  # frames in which a branch holds its two whiskers apart


def _foliage_angles(seed: int = 0) -> np.ndarray:
    """(F, n, 2) angles of foliage-only whisking: small oscillations of both signs."""
    rng = np.random.default_rng(seed)
    frames = np.arange(N_FRAMES)[:, None]
    amplitude = rng.uniform(0.08, 0.15, N)  # marker travel up to 1.2 mm
    phase = rng.uniform(0, 2 * np.pi, N)
    angles = np.zeros((N_FRAMES, N, 2))
    angles[..., 0] = amplitude * np.sin(2 * np.pi * frames / 40 + phase)
    angles[..., 1] = 0.3 * amplitude * np.cos(2 * np.pi * frames / 25 + phase)
    angles[:BASELINE] = 0.0
    return angles


def _add_branch(angles: np.ndarray, left: int) -> np.ndarray:
    """Plant a rigid branch between whiskers ``left`` and ``left + 1``: tips pushed apart."""
    angles = angles.copy()
    for start, stop in PASSES:
        ramp = np.sin(np.linspace(0, np.pi, stop - start)) * BRANCH_ANGLE_RAD
        angles[start:stop, left, 0] = -ramp  # tip pushed left (towards lower indices)
        angles[start:stop, left + 1, 0] = ramp  # tip pushed right
    return angles


def _poses(angles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(R_cam_marker (F, n, 3, 3), t_cam_marker (F, n, 3)) of the markers for (F, n, 2) angles."""
    T = T_cam_marker(SPEC, angles)
    return T[..., :3, :3], T[..., :3, 3]


def _branch_sample(*lefts: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    angles = _foliage_angles(seed)
    for left in lefts:
        angles = _add_branch(angles, left)
    return _poses(angles)


@pytest.fixture(scope="module")
def fixed_threshold_mm() -> float:
    """The paper's threshold: the highest deflection of the same foliage without branch."""
    estimate = estimate_branches(*_branch_sample(), threshold_mm=np.inf)
    return foliage_threshold(estimate.deflection)


def test_the_scene_moves_the_marker_opposite_to_the_tip():
    # the physics the refinement relies on: tip pushed left (theta_h < 0) -> marker x > 0
    theta = -0.3
    t_marker0_marker = T_marker0_marker(SPEC, np.array([theta, 0.0]))[:3, 3]
    assert t_marker0_marker[0] == pytest.approx(-MARKER_OFFSET_MM * np.sin(theta))
    assert t_marker0_marker[0] > 0


def test_foliage_threshold_is_the_foliage_maximum(fixed_threshold_mm):
    # foliage travel: at most 8 mm * sin(0.15) along x and 8 mm * sin(0.045) along y
    travel = MARKER_OFFSET_MM * np.hypot(np.sin(0.15), np.sin(0.3 * 0.15))
    assert 1.0 < fixed_threshold_mm <= travel


def test_branch_between_3_and_4_is_found(fixed_threshold_mm):
    estimate = estimate_branches(*_branch_sample(3), threshold_mm=fixed_threshold_mm)
    assert estimate.gaps == [(3, 4)]
    assert set(estimate.peaks) <= {3, 4} and estimate.peaks
    assert np.flatnonzero(estimate.candidate).tolist() == [3, 4]
    assert estimate.x_integrals[3] > 0 > estimate.x_integrals[4]  # markers opposite to tips
    assert estimate.max_deflection[[3, 4]] == pytest.approx(
        [MARKER_OFFSET_MM * np.sin(BRANCH_ANGLE_RAD)] * 2, abs=0.05
    )
    assert estimate.unseen_markers == []
    assert estimate.contact.shape == estimate.deflection.shape == (N_FRAMES, N)


def test_two_branches_give_two_gaps(fixed_threshold_mm):
    estimate = estimate_branches(*_branch_sample(3, 8), threshold_mm=fixed_threshold_mm)
    assert estimate.gaps == [(3, 4), (8, 9)]


def test_branch_at_the_array_end(fixed_threshold_mm):
    estimate = estimate_branches(*_branch_sample(11), threshold_mm=fixed_threshold_mm)
    assert estimate.gaps == [(11, 12)]


def test_foliage_only_gives_no_estimate(fixed_threshold_mm):
    estimate = estimate_branches(*_branch_sample(), threshold_mm=fixed_threshold_mm)
    assert estimate.gaps == [] and estimate.peaks == []
    assert not estimate.candidate.any()
    assert estimate.contact.any()  # the foliage does touch: it is the threshold that filters


@pytest.mark.parametrize("aggregation", AGGREGATIONS)
def test_every_aggregation_finds_the_branch(aggregation, fixed_threshold_mm):
    estimate = estimate_branches(
        *_branch_sample(3, 8), threshold_mm=fixed_threshold_mm, aggregation=aggregation
    )
    assert estimate.gaps == [(3, 4), (8, 9)]
    assert estimate.aggregation == aggregation


def test_never_seen_marker_is_reported_and_ignored(fixed_threshold_mm):
    R, t = _branch_sample(3)
    R[:, 9], t[:, 9] = np.nan, np.nan
    estimate = estimate_branches(R, t, threshold_mm=fixed_threshold_mm)
    assert estimate.unseen_markers == [9]
    assert estimate.gaps == [(3, 4)]
    assert np.isnan(estimate.deflection[:, 9]).all()
    assert not estimate.contact[:, 9].any() and estimate.curve[9] == 0


def test_marker_missing_in_some_frames_keeps_the_estimate():
    R, t = _branch_sample(3)
    rng = np.random.default_rng(1)
    dropped = rng.random((N_FRAMES, N)) < 0.2
    R[dropped], t[dropped] = np.nan, np.nan
    # dropped frames change which foliage frames pass the contact filter: a threshold with a
    # margin over the foliage (1.25 mm at most) and under the branch (4.5 mm)
    estimate = estimate_branches(R, t, threshold_mm=2.0)
    assert estimate.gaps == [(3, 4)]
    assert not estimate.contact[dropped].any()


# --- online threshold


@pytest.mark.parametrize("seed", range(5))
@pytest.mark.parametrize("lefts", [(3,), (3, 8)])
def test_online_threshold_separates_planted_branches_from_foliage(seed, lefts):
    R, t = _branch_sample(*lefts, seed=seed)
    blind = estimate_branches(R, t, threshold_mm=np.inf)
    threshold = online_threshold(blind.deflection)
    branch_whiskers = [w for left in lefts for w in (left, left + 1)]
    foliage_max = np.nanmax(np.delete(blind.deflection, branch_whiskers, axis=1))
    assert foliage_max < threshold < blind.max_deflection[branch_whiskers].min()
    expected = [(left, left + 1) for left in lefts]
    assert estimate_branches(R, t, threshold_mm=threshold).gaps == expected


@pytest.mark.parametrize("seed", range(5))
def test_online_threshold_on_foliage_only_gives_no_estimate(seed):
    R, t = _branch_sample(seed=seed)
    blind = estimate_branches(R, t, threshold_mm=np.inf)
    threshold = online_threshold(blind.deflection)
    assert threshold > blind.max_deflection.max()
    assert estimate_branches(R, t, threshold_mm=threshold).gaps == []


def test_online_threshold_on_a_table():
    # per-whisker maxima: foliage 2.0 +- 0.2, one branch whisker at 6; a second, lower frame
    # (NaN where unseen) shows that each whisker's level is its maximum over seen frames
    maxima = np.array([1.8, 2.0, 2.2, 1.9, 2.1, 6.0, 2.0, 1.8, 2.2, 1.9, 2.1, 2.0, 2.0])
    deflection = np.stack([0.5 * maxima, maxima])
    deflection[0, 3] = np.nan
    # median 2.0, MAD 0.1 -> sigma 0.148 < 10% of the median = 0.2 -> fence 2.0 + 3 * 0.2
    assert online_threshold(deflection) == pytest.approx(2.6)
    no_spread_floor = online_threshold(deflection, min_relative_spread=0.0)
    assert no_spread_floor == pytest.approx(2.0 + 3 * 1.4826 * 0.1)
    assert online_threshold(deflection, k=1.0) == pytest.approx(2.2)
    # a never-seen whisker is left out of the statistics (as a 0 it would lower the median)
    assert online_threshold(np.c_[deflection, [np.nan, np.nan]]) == pytest.approx(2.6)
    # whiskers that barely move: the floor
    assert online_threshold(np.full((3, N), 0.3)) == 1.0
    assert online_threshold(np.full((3, N), 0.3), floor_mm=0.2) == pytest.approx(0.39)
    assert online_threshold(np.full((3, N), np.nan)) == 1.0


# --- no-contact pose


def test_no_contact_pose_uses_each_markers_first_seen_frames():
    rng = np.random.default_rng(2)
    F, n = 20, 3
    t = rng.normal(0, 5, (F, n, 3)) + [0.0, 0.0, 200.0]
    R = np.broadcast_to(np.eye(3), (F, n, 3, 3)).copy()
    t[1, 0] = np.nan  # a gap inside marker 0's baseline: it is skipped
    R[:5, 1] = np.nan  # marker 1 appears at frame 5
    t[:, 2] = np.nan  # marker 2 is never seen
    R0, t0, first_frame = pose = no_contact_pose(R, t, baseline_frames=3)
    assert t0[0] == pytest.approx(t[[0, 2, 3], 0].mean(axis=0))
    assert t0[1] == pytest.approx(t[5:8, 1].mean(axis=0))
    assert first_frame.tolist() == [0, 5, -1]
    assert pose.unseen.tolist() == [False, False, True]
    assert np.isnan(R0[2]).all() and np.isnan(t0[2]).all()
    assert R0[:2] == pytest.approx(np.broadcast_to(np.eye(3), (2, 3, 3)))


def test_no_contact_rotation_is_a_proper_rotation_average():
    base = rot_y(0.7) @ rot_x(-0.3)
    tilt = [rot_x(0.2), rot_x(-0.2), rot_y(0.1), rot_y(-0.1)]
    R = np.stack([base @ r for r in tilt])[:, None]  # (4, 1, 3, 3), symmetric about base
    t = np.zeros((4, 1, 3))
    R_mean = no_contact_pose(R, t, baseline_frames=4).R0[0]
    assert R_mean == pytest.approx(base, abs=1e-12)
    assert np.linalg.det(R_mean) == pytest.approx(1.0)


def test_no_contact_pose_needs_frames():
    with pytest.raises(ValueError, match="no no-contact frames"):
        no_contact_pose(np.full((5, 2, 3, 3), np.nan), np.full((5, 2, 3), np.nan))
    with pytest.raises(ValueError, match="no no-contact frames"):
        no_contact_pose(np.zeros((0, 2, 3, 3)), np.zeros((0, 2, 3)))
    with pytest.raises(ValueError, match="baseline_frames"):
        no_contact_pose(np.zeros((5, 2, 3, 3)), np.zeros((5, 2, 3)), baseline_frames=0)


def test_estimate_needs_frames():
    with pytest.raises(ValueError, match="no no-contact frames"):
        estimate_branches(np.full((5, N, 3, 3), np.nan), np.full((5, N, 3), np.nan), 1.0)


# --- deflection


def test_deflection_vectors_recover_the_displacement_in_the_marker_frame():
    T_cam_marker0 = make_T(rot_y(0.7) @ rot_x(-0.3), [10.0, -5.0, 200.0])
    displacement = np.array([1.5, -2.0, 0.3])
    T_cam_marker_ = T_cam_marker0 @ make_T(rot_x(0.2) @ rot_y(-0.1), displacement)  # moved, turned
    vec = deflection_vectors(
        T_cam_marker_[None, None, :3, 3], T_cam_marker0[None, :3, :3], T_cam_marker0[None, :3, 3]
    )
    assert vec.shape == (1, 1, 3)
    assert vec[0, 0] == pytest.approx(displacement)
    assert vec[0, 0] == pytest.approx((invert_T(T_cam_marker0) @ T_cam_marker_)[:3, 3])
    assert deflection_mm(vec)[0, 0] == pytest.approx(2.5)


def test_deflection_matches_the_scene_ground_truth():
    angles = _add_branch(_foliage_angles(), 3)
    R, t = _poses(angles)
    R0, t0, _ = no_contact_pose(R, t)
    vec = deflection_vectors(t, R0, t0)
    assert vec == pytest.approx(T_marker0_marker(SPEC, angles)[..., :3, 3], abs=1e-9)


def test_deflection_mm_is_the_xy_norm():
    assert deflection_mm(np.array([[3.0, 4.0, 12.0], [0.0, 0.0, 7.0]])).tolist() == [5.0, 0.0]


def test_deflection_is_nan_where_unseen():
    t = np.array([[[1.0, 2.0, 3.0]], [[np.nan] * 3]])
    vec = deflection_vectors(t, np.eye(3)[None], np.zeros((1, 3)))
    assert np.isnan(vec[1]).all() and vec[0, 0] == pytest.approx([1.0, 2.0, 3.0])


# --- contact


def _x_series(*x: float) -> np.ndarray:
    """(F, 1, 3) deflection vectors along x for one whisker."""
    vec = np.zeros((len(x), 1, 3))
    vec[:, 0, 0] = x
    return vec


def test_single_frame_spike_is_not_contact():
    # 2 mm in one frame: the 4-frame mean is 0.5 mm
    assert not contact(_x_series(0, 0, 0, 0, 2.0, 0, 0, 0)).any()


def test_sustained_deflection_is_contact():
    # 1.5 mm from frame 4: means 0.375, 0.75, 1.125, 1.5, ... -> contact from frame 6
    in_contact = contact(_x_series(0, 0, 0, 0, 1.5, 1.5, 1.5, 1.5, 1.5))[:, 0]
    assert in_contact.tolist() == [False] * 6 + [True] * 3


def test_contact_averages_vectors_not_norms():
    # whisker oscillation: 1.5 mm alternately left and right has a mean vector near 0
    assert not contact(_x_series(0.0, *[1.5, -1.5] * 6)).any()
    vec = np.zeros((4, 1, 3))
    vec[:, 0, 1] = 1.5  # along y it counts too
    assert contact(vec)[:, 0].all()


def test_contact_uses_fewer_measurements_at_the_start():
    # frame 0 alone: 1.5 mm; frame 1: mean of (1.5, 0) = 0.75 mm
    assert contact(_x_series(1.5, 0.0), threshold_mm=0.7)[:, 0].tolist() == [True, True]
    assert contact(_x_series(1.5, 0.0), threshold_mm=0.8)[:, 0].tolist() == [True, False]


def test_contact_window_counts_seen_measurements_only():
    nan = np.nan
    # last 4 seen at frame 5: frames 0, 1, 2, 5 -> mean 1.5 (frames 2..5 would give 1.0)
    in_contact = contact(_x_series(2.0, 2.0, 2.0, nan, nan, 0.0))[:, 0]
    assert in_contact.tolist() == [True, True, True, False, False, True]
    # last 4 seen at frame 6: frames 1, 2, 3, 6 -> mean 0.75 (frames 3..6 would give 1.5)
    in_contact = contact(_x_series(0.0, 0.0, 0.0, 1.5, nan, nan, 1.5))[:, 0]
    assert in_contact.tolist() == [False, False, False, False, False, False, False]


def test_contact_parameters():
    vec = _x_series(0, 0, 1.5, 1.5)
    assert contact(vec, window=2)[:, 0].tolist() == [False, False, False, True]
    assert contact(vec, threshold_mm=0.4)[:, 0].tolist() == [False, False, True, True]
    with pytest.raises(ValueError, match="window"):
        contact(vec, window=0)


# --- aggregation

# 4 frames, 3 whiskers: whisker 0 in contact at 1, 3, 7 mm; whisker 1 never; whisker 2 at 2, 2, 4
TABLE = np.array([[1.0, 0.0, 2.0], [3.0, 0.0, 2.0], [5.0, 0.0, 4.0], [7.0, 9.0, 6.0]])
TABLE_CONTACT = np.array(
    [[True, False, True], [True, False, True], [False, False, True], [True, False, False]]
)


@pytest.mark.parametrize(
    ("method", "expected"),
    [
        ("integration", [7.0, 0.0, 8.0 * 7.0 / 11.0]),  # sums 11, 0, 8 scaled by 7 / 11
        ("max", [7.0, 0.0, 4.0]),
        ("mean", [11.0 / 3.0, 0.0, 8.0 / 3.0]),
        ("median", [3.0, 0.0, 2.0]),
        ("laplacian", [7.0, 0.0, 4.0]),  # 14 - 7 - 0, 0 - 7 - 4 < 0, 8 - 0 - 4
    ],
)
def test_aggregation_on_a_tiny_table(method, expected):
    assert aggregate(TABLE, TABLE_CONTACT, method) == pytest.approx(expected)


def test_max_in_contact():
    assert max_in_contact(TABLE, TABLE_CONTACT) == pytest.approx([7.0, 0.0, 4.0])


def test_laplacian_keeps_peaks():
    deflection = np.array([[1.0, 3.0, 2.0, 2.0, 0.0]])
    # edge-padded: 2-1-3, 6-1-2, 4-3-2, 4-2-0, 0-2-0 -> clipped at 0
    curve = aggregate(deflection, np.ones_like(deflection, bool), "laplacian")
    assert curve == pytest.approx([0.0, 3.0, 0.0, 2.0, 0.0])


def test_gaussian_renormalizes_at_the_edges():
    deflection = np.array([[0.0, 0.0, 1.0]])
    a, b = np.exp(-0.5), np.exp(-2.0)  # kernel weights at 1 and 2 whiskers
    curve = aggregate(deflection, np.ones_like(deflection, bool), "gaussian")
    assert curve == pytest.approx([b / (1 + a + b), a / (1 + 2 * a), 1 / (1 + a + b)])
    flat = np.full((1, 6), 2.5)
    assert aggregate(flat, np.ones_like(flat, bool), "gaussian") == pytest.approx([2.5] * 6)


def test_integration_scales_to_the_largest_max_deflection():
    rng = np.random.default_rng(3)
    deflection = rng.uniform(0, 5, (50, N))
    in_contact = rng.random((50, N)) < 0.4
    curve = aggregate(deflection, in_contact, "integration")
    assert curve.max() == pytest.approx(max_in_contact(deflection, in_contact).max())
    sums = np.where(in_contact, deflection, 0).sum(axis=0)
    assert curve == pytest.approx(sums * curve.max() / sums.max())


def test_aggregations_without_any_contact_are_zero():
    none = np.zeros_like(TABLE_CONTACT)
    for method in AGGREGATIONS:
        assert aggregate(TABLE, none, method) == pytest.approx([0.0, 0.0, 0.0]), method


def test_unknown_aggregation_lists_the_names():
    with pytest.raises(ValueError, match="integration, max, mean, median, laplacian, gaussian"):
        aggregate(TABLE, TABLE_CONTACT, "sum")


# --- candidates and peaks


def test_candidates_by_max_or_curve():
    max_deflection = np.array([3.0, 1.0, 1.0, 2.0])
    curve = np.array([1.0, 3.0, 1.0, 2.0])
    assert candidates(max_deflection, curve, 2.0).tolist() == [True, True, False, False]


@pytest.mark.parametrize(
    ("curve", "candidate", "expected"),
    [
        ([0, 1, 3, 1, 0], [1, 1, 1, 1, 1], [2]),
        ([5, 1, 0, 2], [1, 1, 1, 1], [0, 3]),  # endpoints
        ([0, 2, 2, 0], [1, 1, 1, 1], [1]),  # a plateau counts once, at its (left) middle
        ([0, 2, 2, 2, 0], [0, 0, 0, 1, 0], [2]),  # kept if one of its whiskers is a candidate
        ([1, 1, 1], [1, 1, 1], []),  # a constant curve has no peak
        ([0, 3, 0, 2, 0], [1, 0, 1, 1, 1], [3]),  # the non-candidate peak is dropped
        ([0, 3, 2, 2, 0], [1, 1, 1, 1, 1], [1]),  # a shoulder is no peak
    ],
)
def test_peaks(curve, candidate, expected):
    assert peaks(np.array(curve, float), np.array(candidate, bool)) == expected


# --- refinement


def _marker_x_integrals(tip_angles: dict[int, float]) -> np.ndarray:
    """(n,) marker x integrals of one contact frame from tip angles (+ = tip pushed right)."""
    x = np.zeros(N)
    for whisker, theta in tip_angles.items():
        x[whisker] = -MARKER_OFFSET_MM * np.sin(theta)  # the marker moves opposite to the tip
    return x


def test_refine_moves_a_peak_to_the_gap_the_tips_are_pushed_apart_at():
    # branch between 3 and 4: tip 3 pushed left, tip 4 pushed right
    x = _marker_x_integrals({3: -0.4, 4: 0.4})
    assert x[3] > 0 > x[4]
    assert refine([3], x) == [(3, 4)]
    assert refine([4], x) == [(3, 4)]
    assert refine([3, 4], x) == [(3, 4)]  # duplicates merged


def test_refine_with_one_touched_whisker():
    assert refine([8], _marker_x_integrals({8: -0.3})) == [(8, 9)]  # pushed left: branch right
    assert refine([8], _marker_x_integrals({8: 0.3})) == [(7, 8)]  # pushed right: branch left


def test_refine_at_the_ends_and_several_peaks():
    x = _marker_x_integrals({0: 0.3, 12: -0.3, 5: -0.3, 6: 0.3})
    assert refine([12, 0, 5], x) == [(0, 1), (5, 6), (11, 12)]
    assert refine([], x) == []


# --- markers and whiskers


def test_whisker_of_marker():
    assert whisker_of_marker([5, 7], [7, 3, 5]).tolist() == [2, 0]
    assert whisker_of_marker([0, 12], SPEC.marker_ids).tolist() == [0, 12]
    with pytest.raises(ValueError, match=r"\[9\]"):
        whisker_of_marker([3, 9], [7, 3, 5])


def test_check_baseline_refuses_a_sample_that_starts_moving() -> None:
    from pipeline.deflection import check_baseline

    rng = np.random.default_rng(0)
    vectors = rng.normal(0.0, 0.3, (40, 13, 3))  # free air: pose noise only
    vectors[4, 2] = [2.0, 0.0, 0.0]  # a single-frame jump of unrefined corners
    vectors[:3, 5] = np.nan  # a marker seen late: its baseline starts where it is first seen
    vectors[20:30, 4, 0] += 5.0  # after the baseline: contact, not a bad start
    check_baseline(vectors, 10, 1.0)
    pushed = vectors.copy()
    pushed[3:13, 5, 1] += np.linspace(0.0, 2.5, 10)  # whisker 5 pushed in its baseline frames
    with pytest.raises(ValueError, match=r"whiskers \[5\] move 1\.\d mm across their first 10"):
        check_baseline(pushed, 10, 1.0)
    late = vectors.copy()
    late[13:23, 5, 1] += np.linspace(0.0, 2.5, 10)  # the same push, after its baseline
    check_baseline(late, 10, 1.0)
