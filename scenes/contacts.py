"""Contacts of the whisker rods, shared by the quasi-static and the dynamic mechanics.

The model (foliage points that engage when swept across and push back until they give way,
branches whose shadows bound the rod's heading) is described in :mod:`scenes.mechanics`; this
module holds its per-step pieces, vectorized over whiskers: the foliage's engage / load / release
and the branches' shadows and side memory. Both drivers (:mod:`scenes.mechanics`,
:mod:`scenes.dynamics`) advance one :class:`ContactState` step by step with these.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass, replace

import numpy as np

from scenes.mechanics_model import MechanicsModel

Rel = tuple[np.ndarray, np.ndarray]  # (n, m) x and z of every contact relative to every coupling
_TAU = 2 * math.pi


@dataclass
class ContactState:
    """History a step depends on (mutated in place, one step after the other)."""

    theta: np.ndarray  # (n,) coupling angle theta_h
    theta_v: np.ndarray  # (n,) vertical coupling angle (it sticks while a branch grips the rod)
    engaged: np.ndarray  # (n, m) bool
    side: np.ndarray  # (n, m) sign of the contact's side of the rod line, 0 = on it
    branch_side: np.ndarray  # (n, B) +-1: the rod's side of each branch's shadow


@dataclass(frozen=True)
class Loads:
    """Foliage loads on the pairs of a :class:`Pairs` for given coupling angles, (n, m') each."""

    a: np.ndarray  # projection on the rod (lever arm)
    c: np.ndarray  # signed distance from the rod line, + towards increasing heading
    delta: np.ndarray  # the rod's push past the rest point (> 0 when pushing)
    k_eff: np.ndarray  # strip stiffness in series with the rod's bending
    force: np.ndarray  # contact force magnitude (0 unless engaged and pushed)


# -- foliage ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class Pairs:
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


def engaged_pairs(model: MechanicsModel, rel: Rel, st: ContactState) -> Pairs:
    cols = np.flatnonzero(st.engaged.any(axis=0))
    side, engaged = st.side[:, cols], st.engaged[:, cols]
    fol = model.foliage
    return Pairs(
        cols,
        rel[0][:, cols],
        rel[1][:, cols],
        side,
        engaged,
        np.where(engaged, -side, 0.0),
        fol.stiffness[cols],
        fol.limit[cols],
    )


def project(rx: np.ndarray, rz: np.ndarray, phi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(a, c): each point's position along the rods at headings phi and its signed distance
    from their lines (+ towards increasing heading)."""
    sin, cos = np.sin(phi)[:, None], np.cos(phi)[:, None]
    return rx * sin + rz * cos, rx * cos - rz * sin


def loads(model: MechanicsModel, pr: Pairs, theta: np.ndarray) -> Loads:
    """Loads of the engaged contacts with the rods at coupling angles ``theta``."""
    a, c = project(pr.rx, pr.rz, model.psi + theta)
    delta = pr.back * c
    k_eff = pr.stiffness
    if model.inv_3ei:
        k_eff = k_eff / (1.0 + k_eff * np.maximum(a, 0.0) ** 3 * model.inv_3ei)
    force = np.minimum(np.maximum(k_eff * delta, 0.0), pr.limit)
    return Loads(a, c, delta, k_eff, force)


def foliage_torque(pr: Pairs, ld: Loads) -> tuple[np.ndarray, np.ndarray]:
    """(n,) foliage torque on theta_h and its derivative d torque / d theta_h."""
    torque = (pr.back * ld.force * ld.a).sum(axis=1)
    elastic = (ld.force > 0) & (ld.force < pr.limit)
    return torque, (ld.force * ld.delta - elastic * ld.k_eff * ld.a * ld.a).sum(axis=1)


def engage(model: MechanicsModel, rel: Rel, theta: np.ndarray, st: ContactState) -> bool:
    """Engage contacts the rod lines have swept across; refresh the others' sides."""
    a, c = project(*rel, model.psi + theta)
    free = ~st.engaged
    new = free & (st.side * c < 0) & (a > 0) & (a <= model.length)
    st.engaged |= new
    st.side = np.where(free & ~new & (c != 0), np.sign(c), st.side)
    return bool(new.any())


def release(
    model: MechanicsModel, rel: Rel, theta: np.ndarray, st: ContactState
) -> tuple[bool, Pairs, Loads]:
    """Disengage contacts left behind, given way or off the rod; they keep their current side.

    Returns whether any did, and the loads that remain.
    """
    pr = engaged_pairs(model, rel, st)
    ld = loads(model, pr, theta)
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


def shadows(model: MechanicsModel, P: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
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


def wrap(angle: np.ndarray) -> np.ndarray:
    return (angle + np.pi) % (2 * np.pi) - np.pi


def hold(
    model: MechanicsModel,
    theta_free: np.ndarray,
    gamma: np.ndarray,
    beta: np.ndarray,
    st: ContactState,
    rows: Iterable[int],
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(geometric angle, held (n,) bool, index of the holding branch, 0 where not held): keep
    the rods ``rows`` out of the shadows (the others have no branch in reach), then remember
    their side of every shadow they are (strictly) outside of.

    Every branch in reach ahead of the rod bounds theta from its remembered side; the rod takes
    the admissible angle nearest its free one. If the sides remembered for two branches leave
    none (jammed), it leaves the whole group of shadows on the side nearer its free angle. Plain
    floats per rod: only a few rods meet a branch, and the dynamics call this every step.
    """
    theta, which = theta_free.copy(), np.zeros(theta_free.size, dtype=int)
    frees, headings = theta_free.tolist(), model.psi.tolist()
    all_centres, all_halves, all_sides = gamma.tolist(), beta.tolist(), st.branch_side.tolist()
    for i in rows:
        free, psi = frees[i], headings[i]
        centres, halves, sides = all_centres[i], all_halves[i], all_sides[i]
        lo = out_up = -math.inf
        hi = out_down = math.inf
        near = []  # (branch, theta at the edge of increasing heading, ... of decreasing)
        for b, (centre, half, side) in enumerate(zip(centres, halves, sides, strict=True)):
            u = (psi + free - centre + math.pi) % _TAU - math.pi
            if half > 0 and abs(u) < math.pi / 2:
                upper, lower = free + half - u, free - half - u
                near.append((b, upper, lower))
                out_up, out_down = max(out_up, upper), min(out_down, lower)
                lo = max(lo, upper) if side > 0 else lo
                hi = min(hi, lower) if side < 0 else hi
        if lo > hi and out_up - free <= free - out_down:
            lo, hi = out_up, math.inf
        elif lo > hi:
            lo, hi = -math.inf, out_down
        geom = theta[i] = min(max(free, lo), hi)
        if geom != free:
            which[i] = min(near, key=lambda e: min(abs(e[1] - geom), abs(e[2] - geom)))[0]
        for b, (centre, half, side) in enumerate(zip(centres, halves, sides, strict=True)):
            u = (psi + geom - centre + math.pi) % _TAU - math.pi
            if abs(u) > half and (u > 0) != (side > 0):
                st.branch_side[i, b] = 1.0 if u > 0 else -1.0
    return theta, theta != theta_free, which


def initial_state(model: MechanicsModel, P: np.ndarray) -> ContactState:
    """Rods at rest, nothing engaged, sides taken from the rest configuration."""
    n, m = model.psi.size, model.foliage.x.size
    st = ContactState(
        theta=np.zeros(n),
        theta_v=np.zeros(n),
        engaged=np.zeros((n, m), dtype=bool),
        side=np.zeros((n, m)),
        branch_side=np.ones((n, model.branches.x.size)),
    )
    if model.branches.x.size:
        gamma, _, _ = shadows(model, P)
        u = wrap(model.psi[:, None] - gamma)
        st.branch_side = np.where(u < 0, -1.0, 1.0)
    return st


def stick_slip(
    model: MechanicsModel, theta_v: np.ndarray, torque_v: np.ndarray, branch_torque: np.ndarray
) -> np.ndarray:
    """(n,) vertical coupling angles after a quasi-static step (Coulomb stick-slip).

    A rod pressed against a branch (a vertical cylinder) with normal force N at lever a slides
    along it, i.e. changes theta_v, only when the vertical torque it must carry,
    ``k theta_v - torque_v``, exceeds the grip ``mu N a = mu |branch_torque|``; then it slides
    to the edge of that band. Free rods (branch_torque 0) take ``torque_v / k``.
    """
    grip = model.branch_friction * np.abs(branch_torque)
    return np.clip(theta_v, (torque_v - grip) / model.k, (torque_v + grip) / model.k)
