"""The quasi-static whisker mechanics reproduces each mechanism of SPEC 1."""

import math
import time

import numpy as np
import pytest

from scenes.array import ArraySpec, T_cam_whisker, T_marker0_marker, tip_cam
from scenes.mechanics import simulate
from scenes.obstacles import CompliantContact, RigidCylinder

# Three whiskers at -45, 0 and +45 degrees: the centre one has its coupling at (0, 210) and
# points along +z, so obstacles near x = 0 only ever touch it. The rod is rigid here, so that each
# lever mechanism shows alone; the rod's bending (on by default) has its own tests.
SPEC3 = ArraySpec(n_whiskers=3, marker_ids=(0, 1, 2), rod_modulus_MPa=None)
CENTRE = 1
BASE_Z = SPEC3.frame_radius_mm
R_EFF = 5.0 + SPEC3.whisker_diameter_mm / 2  # default branch radius plus the rod's


def sweep(x0: float, x1: float, step: float = 0.25) -> np.ndarray:
    """Offsets (T, 2) moving the array along x from x0 to x1."""
    count = max(2, int(round(abs(x1 - x0) / step)) + 1)
    return np.stack([np.linspace(x0, x1, count), np.zeros(count)], axis=-1)


def strip(x: float, z: float, **kw) -> CompliantContact:
    params = dict(stiffness_N_per_mm=0.05, force_limit_N=1.0, give_way_mm=1e3) | kw
    return CompliantContact(x, z, **params)


def rods(spec: ArraySpec, offsets: np.ndarray, theta_h: np.ndarray):
    """(couplings, directions), each (T, n, 2) in (x, z), recomputed from the angles alone."""
    psi = spec.headings_rad
    P = spec.frame_radius_mm * np.stack([np.sin(psi), np.cos(psi)], -1) + offsets[:, None]
    phi = psi + theta_h
    return P, np.stack([np.sin(phi), np.cos(phi)], -1)


def segment_point_distance(p0: np.ndarray, p1: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Distance from point q to the segments p0-p1 (broadcast over leading axes)."""
    seg, to_q = p1 - p0, q - p0
    t = np.clip(np.sum(to_q * seg, -1) / np.sum(seg * seg, -1), 0.0, 1.0)
    return np.linalg.norm(to_q - t[..., None] * seg, axis=-1)


def lever_and_push(offset_x: float, theta: float, point: tuple[float, float]):
    """(a, signed distance c) of a point from the centre rod at array offset x and angle theta."""
    qx, qz = point[0] - offset_x, point[1] - BASE_Z
    return qx * math.sin(theta) + qz * math.cos(theta), qx * math.cos(theta) - qz * math.sin(theta)


# -- 1. torsional spring + bounded force: longer lever, larger angle -----------------------------


def test_bounded_force_deflects_more_when_farther_from_the_coupling():
    k, limit = SPEC3.spring_Nmm_per_rad, 0.005
    thetas = {}
    for a in (40.0, 120.0):
        point = (2.0, BASE_Z + a)
        res = simulate(SPEC3, sweep(0, 20), foliage=[strip(*point, force_limit_N=limit)])
        theta = res.angles_rad[-1, CENTRE, 0]
        lever, c = lever_and_push(20.0, theta, point)
        assert res.contact[-1, CENTRE]
        assert -c * 0.05 > limit  # pushed past the force limit: the force is the limit
        assert k * abs(theta) == pytest.approx(limit * lever, rel=1e-9)
        thetas[a] = abs(theta)
    assert thetas[120.0] > 2.5 * thetas[40.0]


# -- 2. rigid obstacle: imposed displacement, kinematic amplification ----------------------------


def test_rigid_contact_nearer_the_coupling_gives_a_larger_angle():
    thetas = {}
    for a in (40.0, 120.0):
        res = simulate(SPEC3, sweep(0, 15), branches=[RigidCylinder(15.0, BASE_Z + a)])
        assert res.branch_contact[-1, CENTRE] and res.contact[-1, CENTRE]
        # The branch is straight ahead at the end: the rod is tangent to it, lagging behind.
        theta = res.angles_rad[-1, CENTRE, 0]
        assert theta == pytest.approx(-math.asin(R_EFF / a), abs=1e-9)
        thetas[a] = abs(theta)
    assert thetas[40.0] > 2.5 * thetas[120.0]


def test_series_bending_reduces_the_coupling_angle_at_a_rigid_contact():
    a, branch = 60.0, [RigidCylinder(15.0, BASE_Z + 60.0)]
    soft = ArraySpec(n_whiskers=3, marker_ids=(0, 1, 2), rod_modulus_MPa=3000.0)
    rigid_theta = simulate(SPEC3, sweep(0, 15), branch).angles_rad[-1, CENTRE, 0]
    bent = simulate(soft, sweep(0, 15), branch)
    bent_theta = bent.angles_rad[-1, CENTRE, 0]
    assert bent.branch_contact[-1, CENTRE]
    assert 0 < abs(bent_theta) < abs(rigid_theta)
    lever = math.sqrt(a**2 - R_EFF**2)
    compliance = 1 / soft.spring_Nmm_per_rad
    share = compliance / (compliance + lever / (3 * soft.rod_bending_EI_Nmm2))
    assert bent_theta == pytest.approx(rigid_theta * share, rel=1e-9)


# -- 3. skip: a large sweep slips past a branch, a small one does not ----------------------------


def test_large_sweep_slips_past_a_branch_and_small_one_does_not():
    branch = [RigidCylinder(0.0, BASE_Z + 140.0)]  # near the tip
    large = simulate(SPEC3, np.concatenate([sweep(-20, 60), sweep(60, -20)]), branch)
    theta = large.angles_rad[:, CENTRE, 0]
    out = len(sweep(-20, 60))
    assert theta[:out].min() < -0.2  # bent a lot on the way out...
    assert theta[out - 1] == 0.0 and not large.contact[out - 1, CENTRE]  # ...then skipped
    assert theta[out:].max() > 0.1  # coming back, it meets the branch from the other side

    small = simulate(SPEC3, sweep(-20, 15), branch)
    assert small.branch_contact[-1, CENTRE]
    assert small.angles_rad[-1, CENTRE, 0] < -0.05


# -- 4. the marker moves opposite to the tip -----------------------------------------------------


def test_marker_moves_opposite_to_the_tip():
    spec = ArraySpec()
    branches = [RigidCylinder(0.0, 320.0), RigidCylinder(120.0, 290.0)]
    res = simulate(spec, np.concatenate([sweep(0, -40), sweep(-40, 40)]), branches)
    angles = res.angles_rad
    moved = np.abs(angles[..., 0]) > 0.02
    assert moved.sum() > 50
    tip = tip_cam(spec, angles) - tip_cam(spec, np.zeros_like(angles))
    marker_m0 = T_marker0_marker(spec, angles)[..., :3, 3]
    marker = np.einsum("nij,...nj->...ni", T_cam_whisker(spec)[:, :3, :3], marker_m0)
    assert np.all(np.sum(tip * marker, axis=-1)[moved] < 0)
    sideways = spec.marker_offset_mm * np.sin(angles[..., 0])
    np.testing.assert_allclose(marker_m0[..., 0], -sideways, atol=1e-12)


# -- 5. no contact, no deflection; giving way releases -------------------------------------------


def test_nothing_in_reach_means_no_deflection():
    still = simulate(SPEC3, np.zeros((5, 2)))
    assert not still.angles_rad.any() and not still.contact.any()
    far = [RigidCylinder(0.0, 600.0)], [strip(0.0, 500.0), strip(300.0, 0.0)]
    res = simulate(SPEC3, sweep(-50, 50, 1.0), *far)
    assert not res.angles_rad.any() and not res.contact.any()


def test_axial_push_gives_no_torque():
    ahead = [strip(0.0, BASE_Z + 200.0)]  # straight ahead of the centre tip
    push = np.stack([np.zeros(101), np.linspace(0, 120, 101)], axis=-1)
    res = simulate(SPEC3, push, foliage=ahead)
    assert not res.angles_rad.any() and not res.contact.any()


def test_foliage_that_gives_way_releases_the_whisker():
    res = simulate(SPEC3, sweep(0, 30), foliage=[strip(2.0, BASE_Z + 60.0, give_way_mm=0.3)])
    theta, touching = res.angles_rad[:, CENTRE, 0], res.contact[:, CENTRE]
    assert touching.any() and theta.min() < -0.01
    assert theta[-1] == 0.0 and not touching[-1]
    first_free = np.flatnonzero(touching)[-1] + 1
    assert not touching[first_free:].any()  # it stays released


# -- 6. the rod never enters a branch ------------------------------------------------------------


@pytest.mark.slow
def test_rods_never_penetrate_branches():
    spec = ArraySpec(rod_modulus_MPa=None)  # a bent rod's coupling line may cross the branch
    rng = np.random.default_rng(1)
    branches = [RigidCylinder(0.0, 330.0), RigidCylinder(60.0, 310.0, radius_mm=8.0)]
    foliage = [
        strip(x, z, force_limit_N=0.03, give_way_mm=4.0)
        for x, z in zip(rng.uniform(-250, 250, 80), rng.uniform(200, 360, 80), strict=True)
    ]
    for step in (0.5, 7.0):  # the coarse path is sub-stepped internally
        offsets = np.concatenate([sweep(0, -50, step), sweep(-50, 50, step), sweep(50, 0, step)])
        res = simulate(spec, offsets, branches, foliage)
        assert res.branch_contact.any()
        P, d = rods(spec, offsets, res.angles_rad[..., 0])
        tips = P + spec.whisker_length_mm * d
        for b in branches:
            dist = segment_point_distance(P, tips, np.array([b.x_mm, b.z_mm]))
            assert dist.min() >= b.radius_mm + spec.whisker_diameter_mm / 2 - 1e-6


def test_one_long_step_cannot_jump_over_a_branch():
    branch = [RigidCylinder(15.0, BASE_Z + 60.0)]
    coarse = simulate(SPEC3, np.array([[0.0, 0.0], [15.0, 0.0]]), branch)
    fine = simulate(SPEC3, sweep(0, 15), branch)
    assert coarse.angles_rad.shape == (2, 3, 2)
    assert coarse.branch_contact[-1, CENTRE]
    assert coarse.angles_rad[-1, CENTRE, 0] == pytest.approx(fine.angles_rad[-1, CENTRE, 0])


# -- 7. torque balance below the force limit -----------------------------------------------------


def test_torque_balance_for_an_elastic_contact():
    kf, vertical, point = 0.01, 0.5, (3.0, BASE_Z + 80.0)
    contact = strip(*point, stiffness_N_per_mm=kf, vertical_ratio=vertical)
    res = simulate(SPEC3, sweep(0, 10), foliage=[contact])
    theta_h, theta_v = res.angles_rad[-1, CENTRE]
    lever, c = lever_and_push(10.0, theta_h, point)
    force = kf * -c  # the rest point is behind the rod (-x side): pushed by |c|
    assert 0 < force < contact.force_limit_N
    k = SPEC3.spring_Nmm_per_rad
    assert k * theta_h == pytest.approx(-force * lever, rel=1e-9)
    assert k * theta_v == pytest.approx(vertical * force * lever, rel=1e-9)


# -- 8. friction: a branch pressing the rod holds its vertical angle -----------------------------


@pytest.mark.parametrize("mu", [0.35, 0.0])
def test_branch_friction_holds_the_vertical_angle_after_the_foliage_lets_go(mu):
    # A tilted strip pushes the rod up (theta_v > 0), a branch then presses it sideways, then the
    # strip gives way: with friction the rod stays up; without, it springs back to theta_v = 0.
    tilted = strip(2.0, BASE_Z + 60.0, force_limit_N=0.01, give_way_mm=8.0, vertical_ratio=0.5)
    res = simulate(SPEC3, sweep(0, 30), [RigidCylinder(10.0, BASE_Z + 100.0)], [tilted], 0.5, mu)
    theta_h, theta_v = res.angles_rad[:, CENTRE, 0], res.angles_rad[:, CENTRE, 1]
    pushed_up = theta_v.max()
    assert pushed_up > 0.04
    assert res.branch_contact[-1, CENTRE] and not np.isclose(theta_h[-1], 0.0)
    grip = mu * SPEC3.spring_Nmm_per_rad * abs(theta_h[-1])  # mu N a, N a the branch torque
    if mu > 0:
        assert theta_v[-1] > 0.9 * pushed_up  # stuck: the vertical spring torque is within grip
        assert SPEC3.spring_Nmm_per_rad * theta_v[-1] <= grip + 1e-12
    else:
        assert theta_v[-1] == 0.0


# -- 9. bad input --------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "offsets",
    [np.zeros((4, 3)), np.zeros(4), np.zeros((0, 2)), np.array([[0.0, 0.0], [np.nan, 0.0]])],
)
def test_bad_offsets_raise(offsets):
    with pytest.raises(ValueError, match="offsets_mm"):
        simulate(SPEC3, offsets)


def test_pivot_inside_a_branch_raises():
    with pytest.raises(ValueError, match="coupling"):
        simulate(SPEC3, np.zeros((2, 2)), [RigidCylinder(0.0, BASE_Z + 3.0)])
    # The coupling passes through the branch between two offsets.
    with pytest.raises(ValueError, match="coupling"):
        simulate(SPEC3, np.array([[-30.0, 0.0], [30.0, 0.0]]), [RigidCylinder(0.0, BASE_Z)])


@pytest.mark.parametrize(
    "kwargs",
    [
        {"max_step_mm": 0.0},
        {"max_step_mm": math.nan},
        {"foliage": [strip(0.0, 300.0, stiffness_N_per_mm=0.0)]},
        {"foliage": [strip(math.inf, 300.0)]},
        {"branches": [RigidCylinder(0.0, 300.0, radius_mm=-1.0)]},
    ],
)
def test_bad_parameters_raise(kwargs):
    with pytest.raises(ValueError):
        simulate(SPEC3, np.zeros((2, 2)), **kwargs)


# -- speed (printed, not asserted) ---------------------------------------------------------------


@pytest.mark.slow
def test_full_array_in_dense_foliage_runs(capsys):
    spec, rng = ArraySpec(), np.random.default_rng(0)
    foliage = [
        strip(x, z, stiffness_N_per_mm=0.02, force_limit_N=0.05, give_way_mm=3.0)
        for x, z in zip(rng.uniform(-300, 300, 200), rng.uniform(150, 380, 200), strict=True)
    ]
    branches = [RigidCylinder(0.0, 330.0), RigidCylinder(100.0, 300.0)]
    x = 50 * np.sin(np.linspace(0, 4 * np.pi, 1000))
    start = time.perf_counter()
    res = simulate(spec, np.stack([x, np.zeros_like(x)], -1), branches, foliage)
    elapsed = time.perf_counter() - start
    with capsys.disabled():
        print(f"\nmechanics: 1000 steps x 13 whiskers x 200 contacts + 2 branches: {elapsed:.2f} s")
    assert res.angles_rad.shape == (1000, 13, 2) and np.all(np.isfinite(res.angles_rad))
    assert res.contact.any() and res.branch_contact.any()


# -- 9. foliage friction: the slip angle atan(mu) sets how hard and how long a strip holds ------


def test_foliage_friction_sets_how_hard_and_how_long_a_strip_holds():
    """One 80 g/m2 strip swept by the central whisker: twice the friction, twice the force
    limit and twice the give-way travel (module docstring of scenes.vegetation), so the
    whisker turns further and stays in contact longer before the strip slips past."""
    from scenes.foliage_materials import PAPER_MODULUS_MPA
    from scenes.vegetation import cantilever_contact, plate_EI_Nmm2

    EI = plate_EI_Nmm2(PAPER_MODULUS_MPA, 0.10, 12.0)
    peak, held = {}, {}
    for mu in (0.2, 0.4):
        contact = cantilever_contact(-5.0, 300.0, EI, 35.0, mu, 0.0)
        result = simulate(SPEC3, sweep(0.0, -40.0), foliage=[contact])
        peak[mu] = np.abs(result.angles_rad[:, 1, 0]).max()
        held[mu] = int(result.contact[:, 1].sum())
    assert peak[0.2] > 0 and peak[0.4] == pytest.approx(2 * peak[0.2], rel=0.05)
    assert held[0.4] > 1.5 * held[0.2]
