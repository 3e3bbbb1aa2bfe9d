"""The dynamic mechanics' time loop (:mod:`scenes.dynamics`), kept cheap: an indoor sample is
~130k steps of 0.5 ms, and at n = 13 whiskers a step costs its number of NumPy calls, not their
size. :class:`Stepper` computes what the shared contact pieces of :mod:`scenes.contacts` would,
but does per step only what can change:

* Branch shadows depend on the path alone: they are computed for a block of steps at once. A
  step with no branch in reach, at it or at the next step, skips the branch update (a rod's side
  of a shadow is then refreshed the step before the branch comes into reach, which is all the
  per-step refresh is used for).
* Foliage: the engaged pairs are a flat list, loaded there. For the free ones one (n, m) product
  tells whether any rod line crossed a contact or a contact has no side yet; only then (and when
  an engaged one lets go) the step runs :func:`scenes.contacts.engage` and
  :func:`scenes.contacts.release` as they are.
* Free stretches: between two samples, with nothing engaged, no branch in reach and no foliage
  within ``length + REACH_MARGIN_MM`` of any coupling, the integrator is linear; its N steps
  there are one 2 x 2 matrix power (the same state as stepping, to rounding).
"""

from __future__ import annotations

import math

import numpy as np

from scenes.contacts import (
    engage,
    foliage_torque,
    hold,
    initial_state,
    release,
    shadows,
)
from scenes.mechanics_model import MechanicsModel

#: A free stretch is jumped only while every contact is this much (mm) beyond a rod's reach: a
#: rod line that crosses a contact from one step to the next with the contact along the rod
#: (0 < a <= L) then needs a sideways move of sqrt((L + margin)^2 - L^2), ~38 mm at L = 140 mm.
REACH_MARGIN_MM = 5.0
_MAX_TURN_RAD = 0.05  # ... and a turn per step below this (free ringing bounds the rate)
_BLOCK_STEPS = 4096  # branch shadows are computed for this many steps at once


class Stepper:
    """Angles, rates and contacts of every whisker along a schedule of steps ``dts`` (S,) with
    the array at offsets ``path`` (S, 2); :meth:`advance` runs a range of steps."""

    def __init__(
        self,
        model: MechanicsModel,
        inertia: float,
        damping: float,
        P0: np.ndarray,
        dts: np.ndarray,
        path: np.ndarray,
    ):
        self.model, self.inertia, self.damping = model, inertia, damping
        self.dts, self.path, self.P_prev = dts.tolist(), path, P0
        self.st = initial_state(model, P0)
        n = model.psi.size
        self.rows = np.arange(n)
        self.omega, self.omega_v = np.zeros(n), np.zeros(n)
        self.held = self.no_one = np.zeros(n, dtype=bool)
        self.pushed = self.no_one
        self.has_branches = model.branches.x.size > 0
        self._block = (0, 0, None)  # first step, end, (gamma, beta, lever, branch flags)
        self._powers: dict[tuple[float, int], np.ndarray] = {}
        self._rebuild()

    # -- public --------------------------------------------------------------------------

    @property
    def contact(self) -> np.ndarray:
        """(n,) bool: the whisker touches a branch or a contact pushes it."""
        if self.pushed is None:  # fast steps leave it to be counted when asked
            count = np.bincount(self.e_w, self.e_force > 0, minlength=self.rows.size)
            self.pushed = count > 0
        return self.held | self.pushed

    def advance(self, s0: int, s1: int) -> None:
        """Run steps s0 .. s1 - 1 (one sample's segment: the array moves in a straight line)."""
        if s1 <= s0:
            return
        flags = self._branch_flags(s0, s1)
        if not flags.any() and self._free_segment(s0, s1):
            self._jump(s0, s1)
        else:
            for s in range(s0, s1):
                self._step(s, bool(flags[s - s0]))
        self.P_prev = self.model.base + self.path[s1 - 1]

    # -- branches ------------------------------------------------------------------------

    def _branch_flags(self, s0: int, s1: int) -> np.ndarray:
        """(s1 - s0,) bool: the step must update the branches (one in reach at it or the next)."""
        if not self.has_branches:
            return np.zeros(s1 - s0, dtype=bool)
        first, end, _ = self._block
        if s0 < first or s1 > end:
            self._load_block(s0, max(s1, s0 + _BLOCK_STEPS))
        first, _, (_, _, _, flags, _) = self._block
        return flags[s0 - first : s1 - first]

    def _load_block(self, s0: int, s1: int) -> None:
        m, S = self.model, len(self.dts)
        stop = min(s1 + 1, S)  # one step more: the next step's reach
        P = (m.base[None] + self.path[s0:stop, None]).reshape(-1, 2)
        gamma, beta, lever = (x.reshape(stop - s0, m.psi.size, -1) for x in shadows(m, P))
        near = (beta > 0).any(axis=2)
        watch = near | np.concatenate([near[1:], np.zeros_like(near[:1])])
        watched = [np.flatnonzero(w).tolist() for w in watch]
        self._block = (s0, min(s1, S), (gamma, beta, lever, watch.any(axis=1), watched))

    def _branches(self, s: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(edge angle, held, lever) at step s, as :func:`scenes.dynamics`' physics says."""
        m, st = self.model, self.st
        first, _, (gamma, beta, lever, _, watched) = self._block
        gamma, beta, lever = gamma[s - first], beta[s - first], lever[s - first]
        edge, held, which = hold(m, st.theta, gamma, beta, st, watched[s - first])
        return edge, held, lever[self.rows, which]

    # -- foliage -------------------------------------------------------------------------

    def _rebuild(self) -> None:
        """The flat list of engaged pairs and the free contacts' sides, after an event."""
        st, fol = self.st, self.model.foliage
        self.e_w, self.e_j = np.nonzero(st.engaged)
        self.e_back = -st.side[self.e_w, self.e_j]
        self.e_stiffness, self.e_limit = fol.stiffness[self.e_j], fol.limit[self.e_j]
        self.e_give_way, self.e_vertical = fol.give_way[self.e_j], fol.vertical[self.e_j]
        self.e_force = np.zeros(self.e_w.size)
        self.free_side = np.where(st.engaged, 0.0, st.side)
        self.unsided = bool(((st.side == 0) & ~st.engaged).any())

    def _foliage(self, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(n,) foliage torques on theta_h and theta_v at couplings P, engaging and releasing."""
        m, st, fol = self.model, self.st, self.model.foliage
        if not fol.x.size:
            return 0.0, 0.0
        rel = (fol.x - P[:, :1], fol.z - P[:, 1:])
        phi = m.psi + st.theta
        sin, cos = np.sin(phi), np.cos(phi)
        crossed = (self.free_side * (rel[0] * cos[:, None] - rel[1] * sin[:, None])).min() < 0
        if self.unsided or crossed:
            return self._event(rel)
        self.pushed = None
        if not self.e_w.size:
            return 0.0, 0.0
        w, j = self.e_w, self.e_j
        rx, rz, sin, cos = rel[0][w, j], rel[1][w, j], sin[w], cos[w]
        a, c = rx * sin + rz * cos, rx * cos - rz * sin  # scenes.contacts.project
        delta = self.e_back * c
        k_eff, cube = self.e_stiffness, np.maximum(a, 0.0) ** 3
        if m.inv_3ei:
            k_eff = k_eff / (1.0 + k_eff * cube * m.inv_3ei)
        force = np.minimum(np.maximum(k_eff * delta, 0.0), self.e_limit)
        own = delta - force * cube * m.inv_3ei  # the contact's own deflection
        gone = (delta <= 0) | (own > self.e_give_way) | (a <= 0) | (a > m.length)
        if gone.any():
            return self._event(rel)
        self.e_force = force
        n = self.rows.size
        torque = np.bincount(w, self.e_back * force * a, minlength=n)
        return torque, np.bincount(w, self.e_vertical * force * a, minlength=n)

    def _event(self, rel: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
        """A contact engages, lets go or takes a side: the shared dense update."""
        m, st = self.model, self.st
        engage(m, rel, st.theta, st)
        _, pr, ld = release(m, rel, st.theta, st)
        self._rebuild()
        self.pushed = np.any(ld.force > 0, axis=1)
        torque_v = np.sum(m.foliage.vertical[pr.cols] * ld.force * ld.a, axis=1)
        return foliage_torque(pr, ld)[0], torque_v

    # -- steps ---------------------------------------------------------------------------

    def _step(self, s: int, branches: bool) -> None:
        m, st, inertia, dt = self.model, self.st, self.inertia, self.dts[s]
        P = m.base + self.path[s]
        torque, torque_v = self._foliage(P)
        bending = m.inv_3ei > 0
        branch_torque, held = 0.0, self.no_one
        if branches and bending:
            edge, held, lever = self._branches(s)
            stiff = np.minimum(1.0 / (np.maximum(lever, 1e-9) * m.inv_3ei), inertia / (2 * dt) ** 2)
            branch_torque = np.where(held, stiff * (edge - st.theta), 0.0)
        relax = 1.0 + dt * self.damping / inertia  # implicit damping
        omega = (self.omega + dt / inertia * (torque + branch_torque - m.k * st.theta)) / relax
        theta = st.theta + dt * omega
        if branches and not bending:
            st.theta = theta
            edge, held, _ = self._branches(s)
            omega_held = (edge - (theta - dt * omega)) / dt  # the edge's velocity: inelastic
            branch_torque = np.where(held, inertia * (omega_held - omega) / dt, 0.0)
            omega, theta = np.where(held, omega_held, omega), edge
        st.theta, self.omega = theta, omega
        # Vertical: spring, foliage and the branch's Coulomb grip as an impulse bound.
        trial = (self.omega_v + dt / inertia * (torque_v - m.k * st.theta_v)) / relax
        self.omega_v = trial
        if held.any():
            grip = dt / inertia * m.branch_friction * np.abs(branch_torque) / relax
            self.omega_v = np.sign(trial) * np.maximum(np.abs(trial) - grip, 0.0)
        st.theta_v = st.theta_v + dt * self.omega_v
        self.held = held

    def _free_segment(self, s0: int, s1: int) -> bool:
        """Nothing engaged, and no contact within reach (+ margin) anywhere on the segment."""
        if self.e_w.size:
            return False
        m, st = self.model, self.st
        rate = math.sqrt(
            max(
                np.max(self.omega**2 + m.k / self.inertia * st.theta**2),
                np.max(self.omega_v**2 + m.k / self.inertia * st.theta_v**2),
            )
        )
        if rate * self.dts[s0] > _MAX_TURN_RAD:
            return False
        if not m.foliage.x.size:
            return True
        P = self.P_prev
        travel = float(np.hypot(*(m.base[0] + self.path[s1 - 1] - P[0])))
        nearest = np.hypot(m.foliage.x - P[:, :1], m.foliage.z - P[:, 1:]).min()
        return nearest - travel > m.length + REACH_MARGIN_MM

    def _jump(self, s0: int, s1: int) -> None:
        """The free steps s0 .. s1 - 1 (equal dt) as one power of the step's 2 x 2 matrix."""
        m, st, dt, count = self.model, self.st, self.dts[s0], s1 - s0
        power = self._powers.get((dt, count))
        if power is None:
            relax = 1.0 + dt * self.damping / self.inertia
            kick = dt * m.k / (self.inertia * relax)
            one = np.array([[1.0 - dt * kick, dt / relax], [-kick, 1.0 / relax]])
            power = self._powers[(dt, count)] = np.linalg.matrix_power(one, count)
        state = power @ np.stack(
            [np.concatenate([st.theta, st.theta_v]), np.concatenate([self.omega, self.omega_v])]
        )
        n = self.rows.size
        st.theta, st.theta_v = state[0, :n], state[0, n:]
        self.omega, self.omega_v = state[1, :n], state[1, n:]
        # Every contact takes the side of the rod line it ends on, as each step would set it.
        P = m.base + self.path[s1 - 1]
        phi = m.psi + st.theta
        rel_x, rel_z = m.foliage.x - P[:, :1], m.foliage.z - P[:, 1:]
        c = rel_x * np.cos(phi)[:, None] - rel_z * np.sin(phi)[:, None]
        st.side = np.where(c != 0, np.sign(c), st.side)
        self._rebuild()
        self.held, self.pushed = self.no_one, self.no_one
