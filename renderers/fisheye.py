"""Fisheye rendering: rays from the shared camera model, traced by Mitsuba, any pixel window.

Mitsuba has no fisheye sensor, so the rays come from :meth:`FisheyeCamera.unproject` (the same
code the labels and the pipeline use), jittered within each pixel, and are evaluated with
``integrator.sample``. Light is split in two parts that are rendered differently:

* the sky: by default exactly, as albedo x sky irradiance E(n) / pi from the traced hit's
  normal and albedo (:mod:`renderers.sky_irradiance`; valid where nothing occludes the sky,
  as for the study's lone marker), or with Mitsuba's ``direct`` integrator (Monte Carlo, correct
  with occluders) over the same sky as an environment map, or with its ``path`` integrator
  (the same, plus sky light reflected between surfaces over ``path_depth`` bounces). For the
  study's lone marker, a print on its flat carrier, nothing else is there to occlude or reflect
  the sky, so all three agree in expectation: "path" is the fidelity ladder's reference, which
  checks that, not a change of the image;
* the sun, a delta light: evaluated exactly per sample as BSDF x irradiance x visibility, so it
  carries no Monte Carlo noise. Keeping it per sample lets a leaf canopy's moving shadow be
  applied afterwards with one shadow ray per sample (:func:`canopy_visibility`) instead of a
  re-render per image. The sun is direct only in every sky mode: sunlight bounced off anything
  (the holder, were it in the scene) is left out.

Output is linear RGB radiance, float32. Pixels outside the image circle are black.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import mitsuba as mi
import numpy as np

from renderers.fisheye_trace import CHUNK_RAYS, BlockTracer, pad_rows
from renderers.frame_sampling import check_light_paths
from renderers.mitsuba_scene import CanopyScene, MarkerScene
from renderers.variant import jit_variant_active
from renderers.window import Window, edge_pixels
from scenes.camera import FisheyeCamera
from scenes.lighting import Lighting, canopy_frame


@dataclass
class RenderedWindow:
    """The clean render of one window: sky and sun parts per pixel, shadow-ray start points."""

    window: Window
    sky_rgb: np.ndarray  # (H, W, 3) float32, mean over the pixel's samples
    sun_rgb: np.ndarray  # (H, W, 3) float32, unshadowed by any canopy
    shadow_points_cam: np.ndarray | None  # (H, W, K, 3) float32 hit points (NaN: no hit)

    def radiance(self, sun_visibility: np.ndarray | None = None) -> np.ndarray:
        """Linear RGB radiance: (H, W, 3), or (N, H, W, 3) for N canopy visibilities (N, H, W)."""
        if sun_visibility is None:
            return self.sky_rgb + self.sun_rgb
        return self.sky_rgb[None] + sun_visibility[..., None] * self.sun_rgb[None]


SKY_METHODS = ("irradiance", "integrator", "path")


class FisheyeRenderer:
    """Renders windows of one marker scene through a fisheye camera model."""

    def __init__(
        self,
        camera: FisheyeCamera,
        scene: MarkerScene,
        spp: int = 16,
        shadow_spp: int = 4,
        sky: str = "irradiance",
        adaptive: bool = True,
        path_depth: int = 3,
    ) -> None:
        """``sky``: ``"irradiance"`` (exact and noise-free where nothing occludes the sky, as for
        the study's lone marker; :mod:`renderers.sky_irradiance`), ``"integrator"`` (Mitsuba's
        ``direct`` integrator, Monte Carlo, correct with occluders) or ``"path"`` (Mitsuba's
        ``path`` integrator with ``path_depth`` indirect bounces: interreflected sky light too).

        ``adaptive`` (with the noise-free ``irradiance`` sky, a square spp of even side and,
        under a leaf canopy, ``shadow_spp`` at most spp / 4):
        trace one stratified sample per 2 x 2 block of sub-cells first, and the other samples
        only in pixels where those disagree, and their neighbours. Light on a flat patch is
        constant, so a pixel whose samples agree holds the full render's value exactly; only
        edges need every sample (see the tests for the measured difference)."""
        if spp < 1 or shadow_spp < 1:
            raise ValueError(f"spp={spp}, shadow_spp={shadow_spp}: both must be >= 1")
        if sky not in SKY_METHODS:
            raise ValueError(f"sky={sky!r}: choose from {', '.join(SKY_METHODS)}")
        self.camera = camera
        self.scene = scene
        self.spp = spp
        self.shadow_spp = shadow_spp
        self.sky = sky
        side = math.isqrt(spp)
        self.adaptive = (
            adaptive
            and sky == "irradiance"
            and side * side == spp
            and side % 2 == 0
            # the canopy's shadow rays start from first-pass hits
            and (scene.lighting.canopy is None or shadow_spp <= spp // 4)
        )
        integrator = None
        if sky == "integrator":
            integrator = mi.load_dict({"type": "direct"})
        elif sky == "path":
            check_light_paths("path", path_depth)
            # max_depth 2 is direct light only; Russian roulette off (it starts at rr_depth)
            depth = path_depth + 2
            integrator = mi.load_dict({"type": "path", "max_depth": depth, "rr_depth": depth})
        self._tracer = BlockTracer(camera, scene.scene, scene.lighting, integrator)

    def render(self, window: Window, seed: int) -> RenderedWindow:
        """Render ``window``; ``seed`` fixes the pixel jitter and Monte Carlo samples.

        With a canopy, ``shadow_spp`` of each pixel's hit points are kept for
        :func:`canopy_visibility`: the canopy's penumbra spans about ten pixels here, so shadow
        visibility is smooth within a pixel and needs fewer rays than the marker's edges.
        """
        lighting = self.scene.lighting
        rng = np.random.default_rng(seed)
        h, w, s = window.height, window.width, self.spp
        first = _first_pass(s) if self.adaptive else np.arange(s)
        rest = np.setdiff1d(np.arange(s), first)
        n_first = len(first)
        keep = np.linspace(0, n_first - 1, min(self.shadow_spp, n_first)).round().astype(int)
        sky = np.zeros((h, w, 3), np.float32)
        sun = np.zeros_like(sky)
        shadow = np.full((h, w, len(keep), 3), np.nan, np.float32) if lighting.canopy else None
        # Row bands bound memory on full frames; a band's first pass fills about one chunk.
        rows = max(1, CHUNK_RAYS // (w * n_first))
        counter = 0
        for r0 in range(0, h, rows):
            band = Window(window.x0, window.y0 + r0, w, min(rows, h - r0))
            positions = band.sample_positions(s, rng)  # (bh, w, s, 2): all samples, drawn once
            pixels = positions.reshape(-1, s, 2)
            a = self._tracer.trace(pixels[:, first], seed + counter, shadow is not None)
            counter += 1
            bh = band.height
            rows_here = slice(r0, r0 + bh)
            sky[rows_here] = (a.sky / np.float32(n_first)).reshape(bh, w, 3)
            sun[rows_here] = (a.sun / np.float32(n_first)).reshape(bh, w, 3)
            if len(rest):
                edge = edge_pixels(a.light_max.reshape(bh, w), a.light_min.reshape(bh, w)).ravel()
                if edge.any():
                    b = self._tracer.trace(pixels[edge][:, rest], seed + counter, False)
                    counter += 1
                    for out, part_a, part_b in ((sky, a.sky, b.sky), (sun, a.sun, b.sun)):
                        flat = out[rows_here].reshape(-1, 3)  # a view of the band's rows
                        flat[edge] = (part_a[edge] + part_b) / np.float32(s)
            if shadow is not None:
                shadow[rows_here] = a.position.reshape(bh, w, n_first, 3)[:, :, keep]
        return RenderedWindow(window, sky, sun, shadow)


def _first_pass(spp: int) -> np.ndarray:
    """Sample indices of the adaptive first pass: one per 2 x 2 block of the stratified n x n
    sub-cells (:meth:`Window.sample_positions` numbers cell (col, row) as row * n + col)."""
    n = math.isqrt(spp)
    col, row = np.arange(spp) % n, np.arange(spp) // n
    return np.flatnonzero((col % 2 == 0) & (row % 2 == 0))


def canopy_visibility(
    canopy: CanopyScene,
    lighting: Lighting,
    rendered: RenderedWindow,
    n_images: int,
    rng: np.random.Generator,
) -> np.ndarray:
    """(N, H, W) float32 sun visibility through the leaf canopy, a new canopy shift per image.

    Shifting the canopy by ``o`` is the same as shifting the shadow-ray origins by ``-o``; the
    sun direction is jittered within the solar disk per ray, which gives true penumbrae.
    """
    if rendered.shadow_points_cam is None:
        raise ValueError("this render kept no shadow points: its lighting has no canopy")
    sun, spec = lighting.sun, lighting.canopy
    _, u, v = canopy_frame(sun, spec)
    pos = rendered.shadow_points_cam.reshape(-1, 3)
    hit = np.flatnonzero(~np.isnan(pos[:, 0]))
    shift = rng.uniform(-spec.max_shift_mm, spec.max_shift_mm, (n_images, 2))
    origins = pos[hit][None] - (shift[:, :1] * u + shift[:, 1:] * v)[:, None, :]
    dirs = jitter_in_cone(
        np.asarray(sun.to_sun_cam), np.radians(sun.angular_radius_deg), (n_images, len(hit)), rng
    )
    vis = np.ones((n_images, len(pos)), np.float32)
    vis[:, hit] = ~_ray_test(canopy.scene, origins.reshape(-1, 3), dirs.reshape(-1, 3)).reshape(
        n_images, len(hit)
    )
    return vis.reshape((n_images,) + rendered.shadow_points_cam.shape[:3]).mean(axis=-1)


def jitter_in_cone(
    axis: np.ndarray, half_angle: float, shape: tuple[int, ...], rng: np.random.Generator
) -> np.ndarray:
    """Unit directions uniform over the disk of angular radius ``half_angle`` around ``axis``."""
    u = np.cross(axis, [0.0, 0.0, 1.0] if abs(axis[2]) < 0.9 else [1.0, 0.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(axis, u)
    r = half_angle * np.sqrt(rng.random(shape))
    a = rng.uniform(0, 2 * np.pi, shape)
    d = axis + (r * np.cos(a))[..., None] * u + (r * np.sin(a))[..., None] * v
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


def _ray_test(scene: mi.Scene, origins: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """Occlusion of rays (any hit), (N,) bool; vectorized on JIT variants."""
    if jit_variant_active():
        out = np.zeros(len(origins), bool)
        for start in range(0, len(origins), CHUNK_RAYS):
            n = min(CHUNK_RAYS, len(origins) - start)
            o, d = (
                pad_rows(a[start : start + n], CHUNK_RAYS).T.astype(np.float32)
                for a in (origins, dirs)
            )
            out[start : start + n] = scene.ray_test(
                mi.Ray3f(mi.Point3f(o), mi.Vector3f(d))
            ).numpy()[:n]
        return out
    return np.array(
        [
            bool(scene.ray_test(mi.Ray3f(mi.Point3f(*o), mi.Vector3f(*d))))
            for o, d in zip(origins.tolist(), dirs.tolist(), strict=True)
        ]
    )
