"""The marker detectability study (SPEC section 4) on a camera twin, one independent task per cell.

A cell is (lighting, size, alpha, phi). Its noise-free colour radiance is rendered once, as a crop
around the marker: the detector only ever looks at the marker and its surroundings, and the rest
of the frame changes nothing it sees (``whiskerbench bench detectability`` measures the saving
against full frames). The crop starts on the camera's MJPEG block grid, so its blocks and Bayer
phase are those of the full frame. For each PSF scale of the sensitivity band the profile's
optics are applied once, and camera images are then drawn from its sensor and stream stages
adaptively: in batches until the Wilson interval of the detection rate excludes 0.95 or the cap
``images`` is reached (a cell that never detects is settled after 10 images, a perfect one after
80). Each image is detected once (OpenCV, ``subpix`` corners as the original system used) and
its corners refined again with the project's ``lines``; both are posed and scored (at the
nominal PSF scale, on a cell's first :data:`POSE_IMAGES` images; the band's other scales and the
images beyond measure detection only). A cell's rows
are written atomically to ``cells/<key>_x<scale>.parquet``, so an interrupted study resumes
where it stopped.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import pandas as pd

from bench.common.atomic import atomic_path, write_bytes
from bench.study.config import IMAGE_STEPS, POSE_IMAGES, Cell, StudyConfig
from bench.study.report import REFINEMENTS, excludes_threshold, wilson_interval
from pipeline.detect import detect_markers
from pipeline.pose import estimate_pose
from pipeline.refine import refine_corners_by_edges
from renderers.camera_twin import optical_image, sensor_images
from scenes.conventions import marker_corners_marker, rotation_angle_deg, transform_points
from scenes.lighting import get_lighting
from scenes.marker import MarkerSpec, carrier_mesh, get_dictionary
from scenes.profile import CameraProfile
from scenes.study import study_pose

# --- Per-process render state: one loaded scene per lighting, reused by every cell.
_STATE: dict = {}


def init_worker(variant: str | None, threads: int | None = None) -> str:
    """Set the Mitsuba variant in this process (called once per worker); return it."""
    from renderers.variant import select_variant

    chosen = select_variant(variant)
    if threads:
        import drjit as dr

        dr.set_thread_count(threads)
    return chosen


def renderer_for(config: StudyConfig, lighting_name: str):
    from renderers.fisheye import FisheyeRenderer
    from renderers.mitsuba_scene import CanopyScene, MarkerScene

    lens = config.camera.lens
    key = (lighting_name, config.dictionary, config.marker_id, config.spp, lens)
    if key not in _STATE:
        lighting = get_lighting(lighting_name)
        scene = MarkerScene(MarkerSpec(config.dictionary, config.marker_id, 10.0), lighting)
        canopy = CanopyScene(lighting) if lighting.canopy else None
        _STATE[key] = (FisheyeRenderer(lens, scene, spp=config.spp), canopy)
    return _STATE[key]


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


@dataclass
class CellRender:
    """A cell's clean crop: its window, the render and the marker's true pose."""

    window: object
    rendered: object
    T_cam_marker: np.ndarray
    render_s: float


def render_cell(config: StudyConfig, cell: Cell, margin_px: int = 16) -> CellRender:
    """Render a cell's clean crop once, framed by the carrier and aligned to the block grid."""
    from renderers.window import Window

    lens = config.camera.lens
    T_cam_marker = study_pose(cell.alpha_deg, cell.phi_deg, config.distance_mm)
    spec = MarkerSpec(config.dictionary, config.marker_id, cell.size_mm)
    window = Window.around(
        lens.project(carrier_outline(T_cam_marker, spec)), lens, margin_px=margin_px
    ).aligned(config.camera.crop_grid_px, lens)
    renderer, _ = renderer_for(config, cell.lighting)
    renderer.scene.set_pose(T_cam_marker, cell.size_mm)
    render_seed = cell.seed_sequence(config.seed).generate_state(1)[0]
    t0 = time.perf_counter()
    rendered = renderer.render(window, seed=int(render_seed) % (1 << 31))
    return CellRender(window, rendered, T_cam_marker, time.perf_counter() - t0)


def clean_radiance(
    config: StudyConfig, render: CellRender, lighting_name: str, n: int, rng: np.random.Generator
) -> np.ndarray:
    """Linear RGB radiance of the crop: (H, W, 3), or (n, H, W, 3) under a canopy (a new leaf
    shadow position per image, drawn from ``rng``)."""
    from renderers.fisheye import canopy_visibility

    _, canopy = renderer_for(config, lighting_name)
    if canopy is None:
        return render.rendered.radiance()
    lighting = get_lighting(lighting_name)
    return render.rendered.radiance(canopy_visibility(canopy, lighting, render.rendered, n, rng))


def camera_images(
    config: StudyConfig,
    profile: CameraProfile,
    lighting_name: str,
    irradiance: np.ndarray,
    origin_px: tuple[int, int],
    n_images: int,
    rng: np.random.Generator,
) -> np.ndarray:
    """The camera's 8-bit grey images of a crop's sensor irradiance: (N, H, W) uint8.

    ``irradiance`` is (H, W, 3), drawn ``n_images`` times, or (N, H, W, 3), one image each.
    """
    exposure = config.exposure * get_lighting(lighting_name).exposure
    n = 1 if irradiance.ndim == 4 else n_images
    return sensor_images(irradiance, profile, rng, n, origin_px, exposure)


class _Draws:
    """A cell's camera images at one PSF scale, batch after batch, as the study draws them: an
    unshadowed crop's optics run once for every batch; under a canopy each image has its own
    shadow, so the optics run per batch. Keeps the time spent in optics and sensor."""

    def __init__(self, config: StudyConfig, render: CellRender, cell: Cell, scale: float):
        self.config, self.render, self.lighting = config, render, cell.lighting
        self.profile = config.camera.with_psf_scale(scale)
        self.rng = np.random.default_rng(cell.seed_sequence(config.seed, scale))
        self.origin = (render.window.x0, render.window.y0)
        self.optics_s = self.sensor_s = 0.0
        self.steady = None
        if not get_lighting(cell.lighting).canopy:
            t0 = time.perf_counter()
            self.steady = optical_image(render.rendered.radiance(), self.profile, self.origin)
            self.optics_s += time.perf_counter() - t0

    def draw(self, n: int) -> np.ndarray:
        """The next ``n`` images: (n, H, W) uint8."""
        t0 = time.perf_counter()
        irradiance = self.steady
        if irradiance is None:
            radiance = clean_radiance(self.config, self.render, self.lighting, n, self.rng)
            irradiance = optical_image(radiance, self.profile, self.origin)
        t1 = time.perf_counter()
        images = camera_images(
            self.config, self.profile, self.lighting, irradiance, self.origin, n, self.rng
        )
        self.optics_s += t1 - t0
        self.sensor_s += time.perf_counter() - t1
        return images


def cell_images(
    config: StudyConfig, cell: Cell, n_images: int, psf_scale: float = 1.0
) -> tuple[np.ndarray, object, np.ndarray]:
    """A cell's first ``n_images`` camera images as the study draws them, in one call:
    ((N, H, W) uint8, the crop's window, T_cam_marker)."""
    render = render_cell(config, cell)
    images = _Draws(config, render, cell, psf_scale).draw(n_images)
    return images, render.window, render.T_cam_marker


def _next_count(n: int, cap: int) -> int:
    return min(cap, next((s for s in IMAGE_STEPS if s > n), cap))


def settled(k: int, n: int) -> bool:
    """Whether k detections in n images place the rate's Wilson interval off THRESHOLD (the
    summary's ``decided`` column, by the same rule)."""
    return bool(excludes_threshold(*wilson_interval(k, n)))


def run_cell(
    config: StudyConfig,
    cell: Cell,
    out_dir: Path,
    psf_scales: tuple[float, ...] | None = None,
    save_images: bool = False,
) -> dict:
    """Compute one cell at each PSF scale and write ``cells/<key>_x<scale>.parquet``
    atomically; return stage timings (s), the images each scale used and its detection rate."""
    scales = config.psf_scales if psf_scales is None else psf_scales
    render = render_cell(config, cell)
    origin = (render.window.x0, render.window.y0)
    lens = config.camera.lens
    T_gt = render.T_cam_marker
    gt = lens.project(transform_points(T_gt, marker_corners_marker(cell.size_mm)))
    timings = {"render_s": render.render_s, "optics_s": 0.0, "sensor_s": 0.0, "detect_s": 0.0}
    used, rates = {}, {}
    for scale in scales:
        draws = _Draws(config, render, cell, scale)
        pose_scale = scale == config.nominal_psf_scale
        rows: list[dict] = []
        k = 0
        while len(rows) < config.images and not (rows and settled(k, len(rows))):
            images = draws.draw(_next_count(len(rows), config.images) - len(rows))
            t0 = time.perf_counter()
            for image in images:
                pose = pose_scale and len(rows) < POSE_IMAGES
                row = _score_image(config, cell, image, origin, gt, T_gt, pose)
                row["image_index"] = len(rows)
                if save_images:
                    path = Path("images") / cell.output_name(scale) / f"{len(rows):04d}.png"
                    write_bytes(out_dir / path, cv2.imencode(".png", image)[1].tobytes())
                    row["image_path"] = str(path)
                k += row["id_ok"]
                rows.append(row)
            timings["detect_s"] += time.perf_counter() - t0
        timings["optics_s"] += draws.optics_s
        timings["sensor_s"] += draws.sensor_s
        table = pd.DataFrame(rows)
        for name, value in reversed(list(dataclasses.asdict(cell).items())):
            table.insert(0, name, value)
        table.insert(1, "psf_scale", scale)
        with atomic_path(out_dir / "cells" / f"{cell.output_name(scale)}.parquet") as tmp:
            table.to_parquet(tmp, index=False)
        used[cell.output_name(scale)] = len(rows)
        rates[scale] = k / len(rows)
    timings["images"] = used
    timings["rates"] = rates
    return timings


def _score_image(
    config: StudyConfig,
    cell: Cell,
    image: np.ndarray,
    origin: tuple[int, int],
    gt: np.ndarray,
    T_gt: np.ndarray,
    pose: bool = True,
) -> dict:
    """Detect once, refine the corners both ways, pose and compare: one row of images.parquet.

    Without ``pose`` (the band's other PSF scales and images past POSE_IMAGES, which measure
    detection only) the corner and pose columns stay NaN: refining and posing cost five times
    the detection."""
    lens = config.camera.lens
    row: dict = {f"gt_{a}{k}_px": gt[k, i] for k in range(4) for i, a in enumerate("xy")}
    detections = detect_markers(image, config.detector, origin)
    match = [d for d in detections if d.marker_id == config.marker_id]
    row.update(detected=bool(detections), id_ok=bool(match), n_detections=len(detections))
    nan = float("nan")
    for r in REFINEMENTS:
        row.update({f"det_{a}{k}_px_{r}": nan for k in range(4) for a in "xy"})
        row.update(
            {f"{m}_{r}": nan for m in ("corner_err_px", "rot_err_deg", "trans_err_mm")}
            | {f"ambiguity_ratio_{r}": nan}
        )
    if not (match and pose):
        return row
    modules = int(get_dictionary(config.dictionary).markerSize) + 2
    corners = {"subpix": match[0].corners_px}
    corners["lines"] = refine_corners_by_edges(
        image,
        corners["subpix"],
        lens,
        modules,
        origin,
        transfer=config.camera.processing.transfer,
    )
    for r, c in corners.items():
        row.update({f"det_{a}{k}_px_{r}": c[k, i] for k in range(4) for i, a in enumerate("xy")})
        row[f"corner_err_px_{r}"] = float(np.linalg.norm(c - gt, axis=1).mean())
        try:
            est = estimate_pose(c, cell.size_mm, lens)
        except ValueError:
            continue
        row[f"rot_err_deg_{r}"] = rotation_angle_deg(est.T_cam_marker[:3, :3], T_gt[:3, :3])
        row[f"trans_err_mm_{r}"] = float(np.linalg.norm(est.T_cam_marker[:3, 3] - T_gt[:3, 3]))
        row[f"ambiguity_ratio_{r}"] = est.ambiguity_ratio
    return row
