"""Scenes rebuilt in Blender Cycles (``bpy``) from the plain data the project renders.

The same meshes, posed (the study's marker, or the whisker array and its vegetation), textures
(nearest filtered) and albedos; the sun as a sun lamp (strength = the preset's irradiance, its
colour, angle 0 like the project's delta sun); the sky as a world shader that evaluates
:meth:`scenes.lighting.Sky.radiance` per direction with math nodes (the same gradient, ground and
backlight, times the sky colour); the same lens. Direct light only (``max_bounces`` 0), a 1-pixel
box filter (uniform samples within each pixel, as the project's jitter), no denoising, no
adaptive sampling.

The lens: Blender's equidistant fisheye stretches its field of view over width and height
separately, so the camera renders a square D x D with ``fisheye_fov = D / f`` (D even, about
``2 f theta_max``: the image circle fills it) and a render border crops the frame's window out
of it; Cycles' pixel centres sit at (D - 1) / 2 in OpenCV terms and its rows count from the
bottom (``../shared/CAMERA_NOTES.md``). Blender's frame is the camera frame turned half a turn
about x (Blender cameras look down -z with +y up): (x, y, z) -> (x, -y, -z).
"""

from __future__ import annotations

import contextlib
import os
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING

import numpy as np

from renderers.window import Window
from scenes.camera import FisheyeCamera
from scenes.conventions import transform_points
from scenes.lighting import Lighting, Sky
from scenes.marker import MarkerSpec, carrier_mesh, marker_albedo, print_mesh
from scenes.materials import CARRIER_ALBEDO

if TYPE_CHECKING:
    import trimesh

#: Camera frame -> Blender frame (a proper rotation: half a turn about x).
CAM_TO_BLENDER = np.diag([1.0, -1.0, -1.0])
#: bpy 5.0.1 pins numpy<2, which opencv 5 rules out; it renders with numpy 2 (pyproject.toml).
INSTALL_HINT = "make cycles, or pip install --no-deps bpy==5.0.1"


def import_bpy() -> ModuleType | None:
    """``bpy`` or None when it is not installed.

    Its import prints a page about modules built for NumPy 1.x (bpy 5.0.1 pins numpy < 2; the
    renderer works with NumPy 2) and a note about audio: both silenced, stderr at the fd level.
    """
    with _quiet():
        try:
            import bpy
        except ImportError:
            return None
    return bpy


def square_side_px(lens: FisheyeCamera) -> int:
    """D: the even side of the square fisheye render whose image circle is about theta_max."""
    return 2 * round(lens.fx_px * lens.theta_max_rad)


def check_lens(lens: FisheyeCamera) -> None:
    """ValueError unless Cycles' equidistant fisheye can reproduce the lens pixel for pixel."""
    d = square_side_px(lens)
    offsets = (lens.cx_px - (d - 1) / 2, lens.cy_px - (d - 1) / 2)
    if lens.model != "equidistant" or lens.fx_px != lens.fy_px or any(lens.shear):
        raise ValueError(
            f"lens: Cycles is set up for a round equidistant lens, not {lens.model} with "
            f"fx={lens.fx_px}, fy={lens.fy_px}, shear={lens.shear}"
        )
    if not all(float(o).is_integer() for o in offsets):
        raise ValueError(f"lens: centre ({lens.cx_px}, {lens.cy_px}) is not on the pixel grid")


#: A scene part: name, mesh in the camera frame (uv kept), albedo (an RGB triple or a texture).
Part = tuple[str, "trimesh.Trimesh", tuple[float, float, float] | np.ndarray]


def marker_parts(marker: MarkerSpec, T_cam_marker: np.ndarray) -> list[Part]:
    """The study's marker: its print (textured) and carrier, posed."""
    parts = []
    for name, mesh, albedo in (
        ("print", print_mesh(marker), marker_albedo(marker)),
        ("carrier", carrier_mesh(marker), (CARRIER_ALBEDO,) * 3),
    ):
        posed = mesh.copy()
        posed.vertices = transform_points(T_cam_marker, np.asarray(mesh.vertices))
        parts.append((name, posed, albedo))
    return parts


class CyclesScene:
    """Lambertian meshes under one lighting preset, loaded in Blender once; renders windows."""

    def __init__(
        self,
        bpy: ModuleType,
        lens: FisheyeCamera,
        parts: Sequence[Part],
        lighting: Lighting,
        spp: int,
        threads: int,
    ) -> None:
        check_lens(lens)
        self.bpy, self.lens = bpy, lens
        self.side = square_side_px(lens)
        with _quiet():  # "Unable to initialise audio" on a machine without a sound device
            bpy.ops.wm.read_factory_settings(use_empty=True)
        scene = self.scene = bpy.context.scene
        self._settings(scene, spp, threads)
        self._camera(scene)
        self._world(scene, lighting.sky)
        if lighting.sun is not None:
            sun = bpy.data.lights.new("sun", "SUN")
            sun.energy = lighting.sun.irradiance
            sun.color = lighting.sun.color
            sun.angle = 0.0
            obj = bpy.data.objects.new("sun", sun)
            to_sun = CAM_TO_BLENDER @ np.asarray(lighting.sun.to_sun_cam)
            obj.rotation_mode = "QUATERNION"  # the lamp shines along its -z
            obj.rotation_quaternion = _vector(to_sun).to_track_quat("Z", "Y")
            scene.collection.objects.link(obj)
        for name, mesh, albedo in parts:
            texture = albedo if isinstance(albedo, tuple) else self._image(name, albedo)
            self._mesh(name, mesh, self._material(name, texture))

    def _settings(self, scene, spp: int, threads: int) -> None:
        scene.render.engine = "CYCLES"
        cycles = scene.cycles
        cycles.device = "CPU"
        cycles.samples = spp
        cycles.use_adaptive_sampling = False
        cycles.use_denoising = False
        cycles.max_bounces = 0  # direct light only
        cycles.pixel_filter_type = "BOX"
        cycles.filter_width = 1.0
        cycles.seed = 0
        scene.render.threads_mode = "FIXED"
        scene.render.threads = threads
        scene.render.use_persistent_data = True  # a second render reuses the synced scene
        scene.render.resolution_x = scene.render.resolution_y = self.side
        scene.render.resolution_percentage = 100
        scene.render.use_border = scene.render.use_crop_to_border = True
        scene.render.image_settings.file_format = "OPEN_EXR"
        scene.render.image_settings.color_depth = "32"
        scene.view_settings.view_transform = "Standard"

    def _camera(self, scene) -> None:
        cam = self.bpy.data.cameras.new("fisheye")
        cam.type = "PANO"
        cam.panorama_type = "FISHEYE_EQUIDISTANT"
        cam.fisheye_fov = self.side / self.lens.fx_px
        cam.clip_start, cam.clip_end = 1e-3, 1e6  # mm
        obj = self.bpy.data.objects.new("fisheye", cam)  # at the origin, looking down -z
        scene.collection.objects.link(obj)
        scene.camera = obj

    def _world(self, scene, sky: Sky) -> None:
        """Background = sky colour x Sky.radiance(direction), built from math nodes."""
        world = self.bpy.data.worlds.new("sky")
        scene.world = world
        nodes, links = world.node_tree.nodes, world.node_tree.links
        xyz = nodes.new("ShaderNodeSeparateXYZ")
        links.new(nodes.new("ShaderNodeTexCoord").outputs["Generated"], xyz.inputs[0])
        up, forward = xyz.outputs["Y"], xyz.outputs["Z"]  # up = dir . UP_CAM; axis = -z

        def math(op: str, a, b, c=None, clamp: bool = False):
            node = nodes.new("ShaderNodeMath")
            node.operation, node.use_clamp = op, clamp
            for socket, value in zip(node.inputs, (a, b, c), strict=True):
                if value is None:
                    continue
                if isinstance(value, float | int):
                    socket.default_value = float(value)
                else:
                    links.new(value, socket)
            return node.outputs[0]

        above = math("GREATER_THAN", up, 0.0)
        gradient = math(
            "MULTIPLY_ADD", up, sky.zenith_radiance - sky.horizon_radiance, sky.horizon_radiance
        )
        base = math(
            "MULTIPLY_ADD",
            above,
            math("SUBTRACT", gradient, sky.ground_radiance),
            sky.ground_radiance,
        )
        # clip((-z - cos_min) / 0.1, 0, 1)
        front = math("MULTIPLY_ADD", forward, -10.0, -10.0 * sky.backlight_cos_min, clamp=True)
        background = nodes["Background"]
        links.new(math("MULTIPLY_ADD", front, sky.backlight_radiance, base), background.inputs[1])
        background.inputs["Color"].default_value = (*sky.color, 1.0)

    def _image(self, name: str, albedo: np.ndarray):
        """A float image of the albedo texture (row 0 on top), raw values, nearest filtered."""
        rows, cols = albedo.shape
        image = self.bpy.data.images.new(name, cols, rows, float_buffer=True)
        image.colorspace_settings.name = "Non-Color"
        rgba = np.repeat(np.flipud(albedo)[..., None], 4, axis=-1).astype(np.float32)
        rgba[..., 3] = 1.0  # Blender's first row is the bottom one
        image.pixels.foreach_set(rgba.ravel())
        image.pack()
        return image

    def _material(self, name: str, albedo):
        """A Lambertian material: an RGB albedo or a texture (image, uv mapped)."""
        material = self.bpy.data.materials.new(name)
        nodes, links = material.node_tree.nodes, material.node_tree.links
        nodes.clear()
        diffuse = nodes.new("ShaderNodeBsdfDiffuse")
        if isinstance(albedo, tuple):
            diffuse.inputs["Color"].default_value = (*albedo, 1.0)
        else:
            texture = nodes.new("ShaderNodeTexImage")
            texture.image, texture.interpolation, texture.extension = albedo, "Closest", "EXTEND"
            links.new(texture.outputs["Color"], diffuse.inputs["Color"])
        out = nodes.new("ShaderNodeOutputMaterial")
        links.new(diffuse.outputs[0], out.inputs["Surface"])
        return material

    def _mesh(self, name: str, mesh, material) -> None:
        """A camera-frame trimesh (uv kept when it has them), in Blender's frame."""
        vertices = np.asarray(mesh.vertices) @ CAM_TO_BLENDER.T
        data = self.bpy.data.meshes.new(name)
        data.from_pydata(vertices.tolist(), [], np.asarray(mesh.faces).tolist())
        uv = getattr(mesh.visual, "uv", None)
        if uv is not None:
            layer = data.uv_layers.new(name="uv")
            loops = np.asarray(mesh.faces).ravel()  # from_pydata keeps the faces' vertex order
            layer.data.foreach_set("uv", np.asarray(uv, np.float32)[loops].ravel())
        data.materials.append(material)
        data.update()
        obj = self.bpy.data.objects.new(name, data)
        self.scene.collection.objects.link(obj)

    def render(self, window: Window) -> tuple[np.ndarray, float, float]:
        """(linear RGB radiance of ``window``, (H, W, 3) float32; wall s; process CPU s).

        Only the render is timed, not reading its pixels back. Columns outside the square
        (beyond the image circle) are black, as in the project's render.
        """
        d, lens = self.side, self.lens
        ox, oy = int(lens.cx_px - (d - 1) / 2), int(lens.cy_px - (d - 1) / 2)
        x0, x1 = max(window.x0 - ox, 0), min(window.x0 + window.width - ox, d)
        y0, y1 = max(window.y0 - oy, 0), min(window.y0 + window.height - oy, d)
        out = np.zeros((window.height, window.width, 3), np.float32)
        if x0 >= x1 or y0 >= y1:
            return out, 0.0, 0.0
        render = self.scene.render
        render.border_min_x, render.border_max_x = x0 / d, x1 / d
        render.border_min_y, render.border_max_y = (d - y1) / d, (d - y0) / d  # from the bottom
        t0, c0 = time.perf_counter(), time.process_time()
        with _quiet():
            self.bpy.ops.render.render()
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        rgb = self._read_result()
        if rgb.shape[:2] != (y1 - y0, x1 - x0):
            raise RuntimeError(f"Cycles rendered {rgb.shape[:2]}, expected {(y1 - y0, x1 - x0)}")
        rows = slice(y0 + oy - window.y0, y1 + oy - window.y0)
        out[rows, x0 + ox - window.x0 : x1 + ox - window.x0] = rgb
        return out, wall, cpu

    def _read_result(self) -> np.ndarray:
        """The last render as (H, W, 3) float32, row 0 on top (through a float EXR)."""
        with tempfile.TemporaryDirectory() as tmp:
            path = Path(tmp) / "render.exr"
            self.bpy.data.images["Render Result"].save_render(str(path))
            image = self.bpy.data.images.load(str(path))
            cols, rows = image.size
            pixels = np.empty(rows * cols * image.channels, np.float32)
            image.pixels.foreach_get(pixels)
            self.bpy.data.images.remove(image)
        return np.flipud(pixels.reshape(rows, cols, -1)[..., :3]).copy()


def _vector(v: np.ndarray):
    from mathutils import Vector  # bpy's own, importable once bpy is

    return Vector([float(c) for c in v])


@contextlib.contextmanager
def _quiet():
    """Blender prints progress per tile and sample and notes to fds 1 and 2: keep them off the
    benchmark's output (its errors still reach Python as exceptions)."""
    sys.stdout.flush()
    sys.stderr.flush()
    saved = [os.dup(1), os.dup(2)]
    try:
        with open(os.devnull, "w") as null:
            os.dup2(null.fileno(), 1)
            os.dup2(null.fileno(), 2)
            yield
    finally:
        for fd, copy in zip((1, 2), saved, strict=True):
            os.dup2(copy, fd)
            os.close(copy)
