"""Whisker dynamics: ringing at sqrt(k / I), decay by the loss factor, convergence, and the
quasi-static limit."""

import math

import numpy as np
import pytest

from scenes.array import ArraySpec
from scenes.dynamics import (
    STEP_S,
    natural_frequency_hz,
    simulate_at,
    simulate_dynamic,
    whisker_inertia_Nmms2,
)
from scenes.mechanics import simulate
from scenes.obstacles import CompliantContact, RigidCylinder

SPEC3 = ArraySpec(n_whiskers=3, marker_ids=(0, 1, 2))  # default rod: bending, PET
CENTRE = 1
BASE_Z = SPEC3.frame_radius_mm
# Near the centre rod's tip: at 80 mm/s it holds the rod, then the rod slips past and rings.
TIP_BRANCH = [RigidCylinder(0.0, BASE_Z + 135.0)]


def skip_run(spec: ArraySpec, step_s: float = STEP_S, duration_s: float = 4.0):
    """(times, centre theta_h): the array moves +x at 80 mm/s from -20 to +70 mm, then stops."""
    t = np.arange(0.0, duration_s, 1e-3)
    x = np.minimum(80.0 * t, 90.0) - 20.0
    res = simulate_dynamic(spec, t, np.stack([x, 0 * x], -1), TIP_BRANCH, step_s=step_s)
    released = np.flatnonzero(res.branch_contact[:, CENTRE])[-1] + 1
    return t, res.angles_rad[:, CENTRE, 0], released


def test_inertia_is_the_slender_rod_plus_the_carrier():
    spec = ArraySpec()
    rod_kg_mm2 = 1380e-9 * math.pi * 1.5**2 / 4 * 140.0**3 / 3
    inertia = whisker_inertia_Nmms2(spec) * 1e3
    assert rod_kg_mm2 < inertia < 1.05 * rod_kg_mm2  # the carrier adds a few percent


def test_free_ringing_frequency_is_sqrt_k_over_I():
    t, theta, released = skip_run(SPEC3)
    free = slice(released + 5, None)
    up = np.flatnonzero(np.diff(np.sign(theta[free])) > 0)
    assert up.size > 10
    period = np.diff(t[free][up]).mean()
    expected = 2 * math.pi * math.sqrt(whisker_inertia_Nmms2(SPEC3) / SPEC3.spring_Nmm_per_rad)
    assert period == pytest.approx(expected, rel=0.02)
    assert 1 / period == pytest.approx(natural_frequency_hz(SPEC3), rel=0.02)


@pytest.mark.parametrize("eta", [0.02, 0.1])
def test_energy_decays_as_the_loss_factor_says(eta):
    spec = ArraySpec(n_whiskers=3, marker_ids=(0, 1, 2), coupling_loss_factor=eta)
    _, theta, released = skip_run(spec)
    free = theta[released + 5 :]
    peaks = np.flatnonzero((free[1:-1] > free[:-2]) & (free[1:-1] >= free[2:]) & (free[1:-1] > 0))
    energy = 0.5 * spec.spring_Nmm_per_rad * free[1:-1][peaks] ** 2  # at a peak, all potential
    assert peaks.size >= 4
    zeta = eta / 2
    expected = math.exp(-4 * math.pi * zeta / math.sqrt(1 - zeta**2))  # per period
    ratios = energy[1:] / energy[:-1]
    np.testing.assert_allclose(ratios, expected, rtol=0.03)


def test_a_released_whisker_rings_where_quasi_static_snaps_back():
    t, theta, released = skip_run(SPEC3, duration_s=1.5)
    after = theta[released : released + 300]  # 0.3 s: over two ringing periods
    assert np.abs(after).max() > 0.1
    assert np.count_nonzero(np.diff(np.sign(after))) >= 4
    x = np.minimum(80.0 * t, 90.0) - 20.0
    quasi = simulate(SPEC3, np.stack([x, 0 * x], -1), TIP_BRANCH).angles_rad[:, CENTRE, 0]
    assert np.all(quasi[released + 1 :] == 0.0)


@pytest.mark.slow  # over a second of CPU: out of `make test-fast`
def test_halving_the_step_changes_the_angles_little():
    strips = [CompliantContact(x, BASE_Z + 90.0, 2e-3, 0.02, 10.0, 0.2) for x in (-30, 5, 40)]
    t = np.arange(0.0, 2.5, 1 / 75)  # 15 fps with 4 subframes, plus the timestamp
    x = 50 * np.sin(2 * math.pi * t / 2.5)
    offsets = np.stack([x, 0 * x], -1)
    spec = ArraySpec()
    branches = [RigidCylinder(0.0, BASE_Z + 100.0), RigidCylinder(60.0, BASE_Z + 120.0)]
    coarse = simulate_dynamic(spec, t, offsets, branches, strips, step_s=2 * STEP_S)
    fine = simulate_dynamic(spec, t, offsets, branches, strips, step_s=STEP_S)
    assert fine.branch_contact.any() and np.abs(fine.angles_rad).max() > 0.1
    assert np.abs(fine.angles_rad - coarse.angles_rad).max() < 5e-3


@pytest.mark.slow  # over a second of CPU: out of `make test-fast`
def test_slow_motion_approaches_quasi_static_away_from_releases():
    t = np.arange(0.0, 7.5, 0.05)
    x = 4.0 * t - 5.0  # 4 mm/s, the indoor speed: from -5 to +25 mm
    offsets = np.stack([x, 0 * x], -1)
    branch = [RigidCylinder(15.0, BASE_Z + 60.0)]
    foliage = [CompliantContact(2.0, BASE_Z + 100.0, 2e-3, 0.02, 50.0, 0.2)]
    for spec in (SPEC3, ArraySpec(n_whiskers=3, marker_ids=(0, 1, 2), rod_modulus_MPa=None)):
        dyn = simulate_dynamic(spec, t, offsets, branch, foliage)
        quasi = simulate(spec, offsets, branch, foliage)
        assert dyn.branch_contact[-1, CENTRE] and np.abs(quasi.angles_rad).max() > 0.05
        np.testing.assert_allclose(dyn.angles_rad, quasi.angles_rad, atol=3e-3)
        np.testing.assert_array_equal(dyn.branch_contact, quasi.branch_contact)


def test_repeated_times_share_one_state_and_dispatch_picks_the_model():
    t = np.array([0.0, 0.1, 0.1, 0.2, 0.2, 0.2, 0.3])
    offsets = np.stack([80 * t, 0 * t], -1)
    res = simulate_at(SPEC3, t, offsets, [RigidCylinder(10.0, BASE_Z + 60.0)])
    np.testing.assert_array_equal(res.angles_rad[1], res.angles_rad[2])
    np.testing.assert_array_equal(res.angles_rad[3], res.angles_rad[5])
    assert res.branch_contact[-1, CENTRE]
    quasi = simulate_at(
        SPEC3, t, offsets, [RigidCylinder(10.0, BASE_Z + 60.0)], mechanics="quasi-static"
    )
    direct = simulate(SPEC3, offsets, [RigidCylinder(10.0, BASE_Z + 60.0)])
    np.testing.assert_array_equal(quasi.angles_rad, direct.angles_rad)
    with pytest.raises(ValueError, match="mechanics"):
        simulate_at(SPEC3, t, offsets, mechanics="rigid")


@pytest.mark.parametrize(
    ("times", "match"),
    [
        (np.array([0.0, 0.2, 0.1]), "non-decreasing"),
        (np.array([0.0, 0.1]), "shape"),
        (np.array([0.0, np.nan, 0.2]), "finite"),
    ],
)
def test_bad_times_raise(times, match):
    with pytest.raises(ValueError, match=match):
        simulate_dynamic(SPEC3, times, np.zeros((3, 2)))


def test_bad_step_raises():
    with pytest.raises(ValueError, match="step_s"):
        simulate_dynamic(SPEC3, np.zeros(2), np.zeros((2, 2)), step_s=0.0)


def test_a_free_stretch_jumped_in_one_matrix_power_equals_stepping():
    """The loop jumps a free segment (nothing in reach) instead of stepping it: same state."""
    from scenes.dynamics_loop import Stepper
    from scenes.mechanics_model import build_model

    model = build_model(SPEC3, [], [CompliantContact(0.0, BASE_Z + 400.0, 2e-3, 0.02, 1.0, 0.2)])
    inertia = whisker_inertia_Nmms2(SPEC3)
    damping = SPEC3.coupling_loss_factor * math.sqrt(model.k * inertia)
    dts, path = np.full(800, STEP_S), np.zeros((800, 2))  # 0.4 s, about three periods
    runs = [Stepper(model, inertia, damping, model.base, dts, path) for _ in range(2)]
    for run in runs:
        run.st.theta, run.omega_v = np.array([0.2, -0.1, 0.05]), np.array([1.0, 0.0, -2.0])
    jumped, stepped = runs
    assert jumped._free_segment(0, 800)
    jumped.advance(0, 800)
    for s in range(800):
        stepped._step(s, False)
    np.testing.assert_allclose(jumped.st.theta, stepped.st.theta, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(jumped.st.theta_v, stepped.st.theta_v, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(jumped.omega, stepped.omega, rtol=1e-9, atol=1e-12)
    np.testing.assert_array_equal(jumped.st.side, stepped.st.side)
    assert np.abs(jumped.st.theta).max() > 0.02  # still ringing: the comparison means something
