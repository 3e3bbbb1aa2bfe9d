"""Where a branch can stand so that the array finds it: reachable positions and gaps.

A branch at x (vegetation frame, mm) is findable only if some whisker rod touches it for some
array offset of the sampling motion; :func:`branch_reach_error` refuses a dataset whose branch
no whisker can reach, and :func:`gap_of_branch` names the two whiskers around a branch (the
gap the pipeline should report).
"""

from __future__ import annotations

import math

import numpy as np

from scenes.array import ArraySpec, outward_cam
from scenes.vegetation import BRANCH_RADIUS_MM, branch_z_mm, reach_z_mm


def _touchable(
    x_mm: np.ndarray, z_mm: float, array: ArraySpec, sweep_mm: float, step_mm: float = 1.0
) -> np.ndarray:
    """(len(x),) whether a branch at (x, z) touches some rod at rest for some array offset in
    [-sweep, +sweep] (offsets sampled every ``step_mm``; the branch is 10 mm wide)."""
    n_steps = max(int(math.ceil(2 * sweep_mm / step_mm)), 1)
    offsets = np.linspace(-sweep_mm, sweep_mm, n_steps + 1)
    u = outward_cam(array)[:, [0, 2]]
    start = array.frame_radius_mm * u
    seg = array.whisker_length_mm * u
    rel = np.stack(np.broadcast_arrays(x_mm[:, None] - offsets[None, :], z_mm), axis=-1)
    d = rel[:, :, None, :] - start  # (x, offset, whisker, 2)
    s = np.clip(np.sum(d * seg, axis=-1) / np.sum(seg * seg, axis=-1), 0.0, 1.0)
    dist = np.linalg.norm(d - s[..., None] * seg, axis=-1)
    return (dist <= BRANCH_RADIUS_MM + 0.5 * array.whisker_diameter_mm).any(axis=(1, 2))


def _reach_limit_mm(array: ArraySpec, sweep_mm: float) -> int:
    """A bound on |x| of any branch a rod can touch: the rods' reach, the sweep, the branch's
    and the rod's radii (the contact test's distance)."""
    return math.ceil(
        reach_z_mm(array) + sweep_mm + BRANCH_RADIUS_MM + 0.5 * array.whisker_diameter_mm
    )


def _reachable_ranges(distance: str, array: ArraySpec, sweep_mm: float) -> str:
    """The reachable branch positions at a distance as 'a..b' intervals (1 mm grid)."""
    limit = _reach_limit_mm(array, sweep_mm)
    grid = np.arange(-limit, limit + 1, dtype=float)
    ok = _touchable(grid, branch_z_mm(distance, array), array, sweep_mm)
    edges = np.flatnonzero(np.diff(np.concatenate([[False], ok, [False]]).astype(int)))
    runs = edges.reshape(-1, 2)
    return ", ".join(f"{grid[a]:g}..{grid[b - 1]:g}" for a, b in runs) or "none"


def branch_reach_error(
    branches_mm: tuple[float, ...], distance: str, array: ArraySpec, sweep_mm: float
) -> str | None:
    """None if a whisker can touch every branch while sweeping +/- ``sweep_mm``; else a line
    naming the first unreachable branch and the reachable x range at that distance."""
    z = branch_z_mm(distance, array)
    xs = np.asarray(branches_mm, dtype=float)
    if xs.size == 0:
        return None
    ok = np.abs(xs) <= _reach_limit_mm(array, sweep_mm)  # no rod reaches beyond it
    ok[ok] = _touchable(xs[ok], z, array, sweep_mm)
    if ok.all():
        return None
    bad = xs[np.argmin(ok)]
    ranges = _reachable_ranges(distance, array, sweep_mm)
    return (
        f"branch at x = {bad:g} mm is out of reach at distance {distance!r} with a "
        f"+/-{sweep_mm:g} mm sweep; reachable x: {ranges} mm"
    )


#: A branch within this of a whisker's heading counts as on it (rounding of x and headings).
ON_HEADING_TOL_RAD = 1e-9


def gap_of_branch(x_mm: float, distance: str, array: ArraySpec) -> tuple[int, int]:
    """The neighbouring whiskers (i, i + 1), left to right, whose headings bracket the branch's
    bearing atan2(x, z_branch). A branch on a whisker's heading belongs to the gap on its right;
    one outside the arc is clamped to the outermost gap on its side (the right end, on the last
    whisker, also gives the last gap)."""
    bearing = math.atan2(x_mm, branch_z_mm(distance, array))
    k = int(np.searchsorted(array.headings_rad, bearing + ON_HEADING_TOL_RAD, side="right")) - 1
    i = min(max(k, 0), array.n_whiskers - 2)
    return i, i + 1
