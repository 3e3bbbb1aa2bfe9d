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

Rod bending (optional, ``spec.rod_bending_EI_Nmm2`` not None). A load ``F`` at ``a`` turns the
coupling by ``F a / k`` and bends the rod as a small-deflection cantilever, so the contact point
lies on a line at ``F a (1/k + a/(3 EI))``. For foliage this is a spring ``3 EI / a^3`` in series
with the strip (its effective stiffness drops, its own deflection is what gives way); for a branch
the geometric angle is the interval edge and the coupling takes only its share
``(1/k) / (1/k + a/(3 EI))`` of it (with foliage engaged too, the coupling angle solves the
branch constraint and the foliage torque together). Each load's bending is independent of the
others' (exact for a single contact).

Left out: friction (contacts push perpendicular to the rod, so a branch never drags a rod
along), rod dynamics, inertia and oscillation (quasi-static), axial loads and buckling, the coupling
of ``theta_v`` into the plane geometry (contacts are solved as if the rod stayed in the plane),
strips bending visibly (foliage is a point spring), the rod's radius for foliage (it counts for
branches only), and the rod's bent shape for foliage (each strip sees the line at the coupling
angle, plus its own series bending).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from scenes.array import ArraySpec
from scenes.mechanics_model import (
    MechanicsModel,
    build_model,
    check_finite,
    check_offsets,
    check_pivots_clear,
)
from scenes.obstacles import CompliantContact, RigidCylinder

_TOL_RAD = 1e-10  # Newton stops when every whisker's step is below this (quadratic: error ~1e-20)
_MAX_NEWTON = 80  # enough for pure bisection from any bracket at float64 resolution
_MAX_PASSES = 8  # engage / solve / release rounds per step (springback can sweep new contacts)

_Rel = tuple[np.ndarray, np.ndarray]  # (n, m) x and z of every contact relative to every coupling


@dataclass(frozen=True)
class MechanicsResult:
    """Deflection of every whisker at every requested time step."""

    angles_rad: np.ndarray  # (T, n, 2) float64: (theta_h, theta_v), scenes.array's convention
    contact: np.ndarray  # (T, n) bool: the whisker touches any obstacle
    branch_contact: np.ndarray  # (T, n) bool: it touches a RigidCylinder


@dataclass
class _State:
    """History a step depends on (mutated in place, one step after the other)."""

    theta: np.ndarray  # (n,) coupling angle theta_h
    engaged: np.ndarray  # (n, m) bool
    side: np.ndarray  # (n, m) sign of the contact's side of the rod line, 0 = on it
    branch_side: np.ndarray  # (n, B) +-1: the rod's side of each branch's shadow


@dataclass(frozen=True)
class _Loads:
    """Foliage loads on the pairs of a :class:`_Pairs` for given coupling angles, (n, m') each."""

    a: np.ndarray  # projection on the rod (lever arm)
    c: np.ndarray  # signed distance from the rod line, + towards increasing heading
    delta: np.ndarray  # the rod's push past the rest point (> 0 when pushing)
    k_eff: np.ndarray  # strip stiffness in series with the rod's bending
    force: np.ndarray  # contact force magnitude (0 unless engaged and pushed)


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


# -- foliage ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Pairs:
    """(whisker, contact) pairs of one step restricted to the engaged contacts: the solver then
    works on a handful of columns instead of all foliage."""

    cols: np.ndarray  # (m',) indices into the foliage
    rx: np.ndarray  # (n, m') contact rest points relative to the couplings
    rz: np.ndarray
    side: np.ndarray  # (n, m')
    engaged: np.ndarray  # (n, m')
    back: np.ndarray  # (n, m') -side where engaged, else 0: the direction the contact pushes
    stiffness: np.ndarray  # (m',)
    limit: np.ndarray  # (m',)


def _engaged_pairs(model: MechanicsModel, rel: _Rel, st: _State) -> _Pairs:
    cols = np.flatnonzero(st.engaged.any(axis=0))
    side, engaged = st.side[:, cols], st.engaged[:, cols]
    fol = model.foliage
    return _Pairs(
        cols,
        rel[0][:, cols],
        rel[1][:, cols],
        side,
        engaged,
        np.where(engaged, -side, 0.0),
        fol.stiffness[cols],
        fol.limit[cols],
    )


def _project(rx: np.ndarray, rz: np.ndarray, phi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(a, c): each point's position along the rods at headings phi and its signed distance
    from their lines (+ towards increasing heading)."""
    sin, cos = np.sin(phi)[:, None], np.cos(phi)[:, None]
    return rx * sin + rz * cos, rx * cos - rz * sin


def _loads(model: MechanicsModel, pr: _Pairs, theta: np.ndarray) -> _Loads:
    """Loads of the engaged contacts with the rods at coupling angles ``theta``."""
    a, c = _project(pr.rx, pr.rz, model.psi + theta)
    delta = pr.back * c
    k_eff = pr.stiffness
    if model.inv_3ei:
        k_eff = k_eff / (1.0 + k_eff * np.maximum(a, 0.0) ** 3 * model.inv_3ei)
    force = np.minimum(np.maximum(k_eff * delta, 0.0), pr.limit)
    return _Loads(a, c, delta, k_eff, force)


def _torque(pr: _Pairs, ld: _Loads) -> tuple[np.ndarray, np.ndarray]:
    """(n,) foliage torque on theta_h and its derivative d torque / d theta_h."""
    torque = (pr.back * ld.force * ld.a).sum(axis=1)
    elastic = (ld.force > 0) & (ld.force < pr.limit)
    return torque, (ld.force * ld.delta - elastic * ld.k_eff * ld.a * ld.a).sum(axis=1)


def _solve(
    model: MechanicsModel,
    pr: _Pairs,
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
        torque, slope = _torque(pr, _loads(model, pr, theta))
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


def _engage(model: MechanicsModel, rel: _Rel, theta: np.ndarray, st: _State) -> bool:
    """Engage contacts the rod lines have swept across; refresh the others' sides."""
    a, c = _project(*rel, model.psi + theta)
    free = ~st.engaged
    new = free & (st.side * c < 0) & (a > 0) & (a <= model.length)
    st.engaged |= new
    st.side = np.where(free & ~new & (c != 0), np.sign(c), st.side)
    return bool(new.any())


def _release(
    model: MechanicsModel, rel: _Rel, theta: np.ndarray, st: _State
) -> tuple[bool, _Pairs, _Loads]:
    """Disengage contacts left behind, given way or off the rod; they keep their current side.

    Returns whether any did, and the loads that remain.
    """
    pr = _engaged_pairs(model, rel, st)
    ld = _loads(model, pr, theta)
    own_deflection = ld.delta - ld.force * np.maximum(ld.a, 0.0) ** 3 * model.inv_3ei
    gone = pr.engaged & (
        (ld.delta <= 0)
        | (own_deflection > model.foliage.give_way[pr.cols])
        | (ld.a <= 0)
        | (ld.a > model.length)
    )
    st.engaged[:, pr.cols] = pr.engaged & ~gone
    st.side[:, pr.cols] = np.where(gone & (ld.c != 0), np.sign(ld.c), pr.side)
    return bool(gone.any()), pr, replace(ld, force=np.where(gone, 0.0, ld.force))


# -- branches --------------------------------------------------------------------------------


def _shadows(model: MechanicsModel, P: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(gamma, beta, lever), each (n, B): blocked headings gamma +- beta, contact distance."""
    br, L = model.branches, model.length
    dx, dz = br.x - P[:, :1], br.z - P[:, 1:]
    D = np.hypot(dx, dz)
    tangent = np.sqrt(D**2 - br.r**2)
    cos_tip = np.clip((D**2 + L**2 - br.r**2) / (2 * D * L), -1.0, 1.0)
    beta = np.where(
        tangent <= L, np.arcsin(br.r / D), np.where(D - br.r < L, np.arccos(cos_tip), 0)
    )
    return np.arctan2(dx, dz), beta, np.minimum(tangent, L)


def _wrap(angle: np.ndarray) -> np.ndarray:
    return (angle + np.pi) % (2 * np.pi) - np.pi


def _clamp(
    model: MechanicsModel,
    theta_free: np.ndarray,
    gamma: np.ndarray,
    beta: np.ndarray,
    side: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(geometric angle, held (n,) bool, index of the holding branch): keep rods out of shadows.

    Every branch in reach ahead of the rod bounds theta from its remembered side; the rod takes
    the admissible angle nearest its free one.
    """
    u = _wrap(model.psi[:, None] + theta_free[:, None] - gamma)
    near = (beta > 0) & (np.abs(u) < np.pi / 2)
    upper_edge = theta_free[:, None] + beta - u  # theta at the edge of increasing heading
    lower_edge = theta_free[:, None] - beta - u
    lo = np.where(near & (side > 0), upper_edge, -np.inf)
    hi = np.where(near & (side < 0), lower_edge, np.inf)
    lo_max, hi_min = lo.max(axis=1), hi.min(axis=1)
    # Jammed (no admissible angle): leave the whole group of shadows on the nearer side.
    out_up = np.where(near, upper_edge, -np.inf).max(axis=1)
    out_down = np.where(near, lower_edge, np.inf).min(axis=1)
    jam_up = out_up - theta_free <= theta_free - out_down
    jammed = lo_max > hi_min
    lo_max = np.where(jammed & jam_up, out_up, np.where(jammed, -np.inf, lo_max))
    hi_min = np.where(jammed & ~jam_up, out_down, np.where(jammed, np.inf, hi_min))
    theta = np.clip(theta_free, lo_max, hi_min)
    gap = np.minimum(np.abs(upper_edge - theta[:, None]), np.abs(lower_edge - theta[:, None]))
    which = np.argmin(np.where(near, gap, np.inf), axis=1)
    return theta, theta != theta_free, which


def _refresh_branch_sides(
    model: MechanicsModel, theta_geom: np.ndarray, gamma: np.ndarray, beta: np.ndarray, st: _State
) -> None:
    """Remember the side of every shadow the rod is (strictly) outside of."""
    u = _wrap(model.psi[:, None] + theta_geom[:, None] - gamma)
    st.branch_side = np.where(np.abs(u) > beta, np.sign(u), st.branch_side)


# -- one step --------------------------------------------------------------------------------


def _equilibrium(
    model: MechanicsModel, P: np.ndarray, rel: _Rel, st: _State
) -> tuple[np.ndarray, np.ndarray]:
    """(coupling angles, held by a branch): spring + foliage equilibrium, then branches."""
    n = model.psi.size
    pr = _engaged_pairs(model, rel, st)
    theta_free = _solve(model, pr, st.theta, model.k, np.ones(n), np.zeros(n))
    if model.branches.x.size == 0:
        return theta_free, np.zeros(n, dtype=bool)
    gamma, beta, lever = _shadows(model, P)
    theta_geom, held, which = _clamp(model, theta_free, gamma, beta, st.branch_side)
    _refresh_branch_sides(model, theta_geom, gamma, beta, st)
    if model.inv_3ei == 0 or not held.any():
        return theta_geom, held  # a rigid rod's coupling angle is its geometric angle
    e = np.where(held, lever[np.arange(n), which] * model.inv_3ei, 0.0)
    A = np.where(held, 1.0 + model.k * e, model.k)
    B = np.where(held, e, 1.0)
    R = np.where(held, theta_geom, 0.0)
    return _solve(model, pr, theta_geom, A, B, R), held


def _step(
    model: MechanicsModel, P: np.ndarray, st: _State
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Advance the state to couplings P (n, 2); theta_h is left in ``st.theta``.

    Returns (n,) theta_v, contact and branch contact. A step repeats engage / solve / release
    until nothing changes, since a rod springing back can sweep across further contacts.
    """
    fol = model.foliage
    rel = (fol.x - P[:, :1], fol.z - P[:, 1:])
    released = False
    for pass_ in range(_MAX_PASSES):
        engaged_new = _engage(model, rel, st.theta, st)
        if pass_ > 0 and not (engaged_new or released):
            break
        st.theta, held = _equilibrium(model, P, rel, st)
        released, pr, ld = _release(model, rel, st.theta, st)
    theta_v = np.sum(fol.vertical[pr.cols] * ld.force * ld.a, axis=1) / model.k
    return theta_v, held | np.any(ld.force > 0, axis=1), held


# -- public ----------------------------------------------------------------------------------


def _initial_state(model: MechanicsModel, P: np.ndarray) -> _State:
    """Rods at rest, nothing engaged, sides taken from the rest configuration."""
    n, m = model.psi.size, model.foliage.x.size
    st = _State(
        theta=np.zeros(n),
        engaged=np.zeros((n, m), dtype=bool),
        side=np.zeros((n, m)),
        branch_side=np.ones((n, model.branches.x.size)),
    )
    if model.branches.x.size:
        gamma, _, _ = _shadows(model, P)
        u = _wrap(model.psi[:, None] - gamma)
        st.branch_side = np.where(u < 0, -1.0, 1.0)
    return st


def simulate(
    spec: ArraySpec,
    offsets_mm: np.ndarray,
    branches: Sequence[RigidCylinder] = (),
    foliage: Sequence[CompliantContact] = (),
    max_step_mm: float = 0.5,
) -> MechanicsResult:
    """Deflect the whiskers of ``spec`` as the array moves through ``offsets_mm`` (T, 2).

    Steps are taken in order (contacts remember their side and state); moves longer than
    ``max_step_mm`` are sub-stepped internally and only the requested steps are returned.
    """
    if not isinstance(spec, ArraySpec):
        raise ValueError(f"spec: expected ArraySpec, got {type(spec).__name__}")
    check_finite("max_step_mm", float(max_step_mm), 0.0)
    offsets = check_offsets(offsets_mm)
    model = build_model(spec, branches, foliage)
    check_pivots_clear(model, offsets)
    path, keep = _substeps(offsets, float(max_step_mm))

    T, n = len(offsets), model.psi.size
    angles = np.zeros((T, n, 2))
    contact = np.zeros((T, n), dtype=bool)
    branch_contact = np.zeros((T, n), dtype=bool)
    st = _initial_state(model, model.base + path[0])
    out = 0
    for s, offset in enumerate(path):
        theta_v, touching, held = _step(model, model.base + offset, st)
        if s == keep[out]:
            angles[out, :, 0], angles[out, :, 1] = st.theta, theta_v
            contact[out], branch_contact[out] = touching, held
            out += 1
    return MechanicsResult(angles, contact, branch_contact)
