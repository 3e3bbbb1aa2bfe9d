"""What the whiskers can touch, as plain data shared by the mechanics and the renderer.

All obstacles live in the *vegetation frame* (``veg``): the camera frame of the array at its
sampling position (array offset zero), in mm. The vegetation does not move; the array does
(:mod:`scenes.motion`), so an obstacle at ``p_veg`` is at ``p_veg - offset`` in the camera frame.
Contacts are resolved in the horizontal plane of the array (camera x and z); obstacles hang or
stand parallel to the camera's y axis.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class RigidCylinder:
    """A rigid branch: a round rod parallel to camera y through (x_mm, z_mm) of the vegetation
    frame. The whisker cannot pass through it (SPEC 1: it imposes a displacement)."""

    x_mm: float
    z_mm: float
    radius_mm: float = 5.0


@dataclass(frozen=True)
class CompliantContact:
    """A piece of foliage (paper strip, leaf, twig) that crosses the array's plane at
    (x_mm, z_mm) of the vegetation frame. Pushed sideways by a whisker by delta mm it resists with
    ``min(stiffness_N_per_mm * delta, force_limit_N)``; beyond ``give_way_mm`` it slips past the
    rod. ``vertical_ratio`` is the out-of-plane share of its force (a tilted strip or leaf pushes
    the whisker up or down as well as sideways)."""

    x_mm: float
    z_mm: float
    stiffness_N_per_mm: float
    force_limit_N: float
    give_way_mm: float
    vertical_ratio: float = 0.0
