"""Fisheye rendering: rays from the shared camera model, traced by Mitsuba, any pixel window.

Mitsuba has no fisheye sensor, so the rays come from :meth:`FisheyeCamera.unproject` (the same
code the labels and the pipeline use), jittered within each pixel, and are evaluated with
``integrator.sample``. Light is split in two parts that are rendered differently:

* the sky (an environment map): Mitsuba's ``direct`` integrator with BSDF sampling, Monte Carlo;
* the sun, a delta light: evaluated exactly per sample as BSDF x irradiance x visibility, so it
  carries no Monte Carlo noise. Keeping it per sample lets a leaf canopy's moving shadow be
  applied afterwards with one shadow ray per sample (:func:`canopy_visibility`) instead of a
  re-render per image.

Output is linear RGB radiance, float32. Pixels outside the image circle are black.
"""

from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from renderers.mitsuba_scene import CanopyScene, MarkerScene
from renderers.window import Window
from scenes.camera import FisheyeCamera
from scenes.lighting import Lighting, canopy_frame

#: Rays are traced in chunks of exactly this size (the last one padded): a new wavefront size
#: compiles a new kernel (~130 ms here), one fixed size compiles once and then reuses it.
CHUNK_RAYS = 1 << 17


@dataclass
class RenderedWindow:
    """The clean render of one window: sky and sun parts per pixel, shadow-ray start points."""

    window: Window
    sky_rgb: np.ndarray  # (H, W, 3) float32, mean over the pixel's samples
    sun_rgb: np.ndarray  # (H, W, 3) float32, unshadowed by any canopy
    shadow_points_cam: np.ndarray | None  # (H, W, K, 3) float32 hit points (NaN: no hit)
    inside: np.ndarray  # (H, W) bool: pixel centre inside the image circle

    def radiance(self, sun_visibility: np.ndarray | None = None) -> np.ndarray:
        """Linear RGB radiance: (H, W, 3), or (N, H, W, 3) for N canopy visibilities (N, H, W)."""
        if sun_visibility is None:
            return self.sky_rgb + self.sun_rgb
        return self.sky_rgb[None] + sun_visibility[..., None] * self.sun_rgb[None]


def _is_jit() -> bool:
    return mi.variant() is not None and not mi.variant().startswith("scalar")


def _trace_jit(scene: mi.Scene, integrator: mi.Integrator, lighting: Lighting, dirs: np.ndarray,
               seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    n = len(dirs)
    ray = mi.RayDifferential3f(mi.Ray3f(mi.Point3f(0.0, 0.0, 0.0), mi.Vector3f(dirs.T.astype(np.float32))))
    sampler = mi.load_dict({"type": "independent"})
    sampler.seed(seed, n)
    sky, _, _ = integrator.sample(scene, sampler, ray)
    si = scene.ray_intersect(ray)
    sun = mi.Color3f(0.0)
    if lighting.sun is not None:
        to_sun = mi.Vector3f(lighting.sun.to_sun_cam)
        bsdf = si.bsdf(ray)
        f = bsdf.eval(mi.BSDFContext(), si, si.to_local(to_sun), si.is_valid())
        lit = si.is_valid() & ~scene.ray_test(si.spawn_ray(to_sun), si.is_valid())
        sun = dr.select(lit, f * lighting.sun.irradiance * mi.Color3f(lighting.sun.color), 0.0)
    p = dr.select(si.is_valid(), si.p, mi.Point3f(dr.nan))
    dr.eval(sky, sun, p)
    return sky.numpy().T, sun.numpy().T, p.numpy().T


def _trace_scalar(scene: mi.Scene, integrator: mi.Integrator, lighting: Lighting, dirs: np.ndarray,
                  seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The same computation one ray at a time, for the scalar_rgb fallback (slow)."""
    sampler = mi.load_dict({"type": "independent"})
    sampler.seed(seed)
    out = np.zeros((3, len(dirs), 3), dtype=np.float32)
    out[2] = np.nan
    for i, d in enumerate(dirs):
        ray = mi.RayDifferential3f(mi.Ray3f(mi.Point3f(0.0), mi.Vector3f(*map(float, d))))
        sky, _, _ = integrator.sample(scene, sampler, ray)
        sampler.advance()
        out[0, i] = np.array(sky)
        si = scene.ray_intersect(ray)
        if not si.is_valid():
            continue
        out[2, i] = np.array(si.p)
        if lighting.sun is not None:
            to_sun = mi.Vector3f(lighting.sun.to_sun_cam)
            if not scene.ray_test(si.spawn_ray(to_sun)):
                f = si.bsdf(ray).eval(mi.BSDFContext(), si, si.to_local(to_sun))
                out[1, i] = np.array(f) * lighting.sun.irradiance * np.asarray(lighting.sun.color)
    return out[0], out[1], out[2]


class FisheyeRenderer:
    """Renders windows of one marker scene through a fisheye camera model."""

    def __init__(
        self, camera: FisheyeCamera, scene: MarkerScene, spp: int = 16, shadow_spp: int = 4
    ) -> None:
        if spp < 1 or shadow_spp < 1:
            raise ValueError(f"spp={spp}, shadow_spp={shadow_spp}: both must be >= 1")
        self.camera = camera
        self.scene = scene
        self.spp = spp
        self.shadow_spp = shadow_spp
        # BSDF sampling only: the sky is smooth, so cosine-weighted sampling is near zero-variance
        # (exactly zero for a uniform sky); the sun, the one sharp light, is evaluated exactly.
        self.integrator = mi.load_dict({"type": "direct", "emitter_samples": 0, "bsdf_samples": 1})
        self._trace = _trace_jit if _is_jit() else _trace_scalar

    def render(self, window: Window, seed: int) -> RenderedWindow:
        """Render ``window``; ``seed`` fixes the pixel jitter and Monte Carlo samples.

        With a canopy, ``shadow_spp`` of each pixel's hit points are kept for
        :func:`canopy_visibility`: the canopy's penumbra spans about ten pixels here, so shadow
        visibility is smooth within a pixel and needs fewer rays than the marker's edges.
        """
        lighting = self.scene.lighting
        rng = np.random.default_rng(seed)
        h, w, s = window.height, window.width, self.spp
        dirs, valid = self.camera.unproject(window.sample_positions(s, rng).reshape(-1, 2))
        sky = np.zeros((h * w * s, 3), np.float32)
        sun = np.zeros_like(sky)
        pos = np.full_like(sky, np.nan)
        idx = np.flatnonzero(valid)
        for k, start in enumerate(range(0, len(idx), CHUNK_RAYS)):
            part = idx[start:start + CHUNK_RAYS]
            traced = self._trace(
                self.scene.scene, self.integrator, lighting, _pad(dirs[part]), (seed * 7919 + k) & 0xFFFFFFFF
            )
            sky[part], sun[part], pos[part] = (a[: len(part)] for a in traced)
        sky = sky.reshape(h, w, s, 3).mean(axis=2)
        sun = sun.reshape(h, w, s, 3).mean(axis=2)
        inside = self.camera.unproject(window.pixel_centres())[1]
        shadow_points = None
        if lighting.canopy is not None:
            keep = np.linspace(0, s - 1, min(self.shadow_spp, s)).round().astype(int)
            shadow_points = pos.reshape(h, w, s, 3)[:, :, keep]
        return RenderedWindow(window, sky, sun, shadow_points, inside)


def _pad(rays: np.ndarray) -> np.ndarray:
    """Pad (n, 3) rays to a whole chunk (JIT variants only) with copies of the first ray."""
    if not _is_jit() or len(rays) == CHUNK_RAYS:
        return rays
    return np.concatenate([rays, np.broadcast_to(rays[:1], (CHUNK_RAYS - len(rays), 3))])


def canopy_visibility(canopy: CanopyScene, lighting: Lighting, rendered: RenderedWindow,
                      n_images: int, rng: np.random.Generator) -> np.ndarray:
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
    dirs = _jitter_in_cone(np.asarray(sun.to_sun_cam), np.radians(sun.angular_radius_deg),
                           (n_images, len(hit)), rng)
    vis = np.ones((n_images, len(pos)), np.float32)
    vis[:, hit] = ~_ray_test(canopy.scene, origins.reshape(-1, 3), dirs.reshape(-1, 3)).reshape(
        n_images, len(hit))
    return vis.reshape((n_images,) + rendered.shadow_points_cam.shape[:3]).mean(axis=-1)


def _jitter_in_cone(axis: np.ndarray, half_angle: float, shape: tuple[int, ...],
                    rng: np.random.Generator) -> np.ndarray:
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
    if _is_jit():
        out = np.zeros(len(origins), bool)
        for start in range(0, len(origins), CHUNK_RAYS):
            n = min(CHUNK_RAYS, len(origins) - start)
            o, d = (_pad(a[start:start + n]).T.astype(np.float32) for a in (origins, dirs))
            out[start:start + n] = scene.ray_test(mi.Ray3f(mi.Point3f(o), mi.Vector3f(d))).numpy()[:n]
        return out
    return np.array([bool(scene.ray_test(mi.Ray3f(mi.Point3f(*o), mi.Vector3f(*d))))
                     for o, d in zip(origins.tolist(), dirs.tolist(), strict=True)])
