"""The whisker mechanics' inputs, checked and turned into arrays once per simulation.

:func:`build_model` validates the array spec's obstacles (finite numbers, positive
stiffnesses, the right types) and packs them as (m,) and (B,) arrays for the vectorized solver
in :mod:`scenes.mechanics`; :func:`check_pivots_clear` refuses a path that drives a whisker's
coupling through a branch.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from scenes.array import ArraySpec
from scenes.obstacles import CompliantContact, RigidCylinder
from scenes.rod_materials import ROD_ON_WOOD_FRICTION


@dataclass(frozen=True)
class FoliageArrays:
    """The compliant contacts as (m,) arrays."""

    x: np.ndarray
    z: np.ndarray
    stiffness: np.ndarray
    limit: np.ndarray
    give_way: np.ndarray
    vertical: np.ndarray


@dataclass(frozen=True)
class BranchArrays:
    """The rigid cylinders as (B,) arrays; ``r`` already includes the rod's radius."""

    x: np.ndarray
    z: np.ndarray
    r: np.ndarray


@dataclass(frozen=True)
class MechanicsModel:
    """Everything constant during a simulation."""

    psi: np.ndarray  # (n,) rest headings
    base: np.ndarray  # (n, 2) couplings at zero offset
    length: float
    k: float
    inv_3ei: float  # 1 / (3 EI), 0 for a rigid rod
    branch_friction: float  # Coulomb coefficient, rod on branch
    foliage: FoliageArrays
    branches: BranchArrays


def check_finite(
    name: str, value: float, minimum: float | None = None, strict: bool = True
) -> None:
    if not math.isfinite(value):
        raise ValueError(f"{name}: must be finite, got {value}")
    if minimum is not None and (value <= minimum if strict else value < minimum):
        raise ValueError(f"{name}: must be {'>' if strict else '>='} {minimum}, got {value}")


def check_offsets(offsets_mm: np.ndarray) -> np.ndarray:
    offsets = np.asarray(offsets_mm, dtype=float)
    if offsets.ndim != 2 or offsets.shape[1] != 2 or offsets.shape[0] < 1:
        raise ValueError(f"offsets_mm: expected shape (T >= 1, 2), got {offsets.shape}")
    if not np.all(np.isfinite(offsets)):
        raise ValueError("offsets_mm: must be finite (found NaN or inf)")
    return offsets


def _foliage_arrays(foliage: Sequence[CompliantContact]) -> FoliageArrays:
    for j, f in enumerate(foliage):
        if not isinstance(f, CompliantContact):
            raise ValueError(f"foliage[{j}]: expected CompliantContact, got {type(f).__name__}")
        check_finite(f"foliage[{j}].x_mm", f.x_mm)
        check_finite(f"foliage[{j}].z_mm", f.z_mm)
        check_finite(f"foliage[{j}].stiffness_N_per_mm", f.stiffness_N_per_mm, 0.0)
        check_finite(f"foliage[{j}].force_limit_N", f.force_limit_N, 0.0, strict=False)
        check_finite(f"foliage[{j}].give_way_mm", f.give_way_mm, 0.0)
        check_finite(f"foliage[{j}].vertical_ratio", f.vertical_ratio)
    fields = ("x_mm", "z_mm", "stiffness_N_per_mm", "force_limit_N", "give_way_mm")
    cols = [np.array([getattr(f, k) for f in foliage], dtype=float) for k in fields]
    vertical = np.array([f.vertical_ratio for f in foliage], dtype=float)
    return FoliageArrays(*cols, vertical=vertical)


def _branch_arrays(branches: Sequence[RigidCylinder], rod_radius: float) -> BranchArrays:
    for b, c in enumerate(branches):
        if not isinstance(c, RigidCylinder):
            raise ValueError(f"branches[{b}]: expected RigidCylinder, got {type(c).__name__}")
        check_finite(f"branches[{b}].x_mm", c.x_mm)
        check_finite(f"branches[{b}].z_mm", c.z_mm)
        check_finite(f"branches[{b}].radius_mm", c.radius_mm, 0.0)
    x = np.array([c.x_mm for c in branches], dtype=float)
    z = np.array([c.z_mm for c in branches], dtype=float)
    r = np.array([c.radius_mm for c in branches], dtype=float) + rod_radius
    return BranchArrays(x, z, r)


def check_pivots_clear(model: MechanicsModel, offsets: np.ndarray) -> None:
    """ValueError if any coupling's straight path between offsets enters a branch's disk."""
    br = model.branches
    if br.x.size == 0:
        return
    # Branch centres relative to each coupling at zero offset: (n, B, 2); the coupling moves
    # along the offset polyline, so measure each centre's distance to that polyline.
    rel = np.stack([br.x, br.z], axis=-1)[None] - model.base[:, None]
    points = offsets if len(offsets) > 1 else np.repeat(offsets, 2, axis=0)
    to_c = rel[None] - points[:-1, None, None]  # (S, n, B, 2)
    seg = np.diff(points, axis=0)[:, None, None]
    length2 = np.sum(seg * seg, axis=-1)
    t = np.clip(np.sum(to_c * seg, axis=-1) / np.where(length2 > 0, length2, 1.0), 0.0, 1.0)
    dist = np.linalg.norm(to_c - t[..., None] * seg, axis=-1)
    bad = dist <= br.r
    if np.any(bad):
        s, i, b = np.argwhere(bad)[0]
        raise ValueError(
            f"branches[{b}]: whisker {i}'s coupling enters the branch (pivot within "
            f"{br.r[b]:.3f} mm of its axis) between offsets {s} and {min(s + 1, len(offsets) - 1)}"
        )


def build_model(
    spec: ArraySpec,
    branches: Sequence[RigidCylinder],
    foliage: Sequence[CompliantContact],
    branch_friction: float = ROD_ON_WOOD_FRICTION,
) -> MechanicsModel:
    if not isinstance(spec, ArraySpec):
        raise ValueError(f"spec: expected ArraySpec, got {type(spec).__name__}")
    check_finite("branch_friction", float(branch_friction), 0.0, strict=False)
    psi = spec.headings_rad
    ei = spec.rod_bending_EI_Nmm2
    return MechanicsModel(
        psi=psi,
        base=spec.frame_radius_mm * np.stack([np.sin(psi), np.cos(psi)], axis=-1),
        length=float(spec.whisker_length_mm),
        k=float(spec.spring_Nmm_per_rad),
        inv_3ei=0.0 if ei is None else 1.0 / (3.0 * ei),
        branch_friction=float(branch_friction),
        foliage=_foliage_arrays(foliage),
        branches=_branch_arrays(branches, spec.whisker_diameter_mm / 2),
    )
