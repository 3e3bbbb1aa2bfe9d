"""Procedural, seeded vegetation (SPEC 2) as plain data: one object drives contacts and meshes.

Everything is in the vegetation frame of :mod:`scenes.obstacles` (the camera frame of the array
at its sampling position, mm; +y is down; the array lies in the plane y = 0). The same
:class:`Vegetation` gives the mechanics its obstacles (:class:`RigidCylinder` branches and
:class:`CompliantContact` foliage, where the geometry crosses y = 0) and the renderer its meshes,
so what the whiskers feel is what the camera sees.

Geometry: the foliage front is the plane z = ``z_front`` =
``frame_radius_mm + whisker_length_mm - SAMPLING_PENETRATION_MM[distance]``; branches stand
``BRANCH_BEHIND_FOLIAGE_MM`` behind it.

Foliage forces (all foliage is a cantilever that slips off the whisker rod)
    A cantilever of bending stiffness EI loaded at lever h from its clamp has stiffness
    k = 3 EI / h^3 and slope F h^2 / (2 EI) at the load. The whisker pushes it sideways; the
    contact holds by friction only while that slope stays below the slip angle, tan(slip) = mu
    (the push splits into a normal part and a part along the strip or leaf that friction must
    carry). So the force peaks at F_max = 2 EI mu / h^2, reached at a push of
    give_way = F_max / k = (2/3) h mu; beyond it the contact slides towards the free end and the
    force falls: we model that as giving way at once. mu is the rod's friction on the foliage
    (:mod:`scenes.foliage_materials`, from :mod:`scenes.rod_materials`): 0.4 on paper, 0.35 on
    bark, 0.3 on leaves (slip angles 21.8, 19.3, 16.7 deg).

Paper strips ("soft" 80 g/m2, "stiff" 160 g/m2; numbers and sources in
:mod:`scenes.foliage_materials`)
    Calliper 0.10 mm and 0.19 mm, in-plane Young's modulus E = 2.92 GPa. Bending stiffness per
    width D = E t^3 / 12: 0.243 N mm (soft) and 1.669 N mm (stiff). A strip of width w = 12 mm
    has EI = D w = 2.92 and 20.0 N mm^2. The strips are cut from a sheet that stays whole above
    y = -h, h = 35 mm above the array plane, so each strip is a cantilever clamped there and
    loaded at y = 0 (the strip twists to meet the rod with its face, so its edgewise stiffness
    never engages): F_max = 2 EI mu / h^2 = 1.91 mN (soft) and 13.1 mN (stiff), k = 2.04e-4 and
    1.40e-3 N/mm, give_way = 9.33 mm for both. At the far distance the central whisker meets the
    strips 95 mm from its coupling: one soft strip gives 0.18 N mm, 0.032 rad, 0.25 mm of marker
    travel, one stiff strip 1.24 N mm, 0.22 rad, 1.7 mm; a branch imposes its displacement and
    gives several mm.

Natural foliage ("sparse": Cornus mas, "dense": Tilia tomentosa; :mod:`scenes.foliage_materials`)
    Twigs are young shoots (E = 1 GPa, diameter 1.1 / 1.4 mm: EI = E pi d^4 / 64 = 71.9 /
    189 N mm^2) loaded at their distance from the twig's base. Leaves are blades on petioles
    loaded at their distance from the blade's base, with EI = D * 45 mm of loaded blade, D from a
    lamina of E = 100 MPa and t = 0.2 / 0.3 mm: 3.0 / 10.1 N mm^2. The parent stem, the petiole
    and the twig flex in series, so levers count as at least 80 mm (twigs) and 25 mm (leaves):
    F_max is at most 7.9 / 21 mN for twigs and 2.9 / 9.7 mN for leaves, with medians (close,
    seeds 0-5) of 3.2 / 19 mN and 1.4 / 3.0 mN. The dense kind has more, larger, stiffer leaves
    and stiffer twigs.

Rendered detail: ``build_vegetation(..., detail=)`` sets only the meshes' tessellation
(:mod:`scenes.foliage_meshes`); the contacts are the same at every level.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from scenes.array import ArraySpec
from scenes.conventions import make_T, rot_y
from scenes.foliage_materials import (
    BRANCH_ALBEDO,
    LEAF_MODULUS_MPA,
    LEAF_SLIP_FRICTION,
    NATURAL,
    PAPER_ALBEDO,
    PAPER_MODULUS_MPA,
    PAPER_SLIP_FRICTION,
    PAPER_THICKNESS_MM,
    RGB,
    TWIG_ALBEDO,
    TWIG_MODULUS_MPA,
    TWIG_SLIP_FRICTION,
    NaturalKind,
)
from scenes.foliage_meshes import (
    CONTACT_RIM_POINTS,
    FoliageDetail,
    branch_mesh,
    get_detail,
    leaf_mesh,
    leaf_rims,
    twig_mesh,
)
from scenes.obstacles import CompliantContact, RigidCylinder

if TYPE_CHECKING:
    import trimesh

# Geometry of the lab's set-up: SPEC 2 gives the branch; the rest are *estimates* of how the
# foliage was hung (no drawing of it exists), each a constant a study can sweep.

#: How far the foliage front lies inside the central whisker's span, back from its tip (mm).
SAMPLING_PENETRATION_MM = {"far": 45.0, "intermediate": 85.0, "close": 125.0}
#: Branch centres lie this far behind the foliage front (mm).
BRANCH_BEHIND_FOLIAGE_MM = 12.0
BRANCH_RADIUS_MM = 5.0  # the 10 mm wooden rod of SPEC 2

FOLIAGE_KINDS = ("none", "soft", "stiff", "sparse", "dense")
PAPER_KINDS = ("soft", "stiff")
NATURAL_KINDS = ("sparse", "dense")

MAX_VERTICAL_RATIO = 0.2

STRIP_WIDTH_MM = 12.0
STRIP_GAP_MM = 2.0
STRIP_JITTER_MM = 1.0  # keeps neighbours apart even at full yaw
STRIP_MAX_YAW_DEG = 25.0
STRIP_CLAMP_HEIGHT_MM = 35.0  # h: the sheet is cut into strips below y = -h
STRIP_BOTTOM_Y_MM = 250.0
SHEET_TOP_Y_MM = -250.0  # the rail the sheet hangs from
STRIP_LAYER_DEPTH_MM = 6.0  # whole strips lie in [z_front, z_front + this], in front of branches
STRIP_HALF_SPAN_MM = 650.0

NATURAL_DEPTH_MM = 80.0  # twigs and leaves spread from z_front to about z_front + this
NATURAL_HALF_SPAN_X_MM = 650.0
NATURAL_HALF_SPAN_Y_MM = 450.0
NATURAL_TRIANGLE_BUDGET = 30_000  # at the default detail level
TWIG_LENGTH_MM = (150.0, 280.0)
TWIG_MAX_PITCH_RAD = 0.2  # twigs lie roughly parallel to the foliage front
TWIG_MIN_LEVER_MM = 80.0
LEAF_LOADED_WIDTH_MM = 45.0
LEAF_MIN_LEVER_MM = 25.0
LEAF_DEPTH_SHARE = 0.3  # damps the depth component of petioles and blades
LEAF_FACING = 1.5  # biases leaf faces towards the camera, out of the foliage


def _check_name(field_name: str, value: str, allowed: tuple[str, ...]) -> None:
    if value not in allowed:
        raise ValueError(f"{field_name}: unknown {value!r}; choose from {', '.join(allowed)}")


@dataclass(frozen=True)
class VegetationSpec:
    """What to build: foliage kind, sampling distance, branch positions x (mm), seed."""

    foliage: str
    distance: str
    branches_mm: tuple[float, ...] = ()
    seed: int = 0

    def __post_init__(self) -> None:
        _check_name("foliage", self.foliage, FOLIAGE_KINDS)
        _check_name("distance", self.distance, tuple(SAMPLING_PENETRATION_MM))
        branches = tuple(float(x) for x in self.branches_mm)
        if not all(math.isfinite(x) for x in branches):
            raise ValueError(f"branches_mm: positions must be finite, got {branches}")
        object.__setattr__(self, "branches_mm", branches)


@dataclass(frozen=True)
class VegetationPart:
    """One renderable material: all meshes of one kind merged, in the vegetation frame."""

    name: str
    mesh: trimesh.Trimesh
    albedo_rgb: RGB


@dataclass(frozen=True)
class Vegetation:
    """The built scene: obstacles for the mechanics and parts for the renderer, whose
    tessellation is ``detail`` (:mod:`scenes.foliage_meshes`; it never changes the obstacles)."""

    spec: VegetationSpec
    z_front_mm: float
    branches: tuple[RigidCylinder, ...]
    contacts: tuple[CompliantContact, ...]
    parts: tuple[VegetationPart, ...]
    detail: FoliageDetail


# -- geometry of the sampling position ------------------------------------------------------


def foliage_front_mm(distance: str, array: ArraySpec) -> float:
    """z of the foliage front for a sampling distance (ValueError for an unknown one)."""
    _check_name("distance", distance, tuple(SAMPLING_PENETRATION_MM))
    return array.frame_radius_mm + array.whisker_length_mm - SAMPLING_PENETRATION_MM[distance]


def branch_z_mm(distance: str, array: ArraySpec) -> float:
    """z of the branch centres at a sampling distance."""
    return foliage_front_mm(distance, array) + BRANCH_BEHIND_FOLIAGE_MM


def reach_z_mm(array: ArraySpec) -> float:
    """The deepest z any whisker reaches: its tip on the optical axis."""
    return array.frame_radius_mm + array.whisker_length_mm


# -- mechanics of foliage -------------------------------------------------------------------


def plate_EI_Nmm2(modulus_MPa: float, thickness_mm: float, width_mm: float) -> float:
    """Bending stiffness of a thin strip about its weak axis: D * w with D = E t^3 / 12."""
    return modulus_MPa * thickness_mm**3 / 12.0 * width_mm


def rod_EI_Nmm2(modulus_MPa: float, diameter_mm: float) -> float:
    """Bending stiffness of a round rod: E pi d^4 / 64."""
    return modulus_MPa * math.pi * diameter_mm**4 / 64.0


def cantilever_contact(
    x_mm: float,
    z_mm: float,
    EI_Nmm2: float,
    lever_mm: float,
    friction: float,
    vertical_ratio: float,
) -> CompliantContact:
    """A cantilever loaded at ``lever_mm`` from its clamp that slips past the rod at the slip
    angle atan(friction) (module docstring): k = 3 EI / h^3, F_max = 2 EI mu / h^2,
    give_way = F_max / k."""
    stiffness = 3.0 * EI_Nmm2 / lever_mm**3
    force_limit = 2.0 * EI_Nmm2 * friction / lever_mm**2
    return CompliantContact(
        x_mm=float(x_mm),
        z_mm=float(z_mm),
        stiffness_N_per_mm=stiffness,
        force_limit_N=force_limit,
        give_way_mm=force_limit / stiffness,
        vertical_ratio=float(vertical_ratio),
    )


def _vertical_ratios(rng: np.random.Generator, n: int) -> np.ndarray:
    return rng.uniform(-MAX_VERTICAL_RATIO, MAX_VERTICAL_RATIO, n)


# -- paper strips ---------------------------------------------------------------------------


def _strips(
    rng: np.random.Generator, kind: str, z_front: float
) -> tuple[list[CompliantContact], trimesh.Trimesh]:
    """A curtain of yawed strips hanging from an uncut sheet; one contact per strip at y = 0."""
    import trimesh

    t = PAPER_THICKNESS_MM[kind]
    pitch = STRIP_WIDTH_MM + STRIP_GAP_MM
    n_half = int(STRIP_HALF_SPAN_MM // pitch) + 1
    x = np.arange(-n_half, n_half + 1) * pitch
    n = x.size
    x = x + rng.uniform(-STRIP_JITTER_MM, STRIP_JITTER_MM, n)
    yaw = np.radians(rng.uniform(-STRIP_MAX_YAW_DEG, STRIP_MAX_YAW_DEG, n))
    half_depth = 0.5 * (STRIP_WIDTH_MM * np.abs(np.sin(yaw)) + t * np.cos(yaw))
    z = z_front + half_depth + rng.uniform(0, 1, n) * (STRIP_LAYER_DEPTH_MM - 2 * half_depth)
    vertical = _vertical_ratios(rng, n)
    EI = plate_EI_Nmm2(PAPER_MODULUS_MPA, t, STRIP_WIDTH_MM)
    contacts = [
        cantilever_contact(xi, zi, EI, STRIP_CLAMP_HEIGHT_MM, PAPER_SLIP_FRICTION, vi)
        for xi, zi, vi in zip(x, z, vertical, strict=True)
    ]
    length = STRIP_BOTTOM_Y_MM + STRIP_CLAMP_HEIGHT_MM
    y_mid = 0.5 * (STRIP_BOTTOM_Y_MM - STRIP_CLAMP_HEIGHT_MM)
    boxes = [
        trimesh.creation.box((STRIP_WIDTH_MM, length, t), make_T(rot_y(a), [xi, y_mid, zi]))
        for xi, zi, a in zip(x, z, yaw, strict=True)
    ]
    sheet_height = -STRIP_CLAMP_HEIGHT_MM - SHEET_TOP_Y_MM
    sheet_centre = [0.5 * (x[0] + x[-1]), SHEET_TOP_Y_MM + 0.5 * sheet_height, z_front + 0.5 * t]
    width = x[-1] - x[0] + STRIP_WIDTH_MM
    boxes.append(trimesh.creation.box((width, sheet_height, t), make_T(np.eye(3), sheet_centre)))
    return contacts, trimesh.util.concatenate(boxes)


# -- natural foliage ------------------------------------------------------------------------


def _unit_rows(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _perpendicular(rng: np.random.Generator, axis: np.ndarray) -> np.ndarray:
    """Random unit vectors perpendicular to the rows of ``axis`` (unit rows)."""
    g = rng.normal(size=axis.shape)
    return _unit_rows(g - np.sum(g * axis, axis=-1, keepdims=True) * axis)


def _twigs(
    rng: np.random.Generator, kind: NaturalKind, z_front: float
) -> tuple[np.ndarray, np.ndarray]:
    """(base, tip) points of the twigs, (n, 3) each, wholly inside the foliage slab."""
    n = kind.twigs
    length = rng.uniform(*TWIG_LENGTH_MM, n)
    heading = rng.uniform(0, 2 * math.pi, n)
    pitch = rng.uniform(-TWIG_MAX_PITCH_RAD, TWIG_MAX_PITCH_RAD, n)
    direction = np.stack(
        [np.cos(heading) * np.cos(pitch), np.sin(heading) * np.cos(pitch), np.sin(pitch)], axis=-1
    )
    dz = length * direction[:, 2]
    r = 0.5 * kind.twig_diameter_mm
    z_lo = z_front + r - np.minimum(dz, 0)
    z_hi = z_front + NATURAL_DEPTH_MM - r - np.maximum(dz, 0)
    base = np.stack(
        [
            rng.uniform(-NATURAL_HALF_SPAN_X_MM, NATURAL_HALF_SPAN_X_MM, n),
            rng.uniform(-NATURAL_HALF_SPAN_Y_MM, NATURAL_HALF_SPAN_Y_MM, n),
            z_lo + rng.uniform(0, 1, n) * (z_hi - z_lo),
        ],
        axis=-1,
    )
    return base, base + length[:, None] * direction


def _leaves(
    rng: np.random.Generator, kind: NaturalKind, base: np.ndarray, tip: np.ndarray, z_front: float
) -> Callable[[int], np.ndarray]:
    """Elliptic leaves on the twigs, as their outlines sampled at k points: (m, k, 3), point 0 at
    the blade's base. Leaves whose ``CONTACT_RIM_POINTS`` outline would poke in front of the
    foliage front are moved back by the same amount at every k."""
    twig = np.repeat(np.arange(len(base)), kind.leaves_per_twig)
    m = twig.size
    along = rng.uniform(0.15, 1.0, m)[:, None]
    attach = base[twig] + along * (tip[twig] - base[twig])
    flatten = np.array([1.0, 1.0, LEAF_DEPTH_SHARE])  # leaves spread along the foliage front
    petiole = _unit_rows(_perpendicular(rng, _unit_rows(tip[twig] - base[twig])) * flatten)
    blade_base = attach + kind.petiole_mm * petiole
    droop = rng.uniform(0.0, 1.0, m)[:, None] * np.array([0.0, 1.0, 0.0])  # leaves hang (+y)
    axis = _unit_rows((petiole + droop) * flatten)
    facing = _unit_rows(rng.normal(size=(m, 3)) + [0.0, 0.0, -LEAF_FACING])  # towards the light
    normal = _unit_rows(facing - np.sum(facing * axis, axis=-1, keepdims=True) * axis)
    side = np.cross(normal, axis)
    length = rng.uniform(*kind.leaf_length_mm, m)[:, None, None]
    width = length * rng.uniform(*kind.leaf_aspect, m)[:, None, None]
    rim = leaf_rims(blade_base, axis, side, length, width, CONTACT_RIM_POINTS)
    shift = np.maximum(z_front - rim[..., 2].min(axis=1), 0.0)

    def outlines(k: int) -> np.ndarray:
        rim = leaf_rims(blade_base, axis, side, length, width, k)
        rim[..., 2] += shift[:, None]
        return rim

    return outlines


def _plane_crossing(polygon: np.ndarray) -> np.ndarray | None:
    """Midpoint of the chord where a convex planar polygon (k, 3) crosses y = 0, or None."""
    nxt = np.roll(polygon, -1, axis=0)
    below = polygon[:, 1] > 0
    edges = np.flatnonzero(below != np.roll(below, -1))
    if edges.size == 0:
        return None
    a, b = polygon[edges], nxt[edges]
    s = a[:, 1] / (a[:, 1] - b[:, 1])
    return (a + s[:, None] * (b - a)).mean(axis=0)


def _natural(
    rng: np.random.Generator, name: str, z_front: float, reach_z: float, detail: FoliageDetail
) -> tuple[list[CompliantContact], list[VegetationPart]]:
    """Twigs carrying leaves; contacts where they cross y = 0 no deeper than ``reach_z``."""
    kind = NATURAL[name]
    base, tip = _twigs(rng, kind, z_front)
    outlines = _leaves(rng, kind, base, tip, z_front)
    rim = outlines(CONTACT_RIM_POINTS)
    twig_EI = rod_EI_Nmm2(TWIG_MODULUS_MPA, kind.twig_diameter_mm)
    leaf_EI = plate_EI_Nmm2(LEAF_MODULUS_MPA, kind.leaf_thickness_mm, LEAF_LOADED_WIDTH_MM)
    contacts = []
    for b, e, v in zip(base, tip, _vertical_ratios(rng, len(base)), strict=True):
        if b[1] * e[1] < 0:
            s = b[1] / (b[1] - e[1])
            c = b + s * (e - b)
            if c[2] <= reach_z:
                lever = max(s * np.linalg.norm(e - b), TWIG_MIN_LEVER_MM)
                contacts.append(
                    cantilever_contact(c[0], c[2], twig_EI, lever, TWIG_SLIP_FRICTION, v)
                )
    for polygon, v in zip(rim, _vertical_ratios(rng, len(rim)), strict=True):
        c = _plane_crossing(polygon)
        if c is not None and c[2] <= reach_z:
            lever = max(float(np.linalg.norm(c - polygon[0])), LEAF_MIN_LEVER_MM)
            contacts.append(cantilever_contact(c[0], c[2], leaf_EI, lever, LEAF_SLIP_FRICTION, v))
    twigs = twig_mesh(base, tip, kind.twig_diameter_mm, detail.twig_sections)
    parts = [
        VegetationPart("twigs", twigs, TWIG_ALBEDO),
        VegetationPart("leaves", leaf_mesh(outlines(detail.leaf_rim_points)), kind.leaf_albedo),
    ]
    return contacts, parts


def build_vegetation(
    spec: VegetationSpec, array: ArraySpec, detail: str | FoliageDetail = "default"
) -> Vegetation:
    """The scene of ``spec``: a pure function of it (the seed drives one numpy Generator).

    ``detail`` (a name in :data:`scenes.foliage_meshes.DETAIL_LEVELS` or a
    :class:`FoliageDetail`) sets only the meshes' tessellation; contacts and branches are the
    same at every level, and the foliage is the same with and without branches.
    """
    tessellation = get_detail(detail)
    rng = np.random.default_rng(spec.seed)
    z_front = foliage_front_mm(spec.distance, array)
    z_branch = z_front + BRANCH_BEHIND_FOLIAGE_MM
    branches = tuple(RigidCylinder(x, z_branch, BRANCH_RADIUS_MM) for x in spec.branches_mm)
    contacts: list[CompliantContact] = []
    parts: list[VegetationPart] = []
    if spec.foliage in PAPER_KINDS:
        contacts, strips = _strips(rng, spec.foliage, z_front)
        parts.append(VegetationPart("strips", strips, PAPER_ALBEDO))
    elif spec.foliage in NATURAL_KINDS:
        contacts, parts = _natural(rng, spec.foliage, z_front, reach_z_mm(array), tessellation)
    if branches:
        rods = branch_mesh(branches, tessellation.branch_sections)
        parts.append(VegetationPart("branches", rods, BRANCH_ALBEDO))
    return Vegetation(
        spec=spec,
        z_front_mm=z_front,
        branches=branches,
        contacts=tuple(sorted(contacts, key=lambda c: c.x_mm)),
        parts=tuple(parts),
        detail=tessellation,
    )
