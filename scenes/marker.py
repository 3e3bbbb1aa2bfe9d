"""ArUco markers as plain data: dictionary, id, size, texture and the meshes that carry them.

The printed marker is the ArUco pattern (black border included; ``size_mm`` is the side of that
black square) surrounded by a white quiet zone of one module, printed on a thin white carrier
that extends one more module beyond the quiet zone. Meshes are built in the marker frame of
:mod:`scenes.conventions` (printed face at z = 0, facing +z).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache
from typing import TYPE_CHECKING

import cv2
import numpy as np

from scenes.conventions import transform_points
from scenes.materials import BLACK_ALBEDO, WHITE_ALBEDO

if TYPE_CHECKING:
    import trimesh

QUIET_ZONE_MODULES = 1
CARRIER_MARGIN_MODULES = 1
CARRIER_THICKNESS_MM = 1.0
PRINT_GAP_MM = (
    0.01  # the carrier's front face sits this far behind the print, so they never coincide
)


def dictionary_names() -> list[str]:
    """Accepted dictionary names: OpenCV's ``DICT_*`` constants, lower case, without the prefix."""
    return sorted({n[5:].lower() for n in dir(cv2.aruco) if n.startswith("DICT_")})  # 16h5, 16H5


def check_dictionary(name: str) -> str:
    """Return the canonical name of an ArUco dictionary, or raise ValueError listing the options."""
    canonical = str(name).lower().removeprefix("dict_")
    if canonical not in dictionary_names():
        raise ValueError(
            f"dictionary={name!r}: unknown; choose one of {', '.join(dictionary_names())}"
        )
    return canonical


@cache
def get_dictionary(name: str) -> cv2.aruco.Dictionary:
    """The OpenCV dictionary object for a name accepted by :func:`check_dictionary`."""
    return cv2.aruco.getPredefinedDictionary(
        getattr(cv2.aruco, "DICT_" + check_dictionary(name).upper())
    )


@dataclass(frozen=True)
class MarkerSpec:
    """Which marker: dictionary, id and printed size (side of the black square, mm)."""

    dictionary: str = "4x4_50"
    marker_id: int = 0
    size_mm: float = 13.2

    def __post_init__(self) -> None:
        object.__setattr__(self, "dictionary", check_dictionary(self.dictionary))
        if not (np.isfinite(self.size_mm) and self.size_mm > 0):
            raise ValueError(f"size_mm={self.size_mm!r}: must be a positive number of millimetres")
        n_ids = get_dictionary(self.dictionary).bytesList.shape[0]
        if not 0 <= int(self.marker_id) < n_ids:
            raise ValueError(
                f"marker_id={self.marker_id!r}: dictionary {self.dictionary} has ids 0..{n_ids - 1}"
            )

    @property
    def modules(self) -> int:
        """Modules across the black square: the code bits plus a one-module black border."""
        return int(get_dictionary(self.dictionary).markerSize) + 2

    @property
    def module_mm(self) -> float:
        return self.size_mm / self.modules

    @property
    def print_half_mm(self) -> float:
        """Half side of the printed area: marker plus quiet zone."""
        return 0.5 * self.size_mm + QUIET_ZONE_MODULES * self.module_mm

    @property
    def carrier_half_mm(self) -> float:
        return self.print_half_mm + CARRIER_MARGIN_MODULES * self.module_mm


def marker_albedo(spec: MarkerSpec) -> np.ndarray:
    """Albedo of the printed area, one texel per module, rows top (+y) to bottom.

    (modules + 2 * quiet zone)^2 float32: the ArUco code with its black border inside a white
    quiet zone. Use nearest filtering: one texel per module keeps the edges hard.
    """
    bits = get_dictionary(spec.dictionary).generateImageMarker(
        spec.marker_id, spec.modules, borderBits=1
    )
    padded = np.pad(bits, QUIET_ZONE_MODULES, constant_values=255)
    return np.where(padded > 127, WHITE_ALBEDO, BLACK_ALBEDO).astype(np.float32)


def print_mesh(spec: MarkerSpec) -> trimesh.Trimesh:
    """The printed face: a square at z = 0 facing +z, with uv (0, 0) at the bottom-left corner."""
    import trimesh

    h = spec.print_half_mm
    vertices = np.array([[-h, -h, 0.0], [h, -h, 0.0], [h, h, 0.0], [-h, h, 0.0]])
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    uv = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    mesh.visual = trimesh.visual.TextureVisuals(uv=uv)
    return mesh


def carrier_mesh(spec: MarkerSpec) -> trimesh.Trimesh:
    """The white carrier plate behind the print: a thin box, front face just behind z = 0."""
    import trimesh

    h = spec.carrier_half_mm
    box = trimesh.creation.box(extents=(2 * h, 2 * h, CARRIER_THICKNESS_MM))
    box.apply_translation((0.0, 0.0, -0.5 * CARRIER_THICKNESS_MM - PRINT_GAP_MM))
    return box


def carrier_outline(T_cam_marker: np.ndarray, spec: MarkerSpec, steps: int = 9) -> np.ndarray:
    """Points along every segment between two carrier vertices, camera frame: (M, 3) mm.

    A crop frames their projections. The vertices alone are not enough: their projections are
    NaN beyond theta_max, and from alpha 90 deg the carrier's far vertices can be past 95 deg
    while part of the marker is not, so a crop framing the vertices would cut the marker.
    Points along the edges keep the visible part of the carrier framed up to the image circle.
    """
    v = transform_points(T_cam_marker, carrier_mesh(spec).vertices)
    i, j = np.triu_indices(len(v), k=1)
    t = np.linspace(0.0, 1.0, steps)[:, None, None]
    return (v[i][None] + t * (v[j] - v[i])[None]).reshape(-1, 3)
