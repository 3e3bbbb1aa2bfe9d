"""Trace the samples of a block of pixels and reduce them per pixel, for :mod:`renderers.fisheye`.

On a JIT variant everything per sample is one Dr.Jit kernel per chunk: the pixel positions go
through the shared camera model (:meth:`FisheyeCamera.unproject_xy` over
:class:`renderers.drjit_ops.DrJitOps`), the rays are traced, the sky term is looked up with the
same code the NumPy side uses, and the samples are summed per pixel, so only per-pixel sums
come back to NumPy. ``scalar_rgb`` traces one ray at a time and reduces with NumPy (slow; the
fallback when no JIT backend works).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from renderers.sky_irradiance import sky_luminance
from renderers.variant import jit_variant_active
from scenes.array_ops import NUMPY
from scenes.camera import FisheyeCamera
from scenes.lighting import Lighting

#: Rays are traced in chunks of about this size (whole pixels, the last one padded): a new
#: wavefront size compiles a new kernel (~130 ms here), one fixed size compiles once and then
#: reuses it.
CHUNK_RAYS = 1 << 17
#: Every kernel's width is a whole number of packets of this many rays: a partial last packet
#: of an edge pass (12 samples a pixel: 16,380 rays) came with a rare segfault in a Dr.Jit
#: thread (``docs/reliability.md``). The padding repeats a real pixel and is dropped.
PACKET_LANES = 16
#: A pass of fewer than CHUNK_RAYS / 2 rays (a crop) goes in chunks of this size instead, so that
#: it is not padded to a whole CHUNK_RAYS; a worker that renders only crops compiles one kernel.
SMALL_CHUNK_RAYS = 1 << 14


@dataclass
class TracedBlock:
    """Per-pixel results of m pixels with k samples each."""

    sky: np.ndarray  # (m, 3) float32 sums over the pixel's samples
    sun: np.ndarray  # (m, 3) float32 sums, unshadowed by any canopy
    light_max: np.ndarray  # (m,) float32 largest sample light (sky + sun, summed over RGB)
    light_min: np.ndarray  # (m,) float32 smallest
    position: np.ndarray | None  # (m, k, 3) float32 hit points (NaN: no hit), if asked


class BlockTracer:
    """Traces (m, k, 2) pixel positions through one scene: sky and sun light per sample."""

    def __init__(
        self,
        camera: FisheyeCamera,
        scene: mi.Scene,
        lighting: Lighting,
        integrator: mi.Integrator | None,
    ) -> None:
        self.camera, self.scene, self.lighting = camera, scene, lighting
        self.integrator = integrator
        self.jit = jit_variant_active()
        if self.jit:
            from renderers.drjit_ops import DrJitOps

            self.ops = DrJitOps()

    def trace(self, points: np.ndarray, seed: int, positions: bool) -> TracedBlock:
        """Per-pixel sums of (m, k, 2) sample positions; ``seed`` seeds the Monte Carlo sky."""
        m, k, _ = points.shape
        if not self.jit:
            return self._trace_scalar(points, seed, positions)
        chunk = CHUNK_RAYS if 2 * m * k >= CHUNK_RAYS else SMALL_CHUNK_RAYS
        per = max(1, chunk // k)  # whole pixels per chunk
        step = PACKET_LANES // math.gcd(k, PACKET_LANES)
        width = -(-per // step) * step  # the chunk's pixels padded to whole packets of rays
        parts = []
        for c, start in enumerate(range(0, m, per)):
            block = points[start : start + per]
            n = len(block)
            block = pad_rows(block, width)  # one kernel size
            out = self._trace_jit(block.reshape(-1, 2), k, c, seed, positions)
            parts.append(tuple(None if a is None else a[:n] for a in out))
        cols = [np.concatenate([p[i] for p in parts]) for i in range(4)]
        pos = np.concatenate([p[4] for p in parts]) if positions else None
        return TracedBlock(*cols, pos)

    def _trace_jit(self, points: np.ndarray, k: int, c: int, seed: int, positions: bool) -> tuple:
        ops, lighting = self.ops, self.lighting
        x, y = ops.Float(points[:, 0]), ops.Float(points[:, 1])
        dx, dy, dz, valid = self.camera.unproject_xy(x, y, ops)
        ray = mi.RayDifferential3f(
            mi.Ray3f(mi.Point3f(0.0), mi.Vector3f(mi.Float(dx), mi.Float(dy), mi.Float(dz)))
        )
        si = self.scene.ray_intersect(ray, active=valid)
        hit = si.is_valid()
        # Lambertian surfaces are one-sided in Mitsuba: seen from behind they are black.
        front = hit & (dr.dot(si.sh_frame.n, -ray.d) > 0)
        bsdf = si.bsdf(ray)
        albedo = dr.select(front, bsdf.eval_diffuse_reflectance(si, front), 0.0)
        sun = dr.zeros(mi.Color3f, dr.width(x))
        if lighting.sun is not None:
            to_sun = mi.Vector3f(lighting.sun.to_sun_cam)
            f = bsdf.eval(mi.BSDFContext(), si, si.to_local(to_sun), front)
            lit = front & ~self.scene.ray_test(si.spawn_ray(to_sun), front)
            sun = dr.select(lit, f * lighting.sun.irradiance * mi.Color3f(lighting.sun.color), 0.0)
        sky_rgb = mi.Color3f(lighting.sky.color)
        if self.integrator is None:
            normal = dr.select(front, si.sh_frame.n, 0.0)
            lit = front & (dr.max(albedo) > 0)
            normal_xyz = (normal.x, normal.y, normal.z)
            lum = sky_luminance(lighting.sky, valid, hit, lit, normal_xyz, (dx, dy, dz), ops)
            sky = dr.select(hit, albedo, 1.0) * mi.Float(lum) * sky_rgb
        else:
            sampler = mi.load_dict({"type": "independent"})
            sampler.seed((seed * 7919 + c) & 0xFFFFFFFF, dr.width(x))
            sky = dr.select(valid, self.integrator.sample(self.scene, sampler, ray)[0], 0.0)
        light = dr.sum(sky + sun)
        per_sample = [*sky, *sun, light]
        if positions:
            per_sample += [*dr.select(hit, si.p, mi.Point3f(dr.nan))]
        dr.eval(*per_sample)  # one kernel; the per-pixel reductions then read its output
        sums = [_per_pixel(dr.ReduceOp.Add, v, k).numpy() for v in per_sample[:6]]
        hi, lo = (_per_pixel(op, light, k).numpy() for op in (dr.ReduceOp.Max, dr.ReduceOp.Min))
        pos = None
        if positions:
            pos = np.stack([v.numpy() for v in per_sample[7:]], axis=-1).reshape(-1, k, 3)
        return np.stack(sums[:3], -1), np.stack(sums[3:], -1), hi, lo, pos

    def _trace_scalar(self, points: np.ndarray, seed: int, positions: bool) -> TracedBlock:
        """One ray at a time (scalar_rgb), then the same sky term and sums in NumPy."""
        m, k, _ = points.shape
        dirs, valid = self.camera.unproject(points.reshape(-1, 2))
        n = len(dirs)
        out = {key: np.zeros((n, 3), np.float32) for key in ("sky", "sun", "normal", "albedo")}
        pos = np.full((n, 3), np.nan, np.float32)
        hit = np.zeros(n, bool)
        lighting = self.lighting
        sampler = mi.load_dict({"type": "independent"})
        sampler.seed(seed)
        for i in np.flatnonzero(valid):
            ray = mi.RayDifferential3f(mi.Ray3f(mi.Point3f(0.0), mi.Vector3f(*map(float, dirs[i]))))
            if self.integrator is not None:
                out["sky"][i] = np.array(self.integrator.sample(self.scene, sampler, ray)[0])
                sampler.advance()
            si = self.scene.ray_intersect(ray)
            if not si.is_valid():
                continue
            hit[i], pos[i] = True, np.array(si.p)
            if dr.dot(si.sh_frame.n, -ray.d) <= 0:
                continue
            bsdf = si.bsdf(ray)
            out["normal"][i] = np.array(si.sh_frame.n)
            out["albedo"][i] = np.array(bsdf.eval_diffuse_reflectance(si))
            if lighting.sun is not None:
                to_sun = mi.Vector3f(lighting.sun.to_sun_cam)
                if not self.scene.ray_test(si.spawn_ray(to_sun)):
                    f = np.array(bsdf.eval(mi.BSDFContext(), si, si.to_local(to_sun)))
                    out["sun"][i] = f * lighting.sun.irradiance * np.asarray(lighting.sun.color)
        if self.integrator is None:
            lit = hit & out["albedo"].any(axis=1)
            normal = out["normal"].astype(float)
            lum = sky_luminance(
                lighting.sky, valid, hit, lit, tuple(normal.T), tuple(dirs.T), NUMPY
            )
            albedo = np.where(hit[:, None], out["albedo"], np.float32(1.0))
            color = np.asarray(lighting.sky.color, np.float32)
            out["sky"] = albedo * lum.astype(np.float32)[:, None] * color
        light = (out["sky"] + out["sun"]).sum(axis=-1).reshape(m, k)
        return TracedBlock(
            out["sky"].reshape(m, k, 3).sum(axis=1),
            out["sun"].reshape(m, k, 3).sum(axis=1),
            light.max(axis=1),
            light.min(axis=1),
            pos.reshape(m, k, 3) if positions else None,
        )


def pad_rows(a: np.ndarray, length: int) -> np.ndarray:
    """``a`` padded along its first axis to ``length`` rows with copies of its first row: a
    chunk of fixed size reuses one compiled kernel."""
    if len(a) == length:
        return a
    return np.concatenate([a, np.broadcast_to(a[:1], (length - len(a), *a.shape[1:]))])


def _per_pixel(op: dr.ReduceOp, value, k: int):
    """Reduce each pixel's k consecutive samples (of an evaluated array: one pass each)."""
    return value if k == 1 else dr.block_reduce(op, value, k, mode="evaluated")
