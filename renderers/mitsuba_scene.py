"""Plain scene data (scenes/) turned into loaded Mitsuba scenes that can be re-posed cheaply.

A scene is loaded once; moving the marker rewrites its mesh vertices through ``mi.traverse``,
which keeps the compiled kernels (a new ``mi.load_dict`` per pose would recompile and leak).
"""

from __future__ import annotations

import math

import mitsuba as mi
import numpy as np
import trimesh

from scenes.conventions import transform_points
from scenes.lighting import Lighting, Sky, canopy_mesh
from scenes.marker import MarkerSpec, carrier_mesh, marker_albedo, print_mesh
from scenes.materials import CANOPY_ALBEDO, CARRIER_ALBEDO

SKY_MAP_SIZE = (64, 128)  # (rows, cols) of the lat-long sky: the sky is smooth


def sky_directions(rows: int, cols: int) -> np.ndarray:
    """(rows, cols, 3) directions of Mitsuba's lat-long envmap texel centres, identity to_world.

    Mitsuba maps a direction v to uv = (atan2(v.x, -v.z) / 2pi, acos(v.y) / pi).
    """
    v = (np.arange(rows) + 0.5) / rows
    u = (np.arange(cols) + 0.5) / cols
    theta = v[:, None] * math.pi
    phi = u[None, :] * 2 * math.pi
    return np.stack(
        np.broadcast_arrays(
            np.sin(theta) * np.sin(phi), np.cos(theta), -np.sin(theta) * np.cos(phi)
        ),
        axis=-1,
    )


def sky_bitmap(sky: Sky) -> np.ndarray:
    """(rows, cols, 3) float32 lat-long radiance of the sky, camera frame = Mitsuba world frame."""
    dirs = sky_directions(*SKY_MAP_SIZE)
    lum = sky.radiance(dirs.reshape(-1, 3)).reshape(SKY_MAP_SIZE)
    return (lum[..., None] * np.asarray(sky.color)).astype(np.float32)


def mesh_to_mitsuba(name: str, mesh: trimesh.Trimesh, bsdf: dict) -> mi.Mesh:
    """A Mitsuba mesh built from a trimesh in memory (uv kept when the trimesh has them)."""
    uv = getattr(mesh.visual, "uv", None)
    out = mi.Mesh(
        name,
        vertex_count=len(mesh.vertices),
        face_count=len(mesh.faces),
        has_vertex_normals=False,
        has_vertex_texcoords=uv is not None,
        props=mi.Properties(),
    )
    params = mi.traverse(out)
    # The buffers' own types: dynamic arrays in every variant, scalar_rgb included.
    floats, ints = type(params["vertex_positions"]), type(params["faces"])
    params["vertex_positions"] = floats(np.asarray(mesh.vertices, dtype=np.float32).ravel())
    params["faces"] = ints(np.asarray(mesh.faces, dtype=np.uint32).ravel())
    if uv is not None:
        params["vertex_texcoords"] = floats(np.asarray(uv, dtype=np.float32).ravel())
    params.update()
    out.set_bsdf(mi.load_dict(bsdf))
    return out


def diffuse_bsdf(value: float | tuple[float, float, float] | np.ndarray) -> dict:
    """A Lambertian BSDF: grey albedo, an RGB tuple, or a (rows, cols) albedo texture (row 0 top,
    sampled nearest so printed module edges stay hard)."""
    if np.isscalar(value):
        return {"type": "diffuse", "reflectance": {"type": "rgb", "value": [float(value)] * 3}}
    if isinstance(value, tuple):
        return {
            "type": "diffuse",
            "reflectance": {"type": "rgb", "value": [float(v) for v in value]},
        }
    # The bitmap's first row sits at v = 0, the bottom of the print: flip so row 0 is the top.
    texture = np.ascontiguousarray(np.flipud(value))[..., None].repeat(3, axis=-1)
    return {
        "type": "diffuse",
        "reflectance": {
            "type": "bitmap",
            "bitmap": mi.Bitmap(texture),
            "filter_type": "nearest",
            "wrap_mode": "clamp",
            "raw": True,
        },
    }


class MarkerScene:
    """A marker (print on a white carrier) under a sky; the pose changes, the scene stays loaded."""

    def __init__(self, marker: MarkerSpec, lighting: Lighting) -> None:
        self.marker = marker
        self.lighting = lighting
        self._print = print_mesh(marker)
        self._carrier = carrier_mesh(marker)
        self.scene = mi.load_dict(
            {
                "type": "scene",
                "sky": {"type": "envmap", "bitmap": mi.Bitmap(sky_bitmap(lighting.sky))},
                "print": mesh_to_mitsuba("print", self._print, diffuse_bsdf(marker_albedo(marker))),
                "carrier": mesh_to_mitsuba("carrier", self._carrier, diffuse_bsdf(CARRIER_ALBEDO)),
            },
            optimize=False,
        )
        self._params = mi.traverse(self.scene)
        self._base_size_mm = marker.size_mm

    def set_pose(self, T_cam_marker: np.ndarray, size_mm: float | None = None) -> None:
        """Place the marker (scaled to ``size_mm``, default the spec's) at ``T_cam_marker``."""
        scale = (size_mm or self._base_size_mm) / self._base_size_mm
        for key, mesh in (("print", self._print), ("carrier", self._carrier)):
            local = np.asarray(mesh.vertices) * [scale, scale, 1.0]
            posed = transform_points(T_cam_marker, local).astype(np.float32)
            key = f"{key}.vertex_positions"
            self._params[key] = type(self._params[key])(posed.ravel())
        self._params.update()


class CanopyScene:
    """The leaf layer alone, for shadow rays only: the camera never sees it."""

    def __init__(self, lighting: Lighting) -> None:
        if lighting.sun is None or lighting.canopy is None:
            raise ValueError(f"lighting {lighting.name!r} has no sun or no canopy")
        mesh = canopy_mesh(lighting.sun, lighting.canopy)
        self.scene = mi.load_dict(
            {
                "type": "scene",
                "leaves": mesh_to_mitsuba("leaves", mesh, diffuse_bsdf(CANOPY_ALBEDO)),
            },
            optimize=False,
        )
