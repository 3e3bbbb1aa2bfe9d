"""Rendered tessellation of the foliage: the fidelity ladder's foliage-detail knob.

A :class:`FoliageDetail` sets only how finely the renderer's meshes sample shapes that
:mod:`scenes.vegetation` has already placed: leaf outlines, twig and branch sections. The contacts
the mechanics get never depend on it (leaves are cut by the array plane on a fixed outline of
``CONTACT_RIM_POINTS`` points, branches are exact cylinders) and it draws no random numbers, so
every level gives the same contacts. ``default`` is the tessellation datasets were made with;
``fine`` is the reference finer than it; paper strips are boxes at every level. Leaves are placed
by their 8-point outline, so a finer outline bulges past it by the chords' sagitta: up to about
4 mm in front of the foliage front (dense, intermediate, seed 0), where no contact is made.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from scenes.conventions import make_T, rot_x
from scenes.obstacles import RigidCylinder

if TYPE_CHECKING:
    import trimesh

#: Points on the leaf outline where the array plane cuts it for the mechanics: fixed, so the
#: contacts are the same at every detail level (it is the default level's outline).
CONTACT_RIM_POINTS = 8
BRANCH_HALF_LENGTH_MM = 400.0  # rendered from y = -400 to +400: fills the view band


@dataclass(frozen=True)
class FoliageDetail:
    """Points on each leaf's outline and sides of each twig and branch section."""

    leaf_rim_points: int
    twig_sections: int
    branch_sections: int

    def __post_init__(self) -> None:
        for name in ("leaf_rim_points", "twig_sections", "branch_sections"):
            if getattr(self, name) < 3:
                raise ValueError(f"{name}: need at least 3, got {getattr(self, name)}")


DETAIL_LEVELS: dict[str, FoliageDetail] = {
    "coarse": FoliageDetail(leaf_rim_points=4, twig_sections=3, branch_sections=12),
    "default": FoliageDetail(
        leaf_rim_points=CONTACT_RIM_POINTS, twig_sections=6, branch_sections=24
    ),
    "fine": FoliageDetail(leaf_rim_points=32, twig_sections=16, branch_sections=64),
}


def get_detail(detail: str | FoliageDetail) -> FoliageDetail:
    """A level by name (ValueError naming the levels), or a :class:`FoliageDetail` as given."""
    if isinstance(detail, FoliageDetail):
        return detail
    if detail not in DETAIL_LEVELS:
        raise ValueError(f"detail: unknown {detail!r}; choose from {', '.join(DETAIL_LEVELS)}")
    return DETAIL_LEVELS[detail]


def leaf_rims(
    blade_base: np.ndarray,
    axis: np.ndarray,
    side: np.ndarray,
    length: np.ndarray,
    width: np.ndarray,
    k: int,
) -> np.ndarray:
    """(m, k, 3) points on elliptic leaf outlines, point 0 at the blade's base.

    blade_base, axis (unit, base to tip), side (unit, across the blade): (m, 3); length, width:
    (m, 1, 1). Outlines with k a multiple of 8 pass through the 8-point outline's points.
    """
    t = np.linspace(0, 2 * math.pi, k, endpoint=False)[None, :, None]
    return (
        blade_base[:, None, :]
        + 0.5 * length * (1 - np.cos(t)) * axis[:, None, :]
        + 0.5 * width * np.sin(t) * side[:, None, :]
    )


def leaf_mesh(rim: np.ndarray) -> trimesh.Trimesh:
    """Fans of the leaf outlines (m, k, 3) about their centroids, with both windings (the renderer
    is one-sided)."""
    import trimesh

    m, k = rim.shape[:2]
    vertices = np.concatenate([rim.mean(axis=1)[:, None, :], rim], axis=1).reshape(-1, 3)
    start = (np.arange(m) * (k + 1))[:, None]
    j = np.arange(k)
    front = np.stack([start + 0 * j, start + 1 + j, start + 1 + (j + 1) % k], axis=-1)
    faces = np.concatenate([front.reshape(-1, 3), front.reshape(-1, 3)[:, ::-1]])
    return trimesh.Trimesh(vertices, faces, process=False)


def twig_mesh(
    base: np.ndarray, tip: np.ndarray, diameter_mm: float, sections: int
) -> trimesh.Trimesh:
    """Prisms from each base to its tip, (n, 3) each."""
    import trimesh

    return trimesh.util.concatenate(
        [
            trimesh.creation.cylinder(radius=0.5 * diameter_mm, segment=[b, e], sections=sections)
            for b, e in zip(base, tip, strict=True)
        ]
    )


def branch_mesh(branches: tuple[RigidCylinder, ...], sections: int) -> trimesh.Trimesh:
    """Vertical rods filling the view band."""
    import trimesh

    rods = []
    for b in branches:
        rod = trimesh.creation.cylinder(
            radius=b.radius_mm, height=2 * BRANCH_HALF_LENGTH_MM, sections=sections
        )
        rod.apply_transform(make_T(rot_x(math.pi / 2), [b.x_mm, 0.0, b.z_mm]))
        rods.append(rod)
    return trimesh.util.concatenate(rods)
