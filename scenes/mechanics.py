"""Quasi-static whisker mechanics (SPEC 1): array offsets over time -> deflection angles.

Geometry. Everything is resolved in the horizontal plane of the array, in the vegetation frame of
:mod:`scenes.obstacles` (x, z in mm). Whisker ``i`` is a straight rod of length ``L`` from its
coupling ``P_i = frame_radius * (sin psi_i, cos psi_i) + offset`` along heading
``phi_i = psi_i + theta_h``, i.e. direction ``(sin phi, cos phi)``; positive ``theta_h`` turns the
tip towards increasing heading, the whisker frame's +x of :mod:`scenes.array`. The coupling is a
torsional spring ``k`` (rest angle 0) about both axes; each step is an equilibrium (no dynamics).

Foliage (:class:`~scenes.obstacles.CompliantContact`, a point in the plane). A contact engages
when the rod's line sweeps across its rest point while the point lies along the rod
(``0 < a <= L``, ``a`` its projection on the rod). Engaged, it is pushed sideways by ``delta``
(the rest point's distance behind the rod line) and pushes back with
``F = min(stiffness * delta, force_limit)`` at lever ``a``. It disengages when the rod returns
past it (``delta <= 0``), when its own deflection exceeds ``give_way_mm`` (it slips past and
stays on the other side until swept across again), or when ``a`` leaves ``(0, L]`` (the tip
passed it). A point on the rod's line (``c == 0``, e.g. met head-on by a tip pushed along its
axis) has no side yet, so it never engages until it has one: axial push-in gives no torque.
The horizontal angle solves ``k * theta_h = sum_j sign_j F_j(theta_h) a_j(theta_h)`` per whisker
(safeguarded Newton, vectorized); the vertical one is ``k * theta_v = sum_j vr_j F_j a_j``.

Branches (:class:`~scenes.obstacles.RigidCylinder`, effective radius ``r`` = its radius plus the
rod's). From the coupling, a branch at distance ``D`` in direction ``gamma`` blocks headings
``[gamma - beta, gamma + beta]``: ``beta = asin(r / D)`` while the tangent point is within reach
(``sqrt(D^2 - r^2) <= L``), else the law-of-cosines angle of the circle's point at distance ``L``
(tip contact) while ``D - r < L``, else nothing. The rod keeps to the side of each branch it was
on (remembered per whisker and branch, refreshed whenever it is outside the interval); if its
free equilibrium heading (spring + foliage) is inside or beyond the interval, it sits on the
interval's edge. As the array moves on, ``beta`` shrinks to 0 and the rod slips past ("skip").
A rod pushed exactly head-on into a branch goes to the side it was on (+ if none). If the sides
remembered for two branches leave no admissible heading (the rod is jammed between overlapping
shadows), it takes the outer edge of the group nearer its free heading, i.e. slips past.

Rod bending (on by default with the PET modulus of :mod:`scenes.rod_materials`; a rigid rod
with ``rod_modulus_MPa=None``). A load ``F`` at ``a`` turns the
coupling by ``F a / k`` and bends the rod as a small-deflection cantilever, so the contact point
lies on a line at ``F a (1/k + a/(3 EI))``. For foliage this is a spring ``3 EI / a^3`` in series
with the strip (its effective stiffness drops, its own deflection is what gives way); for a branch
the geometric angle is the interval edge and the coupling takes only its share
``(1/k) / (1/k + a/(3 EI))`` of it (with foliage engaged too, the coupling angle solves the
branch constraint and the foliage torque together). Each load's bending is independent of the
others' (exact for a single contact).

Friction. In the plane a contact pushes perpendicular to the rod and friction acts along it,
which has no moment about the coupling. Out of the plane, a rod pressed against a branch (a
vertical cylinder) with torque ``N a`` keeps its ``theta_v`` until the vertical torque demand
exceeds ``mu N a`` (Coulomb stick-slip, :func:`scenes.contacts.stick_slip`; ``mu`` =
``branch_friction``). Foliage friction is in the foliage's give-way (:mod:`scenes.vegetation`).

Left out: rod dynamics (:mod:`scenes.dynamics`), axial loads and buckling, the coupling
of ``theta_v`` into the plane geometry (contacts are solved as if the rod stayed in the plane),
strips bending visibly (foliage is a point spring), the rod's radius for foliage (it counts for
branches only), and the rod's bent shape for foliage (each strip sees the line at the coupling
angle, plus its own series bending).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from scenes.array import ArraySpec
from scenes.contacts import (
    ContactState,
    Pairs,
    Rel,
    engage,
    engaged_pairs,
    foliage_torque,
    hold,
    initial_state,
    loads,
    release,
    shadows,
    stick_slip,
)
from scenes.mechanics_model import (
    MechanicsModel,
    build_model,
    check_finite,
    check_offsets,
    check_pivots_clear,
)
from scenes.obstacles import CompliantContact, RigidCylinder
from scenes.rod_materials import ROD_ON_WOOD_FRICTION

_TOL_RAD = 1e-10  # Newton stops when every whisker's step is below this (quadratic: error ~1e-20)
_MAX_NEWTON = 80  # enough for pure bisection from any bracket at float64 resolution
_MAX_PASSES = 8  # engage / solve / release rounds per step (springback can sweep new contacts)


@dataclass(frozen=True)
class MechanicsResult:
    """Deflection of every whisker at every requested time step."""

    angles_rad: np.ndarray  # (T, n, 2) float64: (theta_h, theta_v), scenes.array's convention
    contact: np.ndarray  # (T, n) bool: the whisker touches any obstacle
    branch_contact: np.ndarray  # (T, n) bool: it touches a RigidCylinder


# -- path ------------------------------------------------------------------------------------


def _substeps(offsets: np.ndarray, max_step_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """(path (S, 2), index in path of each requested step (T,)): no move longer than max_step."""
    seg = np.diff(offsets, axis=0)
    counts = np.maximum(np.ceil(np.linalg.norm(seg, axis=-1) / max_step_mm), 1).astype(int)
    owner = np.repeat(np.arange(len(seg)), counts)
    ends = np.cumsum(counts)
    frac = (np.arange(owner.size) - (ends - counts)[owner] + 1) / counts[owner]
    path = np.concatenate([offsets[:1], offsets[owner] + frac[:, None] * seg[owner]])
    return path, np.concatenate([[0], ends])


def _solve(
    model: MechanicsModel,
    pr: Pairs,
    theta0: np.ndarray,
    A: np.ndarray,
    B: np.ndarray,
    R: np.ndarray,
) -> np.ndarray:
    """Roots of ``A theta - B torque(theta) = R`` per whisker (safeguarded Newton).

    Free rod: A = k, B = 1, R = 0. Rod held at a branch at geometric angle g with lever e*3EI:
    A = 1 + k e, B = e, R = g. The foliage torque is bounded by sum(limit * |rel|), which gives
    a bracket that always holds a sign change; Newton steps that leave it are bisections.
    """
    bound = (pr.engaged * pr.limit * np.hypot(pr.rx, pr.rz)).sum(axis=1)
    lo, hi = (R - B * bound) / A, (R + B * bound) / A
    theta = np.minimum(np.maximum(theta0, lo), hi)
    for _ in range(_MAX_NEWTON):
        torque, slope = foliage_torque(pr, loads(model, pr, theta))
        g = A * theta - B * torque - R
        lo, hi = np.where(g < 0, theta, lo), np.where(g > 0, theta, hi)
        with np.errstate(divide="ignore", invalid="ignore"):
            change = np.where(g == 0, 0.0, -g / (A - B * slope))
        small = np.abs(change) < _TOL_RAD
        step = theta + change
        theta = np.where(((step > lo) & (step < hi)) | small, step, 0.5 * (lo + hi))
        if small.all():
            break
    return theta


# -- one step --------------------------------------------------------------------------------


def _equilibrium(
    model: MechanicsModel, P: np.ndarray, rel: Rel, st: ContactState
) -> tuple[np.ndarray, np.ndarray]:
    """(coupling angles, held by a branch): spring + foliage equilibrium, then branches."""
    n = model.psi.size
    pr = engaged_pairs(model, rel, st)
    theta_free = _solve(model, pr, st.theta, model.k, np.ones(n), np.zeros(n))
    if model.branches.x.size == 0:
        return theta_free, np.zeros(n, dtype=bool)
    gamma, beta, lever = shadows(model, P)
    theta_geom, held, which = hold(model, theta_free, gamma, beta, st, range(n))
    if model.inv_3ei == 0 or not held.any():
        return theta_geom, held  # a rigid rod's coupling angle is its geometric angle
    e = np.where(held, lever[np.arange(n), which] * model.inv_3ei, 0.0)
    A = np.where(held, 1.0 + model.k * e, model.k)
    B = np.where(held, e, 1.0)
    R = np.where(held, theta_geom, 0.0)
    return _solve(model, pr, theta_geom, A, B, R), held


def _step(model: MechanicsModel, P: np.ndarray, st: ContactState) -> tuple[np.ndarray, np.ndarray]:
    """Advance the state to couplings P (n, 2); the angles are left in ``st``.

    Returns (n,) contact and branch contact. A step repeats engage / solve / release
    until nothing changes, since a rod springing back can sweep across further contacts.
    """
    fol = model.foliage
    rel = (fol.x - P[:, :1], fol.z - P[:, 1:])
    released = False
    for pass_ in range(_MAX_PASSES):
        engaged_new = engage(model, rel, st.theta, st)
        if pass_ > 0 and not (engaged_new or released):
            break
        st.theta, held = _equilibrium(model, P, rel, st)
        released, pr, ld = release(model, rel, st.theta, st)
    torque_h = foliage_torque(pr, ld)[0]
    torque_v = np.sum(fol.vertical[pr.cols] * ld.force * ld.a, axis=1)
    branch_torque = np.where(held, model.k * st.theta - torque_h, 0.0)
    st.theta_v = stick_slip(model, st.theta_v, torque_v, branch_torque)
    return held | np.any(ld.force > 0, axis=1), held


# -- public ----------------------------------------------------------------------------------


def simulate(
    spec: ArraySpec,
    offsets_mm: np.ndarray,
    branches: Sequence[RigidCylinder] = (),
    foliage: Sequence[CompliantContact] = (),
    max_step_mm: float = 0.5,
    branch_friction: float = ROD_ON_WOOD_FRICTION,
) -> MechanicsResult:
    """Deflect the whiskers of ``spec`` as the array moves through ``offsets_mm`` (T, 2).

    Steps are taken in order (contacts remember their side and state); moves longer than
    ``max_step_mm`` are sub-stepped internally and only the requested steps are returned.
    ``branch_friction`` is the rod-on-branch Coulomb coefficient (:mod:`scenes.rod_materials`).
    """
    check_finite("max_step_mm", float(max_step_mm), 0.0)
    offsets = check_offsets(offsets_mm)
    model = build_model(spec, branches, foliage, branch_friction)
    check_pivots_clear(model, offsets)
    path, keep = _substeps(offsets, float(max_step_mm))

    T, n = len(offsets), model.psi.size
    angles = np.zeros((T, n, 2))
    contact = np.zeros((T, n), dtype=bool)
    branch_contact = np.zeros((T, n), dtype=bool)
    st = initial_state(model, model.base + path[0])
    out = 0
    for s, offset in enumerate(path):
        touching, held = _step(model, model.base + offset, st)
        if s == keep[out]:
            angles[out, :, 0], angles[out, :, 1] = st.theta, st.theta_v
            contact[out], branch_contact[out] = touching, held
            out += 1
    return MechanicsResult(angles, contact, branch_contact)
