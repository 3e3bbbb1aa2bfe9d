"""Whisker dynamics (SPEC 1, issue 13): each whisker rings after it is released.

Per whisker and axis, ``I theta'' + c theta' + k theta = torque`` about the coupling:

* ``I`` (:func:`whisker_inertia_Nmms2`): the rod as a slender cylinder from the coupling to its
  tip, ``m L^2 / 3``, plus the marker's carrier plate ``marker_offset_mm`` behind the coupling
  (:mod:`scenes.marker`'s carrier, ``m (offset^2 + side^2 / 12)``; ~2 % of the total). The holder
  bar (2 x 2 x 8 mm, ~0.03 % of ``I``) is left out. Densities: :mod:`scenes.rod_materials`.
* ``k = spec.spring_Nmm_per_rad``; ``c = eta sqrt(k I)`` from the coupling's loss factor
  ``eta = spec.coupling_loss_factor``: a hysteretic loss factor equals a viscous damping ratio
  ``zeta = eta / 2`` at resonance, so free ringing decays as ``exp(-zeta omega_n t)`` at
  ``omega_n = sqrt(k / I)`` (the default whisker: about 8 Hz, zeta 0.01).
* Foliage: the engage / push / give-way springs of :mod:`scenes.mechanics`, evaluated at the
  current angle (their force law is quasi-static: the strips' own mass is left out).
* Branches: a rigid rod meets a branch as a unilateral constraint: the angle is projected onto
  the shadow's edge and the velocity becomes the edge's (inelastic: the velocity into the branch
  is removed). A bending rod meets it through the rod's bending stiffness, a one-sided torsional
  spring ``K = 3 EI / a`` about the coupling pulling the angle towards the edge (``a`` the
  contact lever); at rest this gives the quasi-static share ``K / (K + k)`` of the edge angle.
  ``K`` is capped at ``I / (2 dt)^2`` (levers under ~0.3 mm at 0.5 ms) so the step stays stable.
* Friction: while a branch presses the rod (torque ``T_b = N a``), the vertical motion sticks
  unless the vertical torque demand exceeds ``mu |T_b|`` (Coulomb stick-slip as an impulse bound:
  a step's vertical velocity is zeroed if the friction impulse can stop it, else reduced by it).

Integration: semi-implicit (symplectic) Euler with implicit damping, fixed step ``step_s``
(default :data:`STEP_S`, 0.5 ms: 0.04 mm of travel at 80 mm/s, 250 steps per ringing period;
tests/test_dynamics.py checks that halving it changes little). Between the requested samples the
array moves linearly, as in :func:`scenes.mechanics.simulate`; samples at equal times share one
state. The loop (:mod:`scenes.dynamics_loop`) skips work that cannot change the result, and jumps
free stretches (nothing within reach) as one power of the step's matrix.

Left out: the rod's own bending modes (its first mode is far above the ~8 Hz coupling mode), air
drag (fold it into ``coupling_loss_factor``), the coupling of axial sliding and vertical stick at a
branch (in reality a rod sliding along its own axis over the branch has less vertical grip), the
round branch tilting the contact normal at tip contact (the tip's friction cone: the rod slips
off at the quasi-static shadow edge, friction does not hold it longer), and rebound at impact.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Literal

import numpy as np

from scenes.array import ArraySpec
from scenes.dynamics_loop import Stepper
from scenes.marker import CARRIER_THICKNESS_MM
from scenes.mechanics import MechanicsResult, simulate
from scenes.mechanics_model import (
    build_model,
    check_finite,
    check_offsets,
    check_pivots_clear,
)
from scenes.obstacles import CompliantContact, RigidCylinder
from scenes.rod_materials import CARRIER_DENSITY_KG_M3, ROD_ON_WOOD_FRICTION

STEP_S = 0.5e-3  # default integration step (s)
_KG_MM2_PER_NMMS2 = 1e3  # 1 N mm s^2 = 1e-3 kg m^2 = 1e3 kg mm^2
MECHANICS = ("dynamic", "quasi-static")


def whisker_inertia_Nmms2(spec: ArraySpec) -> float:
    """Moment of inertia of rod, carrier and marker about the coupling (N mm s^2)."""
    rho_rod = spec.rod_density_kg_m3 * 1e-9  # kg/mm^3
    area = math.pi * spec.whisker_diameter_mm**2 / 4
    length = spec.whisker_length_mm
    rod = rho_rod * area * length * length**2 / 3
    side = 2 * spec.marker_spec(spec.marker_ids[0]).carrier_half_mm
    carrier_mass = CARRIER_DENSITY_KG_M3 * 1e-9 * side**2 * CARRIER_THICKNESS_MM
    distance = spec.marker_offset_mm + CARRIER_THICKNESS_MM / 2
    carrier = carrier_mass * (distance**2 + side**2 / 12)
    return (rod + carrier) / _KG_MM2_PER_NMMS2


def natural_frequency_hz(spec: ArraySpec) -> float:
    """Undamped free ringing frequency sqrt(k / I) / (2 pi) of one whisker."""
    return math.sqrt(spec.spring_Nmm_per_rad / whisker_inertia_Nmms2(spec)) / (2 * math.pi)


def _schedule(
    times: np.ndarray, offsets: np.ndarray, step_s: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(dt (S,), offsets (S, 2), index of the substep ending at each sample (T,)): no step longer
    than ``step_s``; sample 0 is the initial state (index -1), equal times take no step."""
    span = np.diff(times)
    counts = np.ceil(span / step_s - 1e-9).astype(int)
    owner = np.repeat(np.arange(span.size), counts)
    ends = np.cumsum(counts)
    k = np.arange(owner.size) - (ends - counts)[owner] + 1
    frac = k / counts[owner]
    path = offsets[owner] + frac[:, None] * (offsets[owner + 1] - offsets[owner])
    return span[owner] / counts[owner], path, np.concatenate([[0], ends]) - 1


def _check_times(times_s: np.ndarray, count: int) -> np.ndarray:
    times = np.asarray(times_s, dtype=float)
    if times.shape != (count,):
        raise ValueError(f"times_s: expected shape ({count},) like offsets_mm, got {times.shape}")
    if not np.all(np.isfinite(times)):
        raise ValueError("times_s: must be finite (found NaN or inf)")
    if np.any(np.diff(times) < 0):
        raise ValueError("times_s: must be non-decreasing (sort the samples first)")
    return times


def simulate_dynamic(
    spec: ArraySpec,
    times_s: np.ndarray,
    offsets_mm: np.ndarray,
    branches: Sequence[RigidCylinder] = (),
    foliage: Sequence[CompliantContact] = (),
    step_s: float = STEP_S,
    branch_friction: float = ROD_ON_WOOD_FRICTION,
) -> MechanicsResult:
    """Whisker angles at the sample ``times_s`` (T,), non-decreasing, with the array at
    ``offsets_mm`` (T, 2) then, integrated at steps of at most ``step_s`` from rest at
    ``times_s[0]``."""
    check_finite("step_s", float(step_s), 0.0)
    offsets = check_offsets(offsets_mm)
    times = _check_times(times_s, len(offsets))
    model = build_model(spec, branches, foliage, branch_friction)
    check_pivots_clear(model, offsets)
    inertia = whisker_inertia_Nmms2(spec)
    damping = spec.coupling_loss_factor * math.sqrt(model.k * inertia)
    dts, path, keep = _schedule(times, offsets, float(step_s))

    T, n = len(offsets), model.psi.size
    angles = np.zeros((T, n, 2))
    contact = np.zeros((T, n), dtype=bool)
    branch_contact = np.zeros((T, n), dtype=bool)
    sim = Stepper(model, inertia, damping, model.base + offsets[0], dts, path)
    for out in range(T):
        if out:
            sim.advance(keep[out - 1] + 1, keep[out] + 1)
        angles[out, :, 0], angles[out, :, 1] = sim.st.theta, sim.st.theta_v
        contact[out], branch_contact[out] = sim.contact, sim.held
    return MechanicsResult(angles, contact, branch_contact)


def simulate_at(
    spec: ArraySpec,
    times_s: np.ndarray,
    offsets_mm: np.ndarray,
    branches: Sequence[RigidCylinder] = (),
    foliage: Sequence[CompliantContact] = (),
    *,
    mechanics: Literal["dynamic", "quasi-static"] = "dynamic",
    branch_friction: float = ROD_ON_WOOD_FRICTION,
) -> MechanicsResult:
    """The dataset's entry point: dynamics by default, quasi-static as a choice (it ignores the
    times: each sample is an equilibrium)."""
    if mechanics == "dynamic":
        return simulate_dynamic(
            spec, times_s, offsets_mm, branches, foliage, branch_friction=branch_friction
        )
    if mechanics == "quasi-static":
        return simulate(spec, offsets_mm, branches, foliage, branch_friction=branch_friction)
    raise ValueError(f"mechanics={mechanics!r}: unknown; choose from {', '.join(MECHANICS)}")
