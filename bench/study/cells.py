"""The marker detectability study (SPEC section 4) on a camera twin, one independent task per cell.

A cell is (lighting, size, alpha, phi). Its noise-free colour radiance is rendered once, as a crop
around the marker: the detector only ever looks at the marker and its surroundings, and the rest
of the frame changes nothing it sees (``whiskerbench bench detectability`` measures the saving
against full frames). The crop starts on the camera's MJPEG block grid, so its blocks and Bayer
phase are those of the full frame. For each PSF scale of the sensitivity band the profile's
optics are applied once, and camera images are then drawn from its sensor and stream stages
adaptively: in batches until the Wilson interval of the detection rate excludes 0.95 or the cap
``images`` is reached (a cell that never detects is settled after 10 images, a perfect one after
80). Each image is detected once (by default OpenCV with ``subpix`` corners, as the original
system used; ``--detector`` a peer with its ``own`` corners) and its corners refined again with
the project's ``lines``; both are posed and scored (at the nominal PSF scale, on a cell's first
:data:`POSE_IMAGES` images; the band's other scales and the images beyond measure detection
only; :mod:`bench.common.marker_score`, shared with the sweeps). An image on which a peer's
worker crashes (:class:`~pipeline.backends.BackendCrashError`) is a row with ``backend_failed``
set: neither detected nor missed, it counts towards the cap but not towards the detection rate.
A cell's rows are written atomically to ``cells/<key>_x<scale>.parquet``, with its record
(``.json`` beside it: settings and content hash, :mod:`bench.common.units`), so an interrupted
study resumes where it stopped and a damaged cell is computed again. Every cell a process runs
is handed the same :class:`~renderers.marker_renderer.MarkerRenderer` (:func:`init_study_worker`).
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import cv2
import numpy as np
import pandas as pd

from bench.common.atomic import atomic_path, write_bytes
from bench.common.manifest import sha256
from bench.common.marker_score import MarkerTruth, find_marker, score_corners
from bench.common.units import unit_state, write_unit
from bench.study.config import IMAGE_STEPS, POSE_IMAGES, Cell, StudyConfig
from bench.study.report import METRICS, excludes_threshold, refinements_of, wilson_interval
from pipeline.backends import BackendCrashError
from pipeline.refine import refine_corners_by_edges
from renderers.camera_twin import optical_image, sensor_images
from renderers.marker_renderer import MarkerRenderer
from renderers.variant import init_worker
from renderers.window import Window
from scenes.lighting import get_lighting
from scenes.marker import get_dictionary
from scenes.profile import CameraProfile
from scenes.study import study_pose

if TYPE_CHECKING:
    from renderers.fisheye import RenderedWindow


def study_renderer(config: StudyConfig) -> MarkerRenderer:
    """The renderer of the study's marker, lens and samples per pixel (scenes load lazily)."""
    return MarkerRenderer(config.camera.lens, config.dictionary, config.marker_id, config.spp)


def init_study_worker(
    config: StudyConfig, variant: str | None, threads: int | None = None
) -> MarkerRenderer:
    """A study worker's set-up (:class:`~bench.common.executor.TaskPool`'s ``setup``): the
    Mitsuba variant, then the renderer that every cell the worker runs is handed."""
    init_worker(variant, threads)
    return study_renderer(config)


@dataclass
class CellRender:
    """A cell's clean crop: its window, the render and the marker's true pose."""

    window: Window
    rendered: RenderedWindow
    T_cam_marker: np.ndarray
    render_s: float


def render_seed(cell: Cell, seed: int) -> int:
    """The seed of a cell's render jitter: one per cell, shared by its PSF scales."""
    return int(cell.seed_sequence(seed).generate_state(1)[0]) % (1 << 31)


def render_cell(
    renderer: MarkerRenderer,
    cell: Cell,
    seed: int,
    distance_mm: float,
    grid_px: int,
    margin_px: int = 16,
    full_frame: bool = False,
) -> CellRender:
    """Render a cell's clean crop once, framed by the carrier and aligned to the block grid
    (``grid_px``); ``seed`` is the run's, the cell derives its own (:func:`render_seed`).
    ``full_frame``: the whole frame instead (the fidelity ladder's reference)."""
    T_cam_marker = study_pose(cell.alpha_deg, cell.phi_deg, distance_mm)
    if full_frame:
        window = Window.full(renderer.lens)
    else:
        window = renderer.crop(T_cam_marker, cell.size_mm, grid_px, margin_px)
    t0 = time.perf_counter()
    rendered = renderer.render(
        cell.lighting, T_cam_marker, cell.size_mm, window, render_seed(cell, seed)
    )
    return CellRender(window, rendered, T_cam_marker, time.perf_counter() - t0)


def camera_images(
    profile: CameraProfile,
    irradiance: np.ndarray,
    origin_px: tuple[int, int],
    n_images: int,
    rng: np.random.Generator,
    exposure: float,
) -> np.ndarray:
    """The camera's 8-bit grey images of a crop's sensor irradiance: (N, H, W) uint8.

    ``irradiance`` is (H, W, 3), drawn ``n_images`` times, or (N, H, W, 3), one image each.
    ``exposure``: linear radiance to sensor full scale (the lighting preset's included).
    """
    n = 1 if irradiance.ndim == 4 else n_images
    return sensor_images(irradiance, profile, rng, n, origin_px, exposure)


class CellDraws:
    """A cell's camera images at one PSF scale, batch after batch, as the study draws them: an
    unshadowed crop's optics run once for every batch; under a canopy each image has its own
    shadow, so the optics run per batch. Keeps the time spent in optics and sensor."""

    def __init__(
        self,
        config: StudyConfig,
        renderer: MarkerRenderer,
        render: CellRender,
        cell: Cell,
        scale: float,
        rng: np.random.Generator | None = None,
    ):
        """``rng``: the noise stream; the cell's own for this scale by default."""
        self.renderer, self.render, self.lighting = renderer, render, cell.lighting
        self.exposure = config.exposure * get_lighting(cell.lighting).exposure
        self.profile = config.camera.with_psf_scale(scale)
        if rng is None:
            rng = np.random.default_rng(cell.seed_sequence(config.seed, scale))
        self.rng = rng
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
            radiance = self.renderer.radiance(self.lighting, self.render.rendered, n, self.rng)
            irradiance = optical_image(radiance, self.profile, self.origin)
        t1 = time.perf_counter()
        images = camera_images(self.profile, irradiance, self.origin, n, self.rng, self.exposure)
        self.optics_s += t1 - t0
        self.sensor_s += time.perf_counter() - t1
        return images


def _render(config: StudyConfig, cell: Cell, renderer: MarkerRenderer) -> CellRender:
    return render_cell(renderer, cell, config.seed, config.distance_mm, config.camera.crop_grid_px)


def cell_images(
    config: StudyConfig,
    cell: Cell,
    renderer: MarkerRenderer,
    n_images: int,
    psf_scale: float = 1.0,
) -> tuple[np.ndarray, Window, np.ndarray]:
    """A cell's first ``n_images`` camera images as the study draws them, in one call:
    ((N, H, W) uint8, the crop's window, T_cam_marker)."""
    render = _render(config, cell, renderer)
    images = CellDraws(config, renderer, render, cell, psf_scale).draw(n_images)
    return images, render.window, render.T_cam_marker


def next_count(n: int, cap: int) -> int:
    """The next cumulative image count of the adaptive draws (:data:`IMAGE_STEPS`), capped."""
    return min(cap, next((s for s in IMAGE_STEPS if s > n), cap))


def settled(k: int, n: int) -> bool:
    """Whether k detections in n images place the rate's Wilson interval off THRESHOLD (the
    summary's ``decided`` column, by the same rule)."""
    return bool(excludes_threshold(*wilson_interval(k, n)))


def run_cell(
    config: StudyConfig,
    cell: Cell,
    renderer: MarkerRenderer,
    out_dir: Path,
    psf_scales: tuple[float, ...] | None = None,
    save_images: bool = False,
    render: CellRender | None = None,
) -> dict:
    """Compute one cell at each PSF scale and write ``cells/<key>_x<scale>.parquet``
    atomically; return stage timings (s), the images each scale used and its detection rate.
    ``render``: the cell's render when the caller has it (the fidelity ladder draws several
    camera profiles from one); rendered here without."""
    scales = config.psf_scales if psf_scales is None else psf_scales
    render = _render(config, cell, renderer) if render is None else render
    origin = (render.window.x0, render.window.y0)
    truth = MarkerTruth.of(config.camera.lens, config.marker_id, cell.size_mm, render.T_cam_marker)
    timings = {"render_s": render.render_s, "optics_s": 0.0, "sensor_s": 0.0, "detect_s": 0.0}
    used, rates = {}, {}
    for scale in scales:
        draws = CellDraws(config, renderer, render, cell, scale)
        pose_scale = scale == config.nominal_psf_scale
        rows: list[dict] = []
        k = scored = 0  # right ids, and images the detector did not crash on
        while len(rows) < config.images and not (scored and settled(k, scored)):
            images = draws.draw(next_count(len(rows), config.images) - len(rows))
            t0 = time.perf_counter()
            for image in images:
                pose = pose_scale and len(rows) < POSE_IMAGES
                row = _score_image(config, image, origin, truth, pose)
                row["image_index"] = len(rows)
                if save_images:
                    path = Path("images") / cell.output_name(scale) / f"{len(rows):04d}.png"
                    write_bytes(out_dir / path, cv2.imencode(".png", image)[1].tobytes())
                    row["image_path"] = str(path)
                k += row["id_ok"]
                scored += not row["backend_failed"]
                rows.append(row)
            timings["detect_s"] += time.perf_counter() - t0
        timings["optics_s"] += draws.optics_s
        timings["sensor_s"] += draws.sensor_s
        table = pd.DataFrame(rows)
        for name, value in reversed(list(dataclasses.asdict(cell).items())):
            table.insert(0, name, value)
        table.insert(1, "psf_scale", scale)
        write_cell(out_dir, config, cell.output_name(scale), table)
        used[cell.output_name(scale)] = len(rows)
        rates[scale] = k / scored if scored else float("nan")
    timings["images"] = used
    timings["rates"] = rates
    return timings


def cell_record(out_dir: Path, name: str) -> Path:
    """The record of the cell ``name`` (:mod:`bench.common.units`) beside its parquet."""
    return out_dir / "cells" / f"{name}.json"


def write_cell(out_dir: Path, config: StudyConfig, name: str, table: pd.DataFrame) -> None:
    """A cell's parquet and its record: the record first, with the hash of the parquet about to
    be renamed into place, so a cell file is never found without its record."""
    path = out_dir / "cells" / f"{name}.parquet"
    with atomic_path(path) as tmp:
        table.to_parquet(tmp, index=False)
        files = {path.name: sha256(tmp)}
        record = {"unit": name, "settings_sha256": config.settings_hash(), "files": files}
        write_unit(cell_record(out_dir, name), record)


def cell_state(out_dir: Path, name: str, settings_sha256: str) -> str:
    """Whether the cell ``name`` is done and intact (:func:`bench.common.units.unit_state`)."""
    return unit_state(cell_record(out_dir, name), settings_sha256, {"unit": name})


def _score_image(
    config: StudyConfig,
    image: np.ndarray,
    origin: tuple[int, int],
    truth: MarkerTruth,
    pose: bool = True,
) -> dict:
    """Detect once, refine the corners both ways, pose and compare: one row of images.parquet.

    The detector's corners are ``subpix`` (OpenCV) or ``own`` (a peer), ``lines`` refined from
    them (:func:`~bench.study.report.refinements_of`). Without ``pose`` (the band's other PSF
    scales and images past POSE_IMAGES, which measure detection only) the corner and pose
    columns stay NaN: refining and posing cost five times the detection."""
    lens = config.camera.lens
    gt = truth.corners_px
    row: dict = {f"gt_{a}{k}_px": gt[k, i] for k in range(4) for i, a in enumerate("xy")}
    lines, own = refinements_of(config.detector.backend)
    try:
        n_detections, match = find_marker(image, config.detector, origin, truth, lens)
        failed = False
    except BackendCrashError:  # neither detected nor missed: the summary counts it apart
        n_detections, match, failed = 0, [], True
    row.update(detected=bool(n_detections), id_ok=bool(match), n_detections=n_detections)
    row["backend_failed"] = failed
    nan = float("nan")
    for r in (lines, own):
        row.update({f"det_{a}{k}_px_{r}": nan for k in range(4) for a in "xy"})
        row.update({f"{m}_{r}": nan for m in METRICS})
    if not (match and pose):
        return row
    modules = int(get_dictionary(config.dictionary).markerSize) + 2
    corners = {own: match[0]}
    corners[lines] = refine_corners_by_edges(
        image,
        corners[own],
        lens,
        modules,
        origin,
        transfer=config.camera.processing.transfer,
    ).corners_px
    for r, c in corners.items():
        row.update({f"det_{a}{k}_px_{r}": c[k, i] for k in range(4) for i, a in enumerate("xy")})
        errors, _ = score_corners(c, truth, lens)
        row.update({f"{m}_{r}": v for m, v in errors.items()})
    return row
