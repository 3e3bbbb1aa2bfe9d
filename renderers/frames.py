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
* **Light paths.** Direct light only. The sun is a delta light evaluated exactly with shadow
  rays through all three scenes (canopy rays jittered over the solar disk: soft penumbrae). The
  sky term is the exact unoccluded irradiance ``albedo * E(n) / pi``
  (:mod:`renderers.sky_irradiance`). That is exact for the markers, whose faces look back at the
  camera, away from the vegetation in front of the array (nothing occludes their sky but the
  camera body); on the foliage, which nothing downstream measures, it ignores mutual
  occlusion between leaves.

Output: linear RGB radiance (H, W, 3) float32 over the region, 1.0 = full scale of the sensor at
exposure 1, for the camera twin (:mod:`renderers.camera_twin`; a grey sensor takes its Rec. 709
luminance). RGB rather than luminance costs 0-7% more render time (measured on dense foliage,
band and full frames), so there is one path. The region starts and ends on the twin's block grid
(``block_px``: the MJPEG macroblock), so a band encodes exactly as the same rows of a full frame.
Needs a JIT variant (``llvm_ad_rgb`` or ``cuda_ad_rgb``): millions of rays per frame are out of
reach of ``scalar_rgb``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np
import trimesh

from renderers.fisheye import jitter_in_cone
from renderers.mitsuba_scene import CanopyScene, diffuse_bsdf, mesh_to_mitsuba
from renderers.sky_irradiance import irradiance_table
from renderers.window import Window
from scenes.array import (
    ArraySpec,
    T_cam_marker,
    T_cam_whisker,
    deflection_rotation,
    frame_plate_mesh,
    marker_meshes,
    rod_mesh,
)
from scenes.camera import FisheyeCamera
from scenes.conventions import marker_corners_marker
from scenes.lighting import Lighting
from scenes.marker import marker_albedo
from scenes.validation import FieldError

ROD_ALBEDO = 0.55  # translucent white polyester, seen as a light grey
CARRIER_ALBEDO = 0.8
PLATE_ALBEDO = 0.12  # the dark printed arc behind the markers
SHADOW_EPS_MM = 0.02  # shadow rays start this far off the surface (float32 at ~300 mm: 3e-5)


@dataclass(frozen=True)
class FrameSampling:
    """How many samples where, and over how much time."""

    marker_spp: int = 4
    background_spp: int = 1
    subframes: int = 4
    full_frame: bool = False
    margin_px: int = 16  # > half the detector's largest threshold window (23 px)

    def __post_init__(self) -> None:
        for name in ("marker_spp", "background_spp", "subframes"):
            if not (isinstance(getattr(self, name), int) and getattr(self, name) >= 1):
                raise FieldError(name, f"{getattr(self, name)!r}: must be an integer >= 1")
        if self.margin_px < 0:
            raise FieldError("margin_px", f"{self.margin_px}: must be >= 0")


def marker_region(
    camera: FisheyeCamera,
    spec: ArraySpec,
    margin_px: int,
    angles_rad: np.ndarray | None = None,
    block_px: int = 1,
) -> tuple[Window, Window]:
    """(band, zone): the full-width rows and the box that every marker pixel lies in.

    With ``angles_rad`` (..., n, 2), the deflections a sample will show, the box holds the
    markers' carriers at all of them; without, any deflection at all (a marker corner stays
    within ``marker_offset_mm + carrier half-diagonal`` of its coupling: the projections of those
    spheres, sampled densely). ``margin_px`` adds room for the detector's threshold windows.
    Both boxes are then grown to whole ``block_px`` blocks of the full frame (clipped to it).
    """
    if angles_rad is None:
        half_diag = math.sqrt(2) * spec.marker_spec(spec.marker_ids[0]).carrier_half_mm
        radius = spec.marker_offset_mm + half_diag + 1.0
        polar = np.linspace(0, math.pi, 25)
        azimuth = np.linspace(0, 2 * math.pi, 48, endpoint=False)
        p, a = np.meshgrid(polar, azimuth)
        sphere = radius * np.stack(
            [np.sin(p) * np.cos(a), np.sin(p) * np.sin(a), np.cos(p)], axis=-1
        ).reshape(-1, 3)
        centres = T_cam_whisker(spec)[:, :3, 3]
        points = (centres[:, None, :] + sphere[None]).reshape(-1, 3)
    else:
        carrier_mm = 2 * spec.marker_spec(spec.marker_ids[0]).carrier_half_mm
        corners = marker_corners_marker(carrier_mm)
        T = T_cam_marker(spec, np.asarray(angles_rad, dtype=float).reshape(-1, spec.n_whiskers, 2))
        points = np.einsum("...ij,kj->...ki", T[..., :3, :3], corners) + T[..., None, :3, 3]
        points = points.reshape(-1, 3)
    px = camera.project(points)
    if np.isnan(px).any():
        raise ValueError("a marker can leave the image circle: the array does not fit this camera")
    lo = np.floor(px.min(axis=0)).astype(int) - margin_px
    hi = np.ceil(px.max(axis=0)).astype(int) + margin_px
    lo = np.maximum(lo, 0)
    hi = np.minimum(hi, [camera.width_px - 1, camera.height_px - 1])
    band = Window(0, int(lo[1]), camera.width_px, int(hi[1] - lo[1] + 1))
    zone = Window(int(lo[0]), int(lo[1]), int(hi[0] - lo[0] + 1), band.height)
    return band.aligned(block_px, camera), zone.aligned(block_px, camera)


# -- the array as Mitsuba meshes -------------------------------------------------------------


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
        self.scene = mi.load_dict(
            {
                "type": "scene",
                "prints": mesh_to_mitsuba("prints", print_all, diffuse_bsdf(atlas)),
                "carriers": mesh_to_mitsuba(
                    "carriers", _stack_meshes(carriers), diffuse_bsdf(CARRIER_ALBEDO)
                ),
                "rods": mesh_to_mitsuba(
                    "rods", _stack_meshes([rod_mesh(spec)] * n), diffuse_bsdf(ROD_ALBEDO)
                ),
                "plate": mesh_to_mitsuba(
                    "plate", frame_plate_mesh(spec), diffuse_bsdf(PLATE_ALBEDO)
                ),
            },
            optimize=False,
        )
        self._params = mi.traverse(self.scene)

    def set_angles(self, angles_rad: np.ndarray) -> None:
        """Pose every whisker for deflection angles (n, 2) (scenes.array convention)."""
        markers = T_cam_marker(self.spec, angles_rad)
        rods = self._T_cam_whisker.copy()  # rods turn about their couplings, which stay put
        rods[:, :3, :3] = rods[:, :3, :3] @ deflection_rotation(angles_rad)
        rod_local = np.broadcast_to(self._rod_local, (len(rods),) + self._rod_local.shape)
        for key, T, local in (
            ("prints", markers, self._print_local),
            ("carriers", markers, self._carrier_local),
            ("rods", rods, rod_local),
        ):
            posed = np.einsum("nij,nvj->nvi", T[:, :3, :3], local) + T[:, None, :3, 3]
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


# -- the fixed set of rays -------------------------------------------------------------------


@dataclass
class _Batch:
    """The rays of one time sample, resident on the Dr.Jit side."""

    dirs: mi.Vector3f
    pixel: mi.UInt32
    sky_escape: mi.Color3f  # radiance of the sky seen by rays that hit nothing
    to_sun: mi.Vector3f | None  # per ray, jittered over the solar disk (canopy shadows)


@dataclass
class _Plan:
    """The fixed samples of one time sample, NumPy side."""

    dirs: np.ndarray  # (m, 3) float32 camera-frame directions
    pixel: np.ndarray  # (m,) uint32 flat index into the region
    to_sun: np.ndarray | None  # (m, 3) float32 jittered sun directions, or None


def _ray_plan(
    camera: FisheyeCamera,
    region: Window,
    zone: Window,
    sampling: FrameSampling,
    sun_cone: tuple[np.ndarray, float] | None,
    seed: int,
) -> tuple[list[_Plan], np.ndarray]:
    """The samples of each time sample, and the number of samples per region pixel (H, W).

    Zone samples come from their own random stream and are drawn first, so they are the same
    whatever the region (band or full frame). Sample j of pixel (x, y) goes to time sample
    (j + x + y) mod subframes: every time sample covers the image evenly.
    """
    streams = np.random.SeedSequence(seed).spawn(2)
    parts = []
    for window, spp, stream in (
        (zone, sampling.marker_spp, streams[0]),
        (region, sampling.background_spp, streams[1]),
    ):
        rng = np.random.default_rng(stream)
        pos = window.sample_positions(spp, rng)  # (h, w, spp, 2)
        xy = np.floor(pos + 0.5).astype(np.int64).reshape(-1, 2)
        slot = np.tile(np.arange(spp), window.width * window.height)
        keep = np.ones(len(xy), bool)
        if window is region:  # background: only pixels outside the zone
            keep = ~(
                (xy[:, 0] >= zone.x0)
                & (xy[:, 0] < zone.x0 + zone.width)
                & (xy[:, 1] >= zone.y0)
                & (xy[:, 1] < zone.y0 + zone.height)
            )
        sun = None
        if sun_cone is not None:
            sun = jitter_in_cone(*sun_cone, (len(xy),), rng)[keep]
        parts.append((pos.reshape(-1, 2)[keep], xy[keep], slot[keep], sun))
    pos, xy, slot = (np.concatenate([p[i] for p in parts]) for i in range(3))
    dirs, valid = camera.unproject(pos)
    pixel = (xy[:, 1] - region.y0) * region.width + (xy[:, 0] - region.x0)
    when = (slot + xy[:, 0] + xy[:, 1]) % sampling.subframes
    sun = np.concatenate([p[3] for p in parts]) if sun_cone is not None else None
    plans = []
    for k in range(sampling.subframes):
        pick = valid & (when == k)
        plans.append(
            _Plan(
                dirs[pick].astype(np.float32),
                pixel[pick].astype(np.uint32),
                None if sun is None else sun[pick].astype(np.float32),
            )
        )
    count = np.bincount(pixel[valid], minlength=region.height * region.width)
    return plans, count.reshape(region.shape)


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
    ) -> None:
        """``angles_rad`` (..., n, 2): every deflection the frames will show, to fit the band
        to them (:func:`marker_region`); None fits it to any deflection. ``block_px``: the block
        grid (of the camera's stream) the band and zone are aligned to."""
        if mi.variant() is None or mi.variant().startswith("scalar"):
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
        plans, self._count = _ray_plan(camera, self.region, self.zone, sampling, cone, seed)
        self.inside = self._count > 0
        self._batches = [self._batch(plan) for plan in plans]
        self._setup_shading()

    @property
    def rays_per_frame(self) -> int:
        return int(self._count.sum())

    def _batch(self, plan: _Plan) -> _Batch:
        sky = self.lighting.sky
        escape = sky.radiance(plan.dirs.astype(float))[:, None] * np.asarray(sky.color)
        return _Batch(
            mi.Vector3f(plan.dirs.T),
            mi.UInt32(plan.pixel),
            mi.Color3f(escape.T.astype(np.float32)),
            None if plan.to_sun is None else mi.Vector3f(plan.to_sun.T),
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
        self._sun = None
        if sun is not None:
            self._sun = (
                mi.Vector3f(sun.to_sun_cam),
                mi.Color3f(np.asarray(sun.color) * sun.irradiance),
            )

    def render(self, angles_rad: np.ndarray, offsets_mm: np.ndarray) -> np.ndarray:
        """Linear RGB radiance (H, W, 3) float32 of the region for one frame.

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
        total = dr.zeros(mi.Float, self.region.height * self.region.width * 3)
        for batch, angles, offset in zip(self._batches, angles_rad, offsets_mm, strict=True):
            self.array.set_angles(angles)
            shift = dr.opaque(mi.Vector3f, [float(offset[0]), 0.0, float(offset[1])])
            rgb = self._shade(batch, shift)
            for i in range(3):  # interleaved: (H, W, 3) once reshaped
                dr.scatter_reduce(dr.ReduceOp.Add, total, rgb[i], batch.pixel * 3 + i)
            dr.eval(total)  # before the next time sample moves the array
        out = total.numpy().reshape(*self.region.shape, 3)
        count = self._count[..., None]
        return np.divide(out, count, out=np.zeros_like(out), where=count > 0)

    def _shade(self, batch: _Batch, shift: mi.Vector3f) -> mi.Color3f:
        """RGB radiance of each ray: nearest of the array and the vegetation, lit by sky and
        sun.

        The vegetation is searched only up to the array's hit (a shorter ray prunes the search),
        surfaces are shaded only where they are the nearest hit, and shadow rays leave only
        points that face the sun: work masked off costs little in a vectorized kernel.
        """
        ray_cam = mi.Ray3f(mi.Point3f(0.0), batch.dirs)
        si_a = self.array.scene.ray_intersect(ray_cam)
        ray_veg = mi.Ray3f(mi.Ray3f(mi.Point3f(shift), batch.dirs), si_a.t)
        si_v = self.vegetation.ray_intersect(ray_veg)
        near_a = si_a.is_valid() & ~si_v.is_valid()
        parts = [
            self._surface(si, ray_cam, active)
            for si, active in ((si_a, near_a), (si_v, si_v.is_valid()))
        ]
        normal, sky_albedo, sun_f = (
            dr.select(near_a, a, v) for a, v in zip(parts[0], parts[1], strict=True)
        )
        p_cam = dr.select(near_a, si_a.p, si_v.p - shift)
        hit = si_a.is_valid() | si_v.is_valid()
        # E(n) from the table over (azimuth u, polar v); clamp v so it never wraps at the poles
        u = dr.atan2(normal.y, normal.x) / (2 * math.pi)
        half = 0.5 / self._rows
        v = dr.clip(dr.acos(dr.clip(normal.z, -1.0, 1.0)) / math.pi, half, 1.0 - half)
        rgb = sky_albedo * (self._irradiance.eval(mi.Point2f(u, v))[0] / math.pi)
        if self._sun is not None:
            lit = hit & (dr.sum(sun_f) > 0)
            rgb += sun_f * self._sun_visible(p_cam, normal, shift, batch, lit)
        return dr.select(hit, rgb, batch.sky_escape)

    def _surface(self, si: mi.SurfaceInteraction3f, ray: mi.Ray3f, active: mi.Bool):
        """(normal, albedo x sky colour, BSDF x sun) where ``active``; zero on back faces."""
        front = active & (dr.dot(si.sh_frame.n, -ray.d) > 0)
        bsdf = si.bsdf()
        albedo = bsdf.eval_diffuse_reflectance(si, front)
        sun_f = mi.Color3f(0.0)
        if self._sun is not None:
            to_sun, sun_rgb = self._sun
            sun_f = bsdf.eval(mi.BSDFContext(), si, si.to_local(to_sun), front) * sun_rgb
        normal = dr.select(front, si.sh_frame.n, mi.Vector3f(0.0, 0.0, 1.0))
        return normal, dr.select(front, albedo * self._sky_rgb, 0.0), dr.select(front, sun_f, 0.0)

    def _sun_visible(self, p_cam, normal, shift, batch: _Batch, active) -> mi.Float:
        """1 where the sun reaches the point past the array, the vegetation and the canopy."""
        to_sun = self._sun[0]
        origin = p_cam + normal * SHADOW_EPS_MM
        blocked = self.array.scene.ray_test(mi.Ray3f(origin, to_sun), active)
        blocked |= self.vegetation.ray_test(mi.Ray3f(origin + shift, to_sun), active & ~blocked)
        if self.canopy is not None:
            blocked |= self.canopy.ray_test(
                mi.Ray3f(origin + shift, batch.to_sun), active & ~blocked
            )
        return dr.select(blocked, 0.0, 1.0)
