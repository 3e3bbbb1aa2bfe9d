"""Video frames of the whisker array in vegetation through the fisheye, with motion blur.

What a frame needs, and only that:

* **Pixels.** Markers can only appear in a horizontal band: the mechanics run before the
  rendering, so the band is fitted to the markers' carriers over every deflection of the sample
  (or, without them, to any deflection at all; :func:`marker_region`), plus a margin. The
  default renders that band over the full width (black elsewhere); ``full_frame`` renders the
  whole image circle.
  Inside the *zone* (the band's columns that markers can reach) pixels get ``marker_spp``
  samples; elsewhere ``background_spp``. The zone is sampled identically in both modes, so band
  and full frames differ only outside the band (``whiskerbench bench dataset`` measures that the
  detections agree).
* **Rays.** The camera is rigid with the array, so every frame shoots the same rays: they are
  generated once by the shared camera model (:meth:`FisheyeCamera.unproject`), kept on the
  Dr.Jit side, and only the scene moves. Two scenes are traced: the array in the camera frame
  (re-posed per time sample: a few hundred triangles) and the vegetation in its own frame (never
  rebuilt; the array's offset moves the ray origins instead), plus a leaf canopy for shadows.
* **Time.** Each pixel's samples are spread over ``subframes`` instants within the exposure
  (stratified), each rendered with the array and its deflections at that instant: motion blur.
* **Light paths.** ``integrator="direct"`` (the default): direct light only. The sun is a delta
  light evaluated exactly with shadow rays through all three scenes (canopy rays jittered over
  the solar disk: soft penumbrae). The sky term is the exact unoccluded irradiance
  ``albedo * E(n) / pi`` (:mod:`renderers.sky_irradiance`). That is exact for the markers, whose
  faces look back at the camera, away from the vegetation in front of the array (nothing
  occludes their sky but the camera body); on the foliage, which nothing downstream measures,
  it ignores mutual occlusion between leaves.
  ``integrator="path"`` measures what that costs: from each hit a path continues along
  ``path_depth`` cosine-sampled bounces (Lambertian: throughput x albedo) through the array and
  the vegetation. Each vertex adds the exact sun; a bounce that escapes both scenes adds the
  sky in its direction, so leaves, branches and the array occlude the sky and light each other;
  the last vertex adds the unoccluded sky term as above. "direct" is this with zero bounces.
  The canopy casts shadows only (it is out of view): bounces do not see it. Bounce directions
  are seeded per sample and fixed for all its frames, like the camera rays.

Output: linear RGB radiance (H, W, 3) float32 over the region, 1.0 = full scale of the sensor at
exposure 1, for the camera twin (:mod:`renderers.camera_twin`; a grey sensor takes its Rec. 709
luminance). RGB rather than luminance costs 0-7% more render time (measured on dense foliage,
band and full frames), so there is one path. The region starts and ends on the twin's block grid
(``block_px``: the MJPEG macroblock), so a band encodes exactly as the same rows of a full frame.
Needs a JIT variant (``llvm_ad_rgb`` or ``cuda_ad_rgb``): millions of rays per frame are out of
reach of ``scalar_rgb``.

:class:`FrameRecorder` then records each frame through the camera twin, as the dataset's
videos hold them. The scenes are assembled in :mod:`renderers.array_scene`, the rays planned in
:mod:`renderers.frame_rays`.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np
import trimesh

from renderers.array_scene import ArrayScene, vegetation_scene
from renderers.camera_twin import pixel_gain
from renderers.drjit_ops import DrJitOps
from renderers.frame_passes import Batch, TwoPasses, needs_more
from renderers.frame_rays import RayPlan, ray_plan
from renderers.frame_sampling import FrameSampling, marker_region
from renderers.mitsuba_scene import CanopyScene
from renderers.sky_irradiance import irradiance_table
from renderers.twin_recorder import TwinRecorder
from renderers.variant import jit_variant_active
from renderers.window import Window
from scenes.array import ArraySpec
from scenes.camera import FisheyeCamera
from scenes.lighting import Lighting
from scenes.profile import CameraProfile

SHADOW_EPS_MM = 0.02  # shadow rays start this far off the surface (float32 at ~300 mm: 3e-5)


# -- the fixed set of rays -------------------------------------------------------------------


@dataclass
class _Vertex:
    """Where rays hit the nearer of the array and the vegetation, and its surface there."""

    hit: mi.Bool
    p_cam: mi.Point3f
    normal: mi.Vector3f  # towards the ray's origin on front faces; +z elsewhere (unused)
    albedo: mi.Color3f  # 0 on back faces (one-sided Lambertian) and where nothing is hit
    sun_f: mi.Color3f  # BSDF x sun irradiance, 0 likewise


# -- rendering -------------------------------------------------------------------------------


class FrameRenderer:
    """Renders frames of one sample: fixed rays, moving array, offset vegetation."""

    def __init__(
        self,
        camera: FisheyeCamera,
        spec: ArraySpec,
        vegetation_parts: Sequence[tuple[str, trimesh.Trimesh, tuple[float, float, float]]],
        lighting: Lighting,
        sampling: FrameSampling,
        seed: int,
        angles_rad: np.ndarray | None = None,
        block_px: int = 1,
        pixel_gain: Callable[[Window], np.ndarray] | None = None,
    ) -> None:
        """``angles_rad`` (..., n, 2): every deflection the frames will show, to fit the band
        to them (:func:`marker_region`); None fits it to any deflection. ``block_px``: the block
        grid (of the camera's stream) the band and zone are aligned to. ``pixel_gain``: maps the
        region to a per-pixel factor (H, W) float32 that every frame is multiplied by on the
        Dr.Jit side, with the average over each pixel's samples (the camera twin's per-pixel
        optics, :func:`renderers.camera_twin.pixel_gain`); None: 1."""
        if not jit_variant_active():
            raise RuntimeError(
                f"frame rendering needs a JIT variant (llvm_ad_rgb or cuda_ad_rgb), not "
                f"{mi.variant()}; `make setup` installs the libLLVM that llvm_ad_rgb needs"
            )
        self.camera, self.spec, self.lighting, self.sampling = camera, spec, lighting, sampling
        self.band, self.zone = marker_region(camera, spec, sampling.margin_px, angles_rad, block_px)
        self.region = Window.full(camera) if sampling.full_frame else self.band
        self.array = ArrayScene(spec)
        self.vegetation = vegetation_scene(vegetation_parts)
        self.canopy = CanopyScene(lighting).scene if lighting.canopy else None
        sun = lighting.sun
        cone = None
        if self.canopy is not None:
            cone = (np.asarray(sun.to_sun_cam), math.radians(sun.angular_radius_deg))
        plans, self._count = ray_plan(camera, self.region, self.zone, sampling, cone, seed)
        self.inside = self._count > 0
        # child 2 of the seed: ray_plan draws from children 0 and 1
        bounce_seeds = np.random.SeedSequence(seed).spawn(3)[2].generate_state(len(plans))
        self._batches = [self._batch(p, int(s)) for p, s in zip(plans, bounce_seeds, strict=True)]
        self._passes, self.rays_traced = None, 0  # rays_traced: summed over renders
        if sampling.adaptive:
            self._passes = TwoPasses(self._batches, [p.first for p in plans], self.region.shape)
        self._depth = sampling.path_depth if sampling.integrator == "path" else 0
        # OptiX runs one scene (shader binding table) per kernel: on CUDA, Dr.Jit disables a ray
        # query of a second scene recorded into the same kernel ("more than one OptiX shader
        # binding table was used within a single kernel"), so each query is evaluated on its own
        # (without it, frames on an H100 came out 22% too bright: results/gpu/figures.md).
        self._query_per_kernel = mi.variant().startswith("cuda")
        self._setup_shading()
        # Per pixel: its sample count (1 where it has none: its sum is 0) and gain, read by
        # each channel of the interleaved (H, W, 3) sum.
        self._divisor = mi.Float(np.maximum(self._count, 1).ravel().astype(np.float32))
        gain = None if pixel_gain is None else pixel_gain(self.region)
        self._gain = None if gain is None else mi.Float(np.asarray(gain, np.float32).ravel())
        self._channel_pixel = dr.arange(mi.UInt32, self.region.height * self.region.width * 3) // 3

    @property
    def rays_per_frame(self) -> int:
        """Samples per frame when every pixel gets all of its own (the planned rays)."""
        return int(self._count.sum())

    def _batch(self, plan: RayPlan, bounce_seed: int) -> Batch:
        sky = self.lighting.sky
        escape = sky.radiance(plan.dirs.astype(float))[:, None] * np.asarray(sky.color)
        return Batch(
            mi.Vector3f(plan.dirs.T),
            mi.UInt32(plan.pixel),
            mi.Color3f(escape.T.astype(np.float32)),
            None if plan.to_sun is None else mi.Vector3f(plan.to_sun.T),
            bounce_seed,
            dr.arange(mi.UInt32, len(plan.pixel)),
        )

    def _setup_shading(self) -> None:
        sky, sun = self.lighting.sky, self.lighting.sun
        table = irradiance_table(sky).astype(np.float32)
        self._rows = table.shape[0]
        self._irradiance = mi.Texture2f(
            mi.TensorXf(table[..., None]),
            filter_mode=dr.FilterMode.Linear,
            wrap_mode=dr.WrapMode.Repeat,
        )
        self._sky_rgb = mi.Color3f(sky.color)
        self._ops = DrJitOps()  # the sky's radiance along bounces, as kernel code
        self._sun = None
        if sun is not None:
            self._sun = (
                mi.Vector3f(sun.to_sun_cam),
                mi.Color3f(np.asarray(sun.color) * sun.irradiance),
            )

    def render(self, angles_rad: np.ndarray, offsets_mm: np.ndarray) -> np.ndarray:
        """Linear RGB radiance (H, W, 3) float32 of the region for one frame: each pixel's
        mean over its samples, times its ``pixel_gain``.

        ``angles_rad`` (subframes, n, 2) and ``offsets_mm`` (subframes, 2): the whiskers'
        deflections and the array's (x, z) offset in the vegetation frame at each time sample.
        """
        k = self.sampling.subframes
        angles_rad = np.asarray(angles_rad, dtype=float)
        offsets_mm = np.asarray(offsets_mm, dtype=float)
        if angles_rad.shape != (k, self.spec.n_whiskers, 2) or offsets_mm.shape != (k, 2):
            raise ValueError(
                f"need angles ({k}, {self.spec.n_whiskers}, 2) and offsets ({k}, 2), got "
                f"{angles_rad.shape} and {offsets_mm.shape}"
            )
        shifts = [dr.opaque(mi.Vector3f, [float(x), 0.0, float(z)]) for x, z in offsets_mm]
        if self._passes is None:
            total, divisor = self._one_pass(angles_rad, shifts), self._divisor
        else:
            total, divisor = self._two_passes(angles_rad, shifts)
        total /= dr.gather(mi.Float, divisor, self._channel_pixel)
        if self._gain is not None:
            total *= dr.gather(mi.Float, self._gain, self._channel_pixel)
        return total.numpy().reshape(*self.region.shape, 3)

    def _add(self, total: mi.Float, rgb: mi.Color3f, batch: Batch) -> None:
        for i in range(3):  # interleaved: (H, W, 3) once reshaped
            dr.scatter_reduce(dr.ReduceOp.Add, total, rgb[i], batch.pixel * 3 + i)

    def _one_pass(self, angles_rad: np.ndarray, shifts: list) -> mi.Float:
        """Each pixel's sum over all its samples, (H * W * 3,)."""
        total = dr.zeros(mi.Float, self.region.height * self.region.width * 3)
        for batch, angles, shift in zip(self._batches, angles_rad, shifts, strict=True):
            self.array.set_angles(angles)
            self._add(total, self._shade(batch, shift), batch)
            dr.eval(total)  # before the next time sample moves the array
        self.rays_traced += self.rays_per_frame
        return total

    def _two_passes(self, angles_rad: np.ndarray, shifts: list) -> tuple[mi.Float, mi.Float]:
        """Each pixel's sum over its first sample, or all its samples where the first pass shows
        an edge nearby (:mod:`renderers.frame_passes`), and the number of samples summed."""
        passes, size = self._passes, self.region.height * self.region.width * 3
        first, first_rgb = dr.zeros(mi.Float, size), []
        for batch, angles, shift in zip(passes.first, angles_rad, shifts, strict=True):
            self.array.set_angles(angles)
            first_rgb.append(self._shade(batch, shift))
            self._add(first, first_rgb[-1], batch)
            dr.eval(first, first_rgb[-1])
        image = first.numpy().reshape(*self.region.shape, 3)
        image /= np.maximum(passes.first_count, 1)[..., None]
        band_rows = slice(
            self.band.y0 - self.region.y0, self.band.y0 - self.region.y0 + self.band.height
        )
        flags = (needs_more(image, band_rows) & (self._count > passes.first_count)) | (
            passes.first_count == 0
        )
        total, flat = dr.zeros(mi.Float, size), flags.ravel()
        for j, (angles, shift) in enumerate(zip(angles_rad, shifts, strict=True)):
            self._add(total, first_rgb[j], passes.first[j])  # in time-sample order, as one pass
            rest = passes.rest(j, self._batches[j], flat)
            if rest is not None:
                self.array.set_angles(angles)
                self._add(total, self._shade(rest, shift), rest)
            dr.eval(total)
        count = np.where(flags, self._count, passes.first_count)
        self.rays_traced += int(count.sum())
        return total, mi.Float(np.maximum(count, 1).ravel().astype(np.float32))

    def _shade(self, batch: Batch, shift: mi.Vector3f) -> mi.Color3f:
        """RGB radiance of each ray: its first hit lit by sun and sky, plus, for "path", the
        light its bounces gather (one kernel: the loop over the few bounces is unrolled)."""
        v = self._nearest(mi.Point3f(0.0), batch.dirs, shift, True)
        rgb = dr.select(v.hit, self._light(v, shift, batch, self._depth == 0), batch.sky_escape)
        if self._depth == 0:
            return rgb
        n = dr.width(batch.pixel)
        rng = mi.PCG32(n, batch.bounce_seed, mi.UInt64(batch.index))
        beta = mi.Color3f(1.0)  # path throughput
        for bounce in range(1, self._depth + 1):
            active = v.hit & (dr.max(v.albedo) > 0)
            beta *= v.albedo  # Lambertian, cosine-sampled: f cos / pdf = albedo
            local = mi.warp.square_to_cosine_hemisphere(
                mi.Point2f(rng.next_float32(), rng.next_float32())
            )
            d = mi.Frame3f(v.normal).to_world(local)
            v = self._nearest(v.p_cam + v.normal * SHADOW_EPS_MM, d, shift, active)
            sky = self.lighting.sky.radiance_xyz(d.x, d.y, d.z, self._ops) * self._sky_rgb
            light = dr.select(v.hit, self._light(v, shift, batch, bounce == self._depth), sky)
            rgb += dr.select(active, beta * light, 0.0)
        return rgb

    def _query(self, result):
        """A ray query's result, evaluated now on CUDA (one scene per kernel, see __init__);
        unchanged on LLVM, whose kernels may trace any number of scenes."""
        if self._query_per_kernel:
            dr.eval(result)
        return result

    def _nearest(self, origin_cam, dirs, shift: mi.Vector3f, active) -> _Vertex:
        """The nearer hit of the array and the vegetation along rays from ``origin_cam``.

        The vegetation is searched only up to the array's hit (a shorter ray prunes the search).
        Both searches are preliminary (where, not what); only the nearer hit's surface is then
        computed and shaded, once per ray (bit for bit what shading both and selecting gave,
        4-7% less render time on the quick dataset).
        """
        ray_cam = mi.Ray3f(origin_cam, dirs)
        pi_a = self._query(self.array.scene.ray_intersect_preliminary(ray_cam, active=active))
        ray_veg = mi.Ray3f(mi.Ray3f(origin_cam + shift, dirs), pi_a.t)
        pi_v = self._query(self.vegetation.ray_intersect_preliminary(ray_veg, active=active))
        near_a = pi_a.is_valid() & ~pi_v.is_valid()
        hit = pi_a.is_valid() | pi_v.is_valid()
        offset = dr.select(near_a, mi.Vector3f(0.0), shift)  # the hit scene's frame
        ray = mi.Ray3f(origin_cam + offset, dirs)
        si = dr.select(near_a, pi_a, pi_v).compute_surface_interaction(ray, mi.RayFlags.All, hit)
        normal, albedo, sun_f = self._surface(si, ray, hit)
        return _Vertex(hit, si.p - offset, normal, albedo, sun_f)

    def _light(self, v: _Vertex, shift: mi.Vector3f, batch: Batch, sky: bool) -> mi.Color3f:
        """Light a vertex sends back along its ray: the sun, and with ``sky`` the unoccluded
        sky (shadow rays leave only points that face the sun: work masked off costs little in a
        vectorized kernel)."""
        rgb = mi.Color3f(0.0)
        if sky:
            # E(n) from the table over (azimuth u, polar v); clamp v so it never wraps at poles
            n = v.normal
            u = dr.atan2(n.y, n.x) / (2 * math.pi)
            half = 0.5 / self._rows
            t = dr.clip(dr.acos(dr.clip(n.z, -1.0, 1.0)) / math.pi, half, 1.0 - half)
            irradiance = self._irradiance.eval(mi.Point2f(u, t))[0]
            rgb = (v.albedo * self._sky_rgb) * (irradiance / math.pi)
        if self._sun is not None:
            lit = v.hit & (dr.sum(v.sun_f) > 0)
            rgb += v.sun_f * self._sun_visible(v.p_cam, v.normal, shift, batch, lit)
        return rgb

    def _surface(self, si: mi.SurfaceInteraction3f, ray: mi.Ray3f, active: mi.Bool):
        """(normal, albedo, BSDF x sun) where ``active``; zero on back faces."""
        front = active & (dr.dot(si.sh_frame.n, -ray.d) > 0)
        bsdf = si.bsdf()
        albedo = bsdf.eval_diffuse_reflectance(si, front)
        sun_f = mi.Color3f(0.0)
        if self._sun is not None:
            to_sun, sun_rgb = self._sun
            sun_f = bsdf.eval(mi.BSDFContext(), si, si.to_local(to_sun), front) * sun_rgb
        normal = dr.select(front, si.sh_frame.n, mi.Vector3f(0.0, 0.0, 1.0))
        return normal, dr.select(front, albedo, 0.0), dr.select(front, sun_f, 0.0)

    def _sun_visible(self, p_cam, normal, shift, batch: Batch, active) -> mi.Float:
        """1 where the sun reaches the point past the array, the vegetation and the canopy."""
        to_sun = self._sun[0]
        origin = p_cam + normal * SHADOW_EPS_MM
        blocked = self._query(self.array.scene.ray_test(mi.Ray3f(origin, to_sun), active))
        blocked |= self._query(
            self.vegetation.ray_test(mi.Ray3f(origin + shift, to_sun), active & ~blocked)
        )
        if self.canopy is not None:
            blocked |= self._query(
                self.canopy.ray_test(mi.Ray3f(origin + shift, batch.to_sun), active & ~blocked)
            )
        return dr.select(blocked, 0.0, 1.0)


class FrameRecorder:
    """A sample's frames rendered and recorded through the camera twin: full-size 8-bit grey,
    one at a time, with the seconds spent rendering, in the optics and in the sensor."""

    def __init__(
        self,
        profile: CameraProfile,
        spec: ArraySpec,
        vegetation_parts: Sequence[tuple[str, trimesh.Trimesh, tuple[float, float, float]]],
        lighting: Lighting,
        sampling: FrameSampling,
        render_seed: int,
        noise_seed: int,
        exposure: float,
        angles_rad: np.ndarray,
        offsets_mm: np.ndarray,
    ) -> None:
        """``angles_rad`` (F, K + 1, n, 2): each frame's deflections at its K = ``subframes``
        time samples, then at its timestamp (the band is fitted to them all); ``offsets_mm``
        (F, K, 2): the array's (x, z) offset in the vegetation frame at each time sample;
        ``exposure``: linear radiance to sensor full scale, before the lighting's own factor."""
        self.profile = profile
        self.renderer = FrameRenderer(
            profile.lens,
            spec,
            vegetation_parts,
            lighting,
            sampling,
            render_seed,
            angles_rad=angles_rad,
            block_px=profile.stream.block_px,
            pixel_gain=lambda region: pixel_gain(profile, (region.x0, region.y0), region.shape),
        )
        self.angles_rad, self.offsets_mm = angles_rad, offsets_mm
        self.exposure = exposure * lighting.exposure
        renderer = self.renderer
        self.twin = TwinRecorder(profile, renderer.region, renderer.band, self.exposure, noise_seed)
        self.render_s = 0.0
        self.frames_reused = 0  # frames that took the previous frame's optical image
        self._last_frame: int | None = None  # the frame render_once was given before
        self._irradiance: np.ndarray | None = None  # the optical image record used last

    @property
    def optics_s(self) -> float:
        return self.twin.optics_s

    @property
    def sensor_s(self) -> float:
        return self.twin.sensor_s

    def reset_timers(self) -> None:
        self.render_s = self.twin.optics_s = self.twin.sensor_s = 0.0

    def radiance(self, f: int) -> np.ndarray:
        """Clean linear RGB radiance of frame ``f`` over the renderer's region, times the
        twin's per-pixel optics (:data:`~renderers.camera_twin.PIXEL_GAIN_STAGES`)."""
        t0 = time.perf_counter()
        k = self.renderer.sampling.subframes
        radiance = self.renderer.render(self.angles_rad[f, :k], self.offsets_mm[f])
        self.render_s += time.perf_counter() - t0
        return radiance

    def still_as(self, f: int, g: int) -> bool:
        """Whether frames ``f`` and ``g`` show the same scene at every time sample (the array
        at rest, a still lead-in): the same rays meet the same geometry, so the same radiance."""
        k = self.renderer.sampling.subframes
        return np.array_equal(self.angles_rad[f, :k], self.angles_rad[g, :k]) and np.array_equal(
            self.offsets_mm[f], self.offsets_mm[g]
        )

    def frame(self, f: int) -> np.ndarray:
        """The camera's 8-bit grey frame ``f`` (H, W): black outside the rendered region."""
        return self.record(self.render_once(f))

    def render_once(self, f: int) -> np.ndarray | None:
        """Frame ``f``'s radiance (:meth:`radiance`), or None where ``f`` is still as the frame
        given before it: render and optics are deterministic, so :meth:`record` reuses that
        frame's optical image and draws only the new frame's sensor noise."""
        still = self._last_frame is not None and self.still_as(f, self._last_frame)
        self._last_frame = f
        if still:
            self.frames_reused += 1
            return None
        return self.radiance(f)

    def record(self, radiance: np.ndarray | None) -> np.ndarray:
        """The 8-bit frame of :meth:`render_once`'s result, called in the frames' order (the
        sensor's noise streams go on from frame to frame): another thread may record frame f
        while :meth:`render_once` renders f + 1."""
        if radiance is not None:
            self._irradiance = self.twin.optics(radiance)
        return self.twin.expose(self._irradiance)
