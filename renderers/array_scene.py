"""The whisker array and the vegetation as loaded Mitsuba scenes, for :mod:`renderers.frames`.

The array is traced in the camera frame and re-posed per time sample by rewriting three small
vertex buffers; the vegetation is one static scene in its own frame (the array's offset moves
the ray origins instead, :class:`renderers.frames.FrameRenderer`).
"""

from __future__ import annotations

from collections.abc import Sequence

import mitsuba as mi
import numpy as np
import trimesh

from renderers.mitsuba_scene import diffuse_bsdf, mesh_to_mitsuba
from scenes.array import (
    ArraySpec,
    T_cam_marker,
    T_cam_whisker,
    deflection_rotation,
    frame_plate_mesh,
    marker_meshes,
    rod_mesh,
)
from scenes.marker import marker_albedo
from scenes.materials import CARRIER_ALBEDO, PLATE_ALBEDO, ROD_ALBEDO


class ArrayScene:
    """Markers (one atlas-textured mesh), carriers with holders, rods and the arc plate.

    Re-posing rewrites three small vertex buffers; the loaded scene and its kernels stay.
    """

    def __init__(self, spec: ArraySpec) -> None:
        self.spec = spec
        n = spec.n_whiskers
        prints, carriers = zip(*(marker_meshes(spec, i) for i in spec.marker_ids), strict=True)
        self._print_local = np.stack([np.asarray(m.vertices) for m in prints])
        self._carrier_local = np.stack([np.asarray(m.vertices) for m in carriers])
        self._rod_local = np.asarray(rod_mesh(spec).vertices)
        self._T_cam_whisker = T_cam_whisker(spec)
        atlas = np.concatenate([marker_albedo(spec.marker_spec(i)) for i in spec.marker_ids], 1)
        uv = np.asarray(prints[0].visual.uv, dtype=float)
        print_all = _stack_meshes(prints)
        print_all.visual = trimesh.visual.TextureVisuals(
            uv=np.concatenate([(uv + [i, 0.0]) / [n, 1.0] for i in range(n)])
        )
        #: name -> (mesh at rest, albedo: an RGB triple or a texture), the parts as plain data
        self.parts = {
            "prints": (print_all, atlas),
            "carriers": (_stack_meshes(carriers), (CARRIER_ALBEDO,) * 3),
            "rods": (_stack_meshes([rod_mesh(spec)] * n), (ROD_ALBEDO,) * 3),
            "plate": (frame_plate_mesh(spec), (PLATE_ALBEDO,) * 3),
        }
        self.scene = mi.load_dict(
            {
                "type": "scene",
                **{
                    name: mesh_to_mitsuba(name, mesh, diffuse_bsdf(albedo))
                    for name, (mesh, albedo) in self.parts.items()
                },
            },
            optimize=False,
        )
        self._params = mi.traverse(self.scene)
        self._posed: np.ndarray | None = None  # the angles the scene holds (None: at rest)

    def posed_vertices(self, angles_rad: np.ndarray) -> dict[str, np.ndarray]:
        """The moving parts' vertices (V, 3) in the camera frame for deflections (n, 2)."""
        markers = T_cam_marker(self.spec, angles_rad)
        rods = self._T_cam_whisker.copy()  # rods turn about their couplings, which stay put
        rods[:, :3, :3] = rods[:, :3, :3] @ deflection_rotation(angles_rad)
        rod_local = np.broadcast_to(self._rod_local, (len(rods),) + self._rod_local.shape)
        return {
            key: (np.einsum("nij,nvj->nvi", T[:, :3, :3], local) + T[:, None, :3, 3]).reshape(-1, 3)
            for key, T, local in (
                ("prints", markers, self._print_local),
                ("carriers", markers, self._carrier_local),
                ("rods", rods, rod_local),
            )
        }

    def set_angles(self, angles_rad: np.ndarray) -> None:
        """Pose every whisker for deflection angles (n, 2) (scenes.array convention); the
        same angles again leave the scene (and its acceleration structure) as it is."""
        angles_rad = np.array(angles_rad, dtype=float)
        if self._posed is not None and np.array_equal(angles_rad, self._posed):
            return
        self._posed = angles_rad
        for key, posed in self.posed_vertices(angles_rad).items():
            key = f"{key}.vertex_positions"
            self._params[key] = type(self._params[key])(posed.astype(np.float32).ravel())
        self._params.update()


def _stack_meshes(meshes: Sequence[trimesh.Trimesh]) -> trimesh.Trimesh:
    """Concatenate meshes keeping vertex order (trimesh.util.concatenate may drop the uv)."""
    vertices, faces, base = [], [], 0
    for m in meshes:
        vertices.append(np.asarray(m.vertices))
        faces.append(np.asarray(m.faces) + base)
        base += len(m.vertices)
    return trimesh.Trimesh(np.concatenate(vertices), np.concatenate(faces), process=False)


def vegetation_scene(parts: Sequence[tuple[str, trimesh.Trimesh, tuple[float, float, float]]]):
    """The vegetation (name, mesh in the vegetation frame, RGB albedo) as one static scene."""
    shapes = {
        name: mesh_to_mitsuba(name, mesh, diffuse_bsdf(tuple(albedo)))
        for name, mesh, albedo in parts
        if len(mesh.faces)
    }
    return mi.load_dict({"type": "scene", **shapes}, optimize=False)
