"""The whisker array (SPEC section 1): geometry, frames and meshes, built from parameters.

Frames (all in mm, poses as ``T_a_b`` of :mod:`scenes.conventions`):

``cam``
    The camera frame. The camera sits at the centre of the arc; the array lies in the camera's
    horizontal plane (y = 0). Whisker ``i`` (0 = leftmost in the image) points outwards along
    heading ``psi_i = -arc/2 + i * arc/(n - 1)``: direction ``u_i = (sin psi_i, 0, cos psi_i)``.
``whisker`` (one per whisker, at rest)
    Origin at the coupling (the torsional spring), ``frame_radius_mm`` from the camera along
    ``u_i``. Axes as the marker's: +z towards the camera (``-u_i``), +y up (``-y_cam``),
    +x = y x z, which is the whisking direction (+x_cam for the centre whisker).
``marker`` (one per whisker)
    The marker frame of :mod:`scenes.conventions` (the printed face's centre, +z out of the face):
    ``marker_offset_mm`` in front of the coupling along the whisker frame's +z, rigid with the rod.

Deflection is a rotation of the rod, holder and marker about the coupling by two angles:
``theta_h`` moves the tip towards the whisker frame's +x, ``theta_v`` moves it up (+y). The
rotation is ``R = R_y(-theta_h) @ R_x(theta_v)``; the marker, behind the pivot, moves the other
way by ``marker_offset_mm * sin(theta)`` (SPEC 1).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from scenes.conventions import make_T
from scenes.marker import MarkerSpec, carrier_mesh, print_mesh
from scenes.rod_materials import COUPLING_LOSS_FACTOR, ROD_DENSITY_KG_M3, ROD_MODULUS_MPA
from scenes.validation import FieldError

if TYPE_CHECKING:
    import trimesh

FRAME_PLATE_HEIGHT_MM = 24.0  # the arc plate that carries the couplings, seen behind the markers
FRAME_PLATE_THICKNESS_MM = 4.0
FRAME_PLATE_MARGIN_DEG = 4.0  # plate extends this far past the outer whiskers


class ArraySpecError(FieldError):
    """An invalid array parameter; ``field`` names it."""


@dataclass(frozen=True)
class ArraySpec:
    """The sensor's design parameters (SPEC 1 values by default)."""

    n_whiskers: int = 13
    arc_deg: float = 90.0
    frame_radius_mm: float = 210.0
    whisker_length_mm: float = 140.0
    whisker_diameter_mm: float = 1.5
    spring_Nmm_per_rad: float = 5.7
    marker_offset_mm: float = 8.0
    marker_size_mm: float = 13.2
    dictionary: str = "DICT_4X4_50"
    marker_ids: tuple[int, ...] = field(default_factory=lambda: tuple(range(13)))
    #: Young's modulus of the rod (its bending in series with the coupling); None = rigid rod.
    rod_modulus_MPa: float | None = ROD_MODULUS_MPA
    rod_density_kg_m3: float = ROD_DENSITY_KG_M3  # the whisker's inertia (scenes.dynamics)
    coupling_loss_factor: float = COUPLING_LOSS_FACTOR  # the coupling's damping (scenes.dynamics)

    def __post_init__(self) -> None:
        positive = (
            "frame_radius_mm",
            "whisker_length_mm",
            "whisker_diameter_mm",
            "spring_Nmm_per_rad",
            "marker_offset_mm",
            "marker_size_mm",
            "rod_density_kg_m3",
        )
        for name in positive:
            if not getattr(self, name) > 0:
                raise ArraySpecError(name, f"must be > 0, got {getattr(self, name)}")
        if self.n_whiskers < 2:
            raise ArraySpecError("n_whiskers", f"must be >= 2, got {self.n_whiskers}")
        if not 0 < self.arc_deg < 180:
            raise ArraySpecError("arc_deg", f"must be in (0, 180), got {self.arc_deg}")
        if len(self.marker_ids) != self.n_whiskers or len(set(self.marker_ids)) != self.n_whiskers:
            raise ArraySpecError("marker_ids", f"need {self.n_whiskers} distinct ids")
        if self.marker_offset_mm >= self.frame_radius_mm:
            raise ArraySpecError("marker_offset_mm", "must be smaller than frame_radius_mm")
        if self.rod_modulus_MPa is not None and not self.rod_modulus_MPa > 0:
            raise ArraySpecError("rod_modulus_MPa", "must be > 0 or None")
        if not 0 <= self.coupling_loss_factor < 2:
            raise ArraySpecError(
                "coupling_loss_factor",
                f"must be in [0, 2) (damping ratio eta / 2 below 1), "
                f"got {self.coupling_loss_factor}",
            )
        for i in self.marker_ids:
            self.marker_spec(i)  # validates dictionary and id range

    def marker_spec(self, marker_id: int) -> MarkerSpec:
        return MarkerSpec(self.dictionary, int(marker_id), self.marker_size_mm)

    @property
    def headings_rad(self) -> np.ndarray:
        """(n,) whisker headings psi, left to right in the image."""
        half = math.radians(self.arc_deg) / 2
        return np.linspace(-half, half, self.n_whiskers)

    @property
    def spacing_rad(self) -> float:
        return math.radians(self.arc_deg) / (self.n_whiskers - 1)

    @property
    def rod_bending_EI_Nmm2(self) -> float | None:
        """Bending stiffness E*I of the round rod (N mm^2), None for a rigid rod."""
        if self.rod_modulus_MPa is None:
            return None
        return self.rod_modulus_MPa * math.pi * self.whisker_diameter_mm**4 / 64

    def whisker_index(self, marker_id: int) -> int:
        """The whisker that carries ``marker_id`` (ValueError if none does)."""
        try:
            return self.marker_ids.index(int(marker_id))
        except ValueError:
            raise ValueError(f"marker id {marker_id} is not on this array") from None

    def to_json(self) -> dict:
        out = {k: getattr(self, k) for k in self.__dataclass_fields__}
        out["marker_ids"] = list(self.marker_ids)
        return out


def outward_cam(spec: ArraySpec) -> np.ndarray:
    """(n, 3) unit whisker directions u_i in the camera frame."""
    psi = spec.headings_rad
    return np.stack([np.sin(psi), np.zeros_like(psi), np.cos(psi)], axis=-1)


def T_cam_whisker(spec: ArraySpec) -> np.ndarray:
    """(n, 4, 4) rest poses of the whisker frames (origin at the coupling)."""
    u = outward_cam(spec)
    z = -u
    y = np.broadcast_to([0.0, -1.0, 0.0], z.shape)
    x = np.cross(y, z)
    T = np.tile(np.eye(4), (spec.n_whiskers, 1, 1))
    T[:, :3, 0], T[:, :3, 1], T[:, :3, 2] = x, y, z
    T[:, :3, 3] = spec.frame_radius_mm * u
    return T


def deflection_rotation(angles_rad: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotation R_y(-theta_h) @ R_x(theta_v) for (..., 2) angles (theta_h, theta_v)."""
    angles_rad = np.asarray(angles_rad, dtype=float)
    h, v = angles_rad[..., 0], angles_rad[..., 1]
    ch, sh, cv, sv = np.cos(h), np.sin(h), np.cos(v), np.sin(v)
    zero, one = np.zeros_like(h), np.ones_like(h)
    Ry = np.stack([ch, zero, -sh, zero, one, zero, sh, zero, ch], axis=-1)
    Rx = np.stack([one, zero, zero, zero, cv, -sv, zero, sv, cv], axis=-1)
    shape = h.shape + (3, 3)
    return Ry.reshape(shape) @ Rx.reshape(shape)


def T_whisker_marker(spec: ArraySpec, angles_rad: np.ndarray) -> np.ndarray:
    """(..., 4, 4) marker pose in its rest whisker frame for deflection angles (..., 2)."""
    R = deflection_rotation(angles_rad)
    T = np.zeros(R.shape[:-2] + (4, 4))
    T[..., :3, :3] = R
    T[..., :3, 3] = R @ np.array([0.0, 0.0, spec.marker_offset_mm])
    T[..., 3, 3] = 1.0
    return T


def T_cam_marker(spec: ArraySpec, angles_rad: np.ndarray) -> np.ndarray:
    """(..., n, 4, 4) marker poses in the camera frame for angles (..., n, 2)."""
    return T_cam_whisker(spec) @ T_whisker_marker(spec, angles_rad)


def T_marker0_marker(spec: ArraySpec, angles_rad: np.ndarray) -> np.ndarray:
    """(..., 4, 4) deflected marker pose in its own no-contact frame (the seed paper's T_M0M;
    notation in scenes.conventions)."""
    rest = T_whisker_marker(spec, np.zeros(2))
    rest_inv = make_T(rest[:3, :3].T, -rest[:3, :3].T @ rest[:3, 3])
    return rest_inv @ T_whisker_marker(spec, angles_rad)


def tip_cam(spec: ArraySpec, angles_rad: np.ndarray) -> np.ndarray:
    """(..., n, 3) whisker tip positions in the camera frame for angles (..., n, 2)."""
    R = deflection_rotation(angles_rad)
    tip_w = R @ np.array([0.0, 0.0, -spec.whisker_length_mm])
    T = T_cam_whisker(spec)
    return np.einsum("nij,...nj->...ni", T[:, :3, :3], tip_w) + T[:, :3, 3]


# -- meshes ----------------------------------------------------------------------------------


def rod_mesh(spec: ArraySpec, sections: int = 8) -> trimesh.Trimesh:
    """The whisker rod in its whisker frame: from the coupling out along -z."""
    import trimesh

    rod = trimesh.creation.cylinder(
        radius=spec.whisker_diameter_mm / 2, height=spec.whisker_length_mm, sections=sections
    )
    rod.apply_translation([0.0, 0.0, -spec.whisker_length_mm / 2])
    return rod


def marker_meshes(spec: ArraySpec, marker_id: int) -> tuple[trimesh.Trimesh, trimesh.Trimesh]:
    """(print, carrier-and-holder) of one marker in its marker frame."""
    import trimesh

    marker = spec.marker_spec(marker_id)
    holder_len = spec.marker_offset_mm
    holder = trimesh.creation.box((2.0, 2.0, holder_len))
    holder.apply_translation([0.0, 0.0, -holder_len / 2])
    return print_mesh(marker), trimesh.util.concatenate([carrier_mesh(marker), holder])


def frame_plate_mesh(spec: ArraySpec, segments: int = 96) -> trimesh.Trimesh:
    """The arc plate carrying the couplings, in the camera frame (static with the camera)."""
    import trimesh

    half = math.radians(spec.arc_deg / 2 + FRAME_PLATE_MARGIN_DEG)
    a = np.linspace(-half, half, segments)
    r0 = spec.frame_radius_mm + 1.0
    r1 = r0 + FRAME_PLATE_THICKNESS_MM
    h = FRAME_PLATE_HEIGHT_MM / 2
    ring = []
    for r in (r0, r1):
        for y in (-h, h):
            ring.append(np.stack([r * np.sin(a), np.full_like(a, y), r * np.cos(a)], axis=-1))
    verts = np.concatenate(ring)  # 4 rails of `segments` vertices: (r0,-h), (r0,h), (r1,-h), (r1,h)
    faces, wanted = [], []
    # (rail a, rail b, outward normal as (radial, y) weights): inner face, bottom, outer, top
    sides = [(0, 1, (-1.0, 0.0)), (1, 3, (0.0, 1.0)), (3, 2, (1.0, 0.0)), (2, 0, (0.0, -1.0))]
    radial = np.stack([np.sin(a), np.zeros_like(a), np.cos(a)], axis=-1)
    for ra, rb, (wr, wy) in sides:
        for k in range(segments - 1):
            a0, a1 = ra * segments + k, ra * segments + k + 1
            b0, b1 = rb * segments + k, rb * segments + k + 1
            faces += [[a0, b0, a1], [a1, b0, b1]]
            wanted += [wr * radial[k] + [0.0, wy, 0.0]] * 2
    faces = np.asarray(faces)
    tri = verts[faces]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    flip = np.einsum("ij,ij->i", normal, np.asarray(wanted)) < 0
    faces[flip] = faces[flip][:, ::-1]
    return trimesh.Trimesh(verts, faces, process=False)
