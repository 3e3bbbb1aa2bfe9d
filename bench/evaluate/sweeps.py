"""One-axis sweeps: where each pipeline variant stops detecting the array's marker.

From a base point (the array's 13.2 mm marker 200 mm away at alpha 40 deg, tilted phi 30 deg, in
``sun``, no motion blur, the camera profile's own read noise) one thing at a time is varied:

``alpha_deg``
    angular position in the field of view, the marker facing the camera (``alpha_axis_phi_deg``,
    default 0, as in the first column of the SPEC 4 study);
``phi_deg``
    tilt about both in-plane axes (:func:`scenes.study.study_pose`) at the base alpha;
``lighting``
    the lighting presets (categorical);
``blur_px``
    motion blur: the marker moves ``L`` px horizontally in the image during the exposure
    (:func:`renderers.motion_blur.motion_blur`);
``read_noise_e``
    sensor noise, as the rms read noise (electrons) of the camera profile's well;
``psf_scale``
    lens sharpness: the profile's PSF widths times each level of its band
    (:meth:`scenes.profile.Band.psf_levels`, or only the band's ends), so the axis follows the
    profile when it is recalibrated. The base point's PSF is ``base_psf_scale`` (1: the table as
    calibrated, also for a profile written at another scale, e.g. a dataset's ``camera.json``).

Images come from the camera twin (``camera``, a :class:`scenes.profile.CameraProfile`, default
``prototype``): the motion blur acts on the clean radiance, then the profile's optics, sensor
and stream stages run, the read noise and the PSF scale replaced by the point's.

The PSF is applied after the render, so the lens-sharpness levels share the base point's render
and noise draw: only the lens differs between them. The other axes are read again with the base
point's PSF at the band's ends (:meth:`~bench.evaluate.sweep_config.SweepConfig.band_end_sweeps`)
to see whether a pipeline's lead at the nominal PSF holds across the band.

Each distinct crop is rendered once per seed (:func:`clean_render`: the study's
:func:`~bench.study.cells.render_cell` with one :class:`~renderers.marker_renderer.MarkerRenderer`
for the whole sweep), ``images`` camera images are drawn from it and every pipeline gets the
same images, scored as the study scores them (:mod:`bench.common.marker_score`). A seed fixes
the noise and the canopy's shadows through :meth:`bench.study.config.Cell.seed_sequence` (the
render's jitter is :data:`RENDER_SEED`'s for every seed), so a seed's images at a point do not
depend on the rest of the grid; the levels of the blur and the noise axes share one render and
one noise draw per seed, so that only the level differs between them (so do the
lens-sharpness levels, with the base point's).

:func:`run_sweeps` gives one row per (axis, level, seed, pipeline);
:func:`bench.evaluate.sweep_report.boundaries` reads off where recall falls below 95 % and
whether the seeds agree, :func:`bench.evaluate.sweep_report.plot_sweeps` draws it all.

The default levels were set after a first run with the presets (5 seeds x 20 images):

* alpha: 0..92 deg. On the ``ideal`` camera (image circle to 95 deg) no preset loses the marker
  while it is inside the image circle (93 deg still detected); at 94 deg its far edge (alpha +
  1.9 deg) is past theta_max and every preset fails: a failure of geometry, not of the
  detector. The prototype's image circle ends at 92.5 deg, so the levels now stop at 92. What
  differs along alpha is the pose: ``pose_method="fisheye"`` fails from 90 deg on.
* phi: 35, 45 and 55 added to resolve the two boundaries (``fast`` 35 -> 40, the others
  50 -> 55).
* blur: the first levels (4..32 px) were all failures from 4 px on; the marker's modules are
  2.2 mm, about 7 px at the base point, and a smear of 4-5 px erases its code. Levels are now
  0..6 and 8 px. 4 px is about 0.4 deg of motion in one exposure: plausible for a whisker that
  is brushed.
* read noise: nothing is detected above about 400 e- (the first levels 800 and 1600 were all
  zero), so the levels are 3..300 in steps of 50 and 400. Recall falls below 95 % near
  200 e- rms (3.3 % of full scale). That is not a real read noise (this sensor class has a
  few e-): the upper levels stand for the total noise of a dim scene at high gain.
* lighting: unchanged; ``backlit`` and ``canopy`` fail for ``fast`` only.
"""

from __future__ import annotations

import copy
import dataclasses
from dataclasses import dataclass

import numpy as np
import pandas as pd

from bench.common.executor import TaskPool, effective_executor
from bench.common.marker_score import MarkerTruth, score_corners
from bench.evaluate.sweep_config import NUMERIC_AXES, SweepConfig, SweepPoint
from bench.study.cells import CellRender, camera_images, render_cell
from bench.study.config import Cell
from pipeline.backends import BackendCrashError, BackendError, require
from pipeline.detect import detect_markers
from pipeline.presets import PipelineConfig
from renderers.camera_twin import optical_image
from renderers.marker_renderer import MarkerRenderer
from renderers.motion_blur import motion_blur
from renderers.variant import init_worker
from scenes.camera import FisheyeCamera
from scenes.conventions import rotation_angle_deg
from scenes.lighting import get_lighting

#: The run seed of every sweep render's jitter: each seed's crop is rendered with seed 0's
#: jitter (as the sweeps always have); a sweep seed draws the noise and the canopy's shadows.
RENDER_SEED = 0

# --- Rendering --------------------------------------------------------------------------------


def clean_render(
    config: SweepConfig, renderer: MarkerRenderer, point: SweepPoint, seed: int
) -> tuple[CellRender, np.ndarray, np.random.Generator]:
    """The clean linear radiance of one point's crop, before any camera stage.

    The study's pose, crop (with ``point.margin_px``) and render
    (:func:`bench.study.cells.render_cell`); a sweep needs the radiance itself because motion
    blur acts on it before the optics. Returns the render, its radiance ((H, W, 3), or
    (N, H, W, 3) under a canopy, one shadow position per image) and the noise generator,
    already advanced past the canopy draws: copy it for each set of images.
    """
    cell = Cell(point.lighting, config.size_mm, point.alpha_deg, point.phi_deg)
    grid_px = config.camera.crop_grid_px
    render = render_cell(
        renderer, cell, RENDER_SEED, config.distance_mm, grid_px, margin_px=point.margin_px
    )
    rng = np.random.default_rng(cell.seed_sequence(seed).generate_state(2)[1])
    radiance = renderer.radiance(point.lighting, render.rendered, config.images, rng)
    return render, radiance, rng


# --- Scoring ----------------------------------------------------------------------------------


#: The per-image errors :func:`score_images` gives as medians, in its columns' order.
_MEDIANS = (
    "corner_err_px", "rot_err_deg", "trans_err_mm", "own_rot_err_deg", "own_trans_err_mm"
)  # fmt: skip


def score_images(
    pipeline: PipelineConfig,
    images: np.ndarray,
    origin_px: tuple[int, int],
    truth: MarkerTruth,
    lens: FisheyeCamera,
) -> dict:
    """Detect and pose the marker in each image; the summary row of one pipeline.

    ``images``: (N, H, W) uint8 crops whose top-left pixel is ``origin_px`` in the full frame.
    Errors as in the study (:mod:`bench.common.marker_score`); medians are over the images
    where the right id was found (pose errors: where the pose could also be solved). The
    backend's own pose, where it has one, is scored beside the project's (``own_*``; NaN for
    OpenCV). An image on which the backend crashes (:class:`BackendCrashError`) or fails
    (:class:`BackendError`: a plugin that raises or answers outside its contract) is counted in
    ``backend_failures`` and left out of ``recall``: it is neither found nor missed, and the
    other pipelines' sweeps go on.
    """
    hits = false_ids = pose_failures = failures = 0
    errors: dict[str, list[float]] = {k: [] for k in _MEDIANS}
    for image in images:
        try:
            detections = detect_markers(image, pipeline.detector, origin_px, lens, truth.size_mm)
        except (BackendCrashError, BackendError):
            failures += 1
            continue
        match = [d for d in detections if d.marker_id == truth.marker_id]
        false_ids += len(detections) - len(match)
        if not match:
            continue
        hits += 1
        own = match[0].own_T_cam_marker
        if own is not None and np.isfinite(own).all():
            T_gt = truth.T_cam_marker
            errors["own_rot_err_deg"].append(rotation_angle_deg(own[:3, :3], T_gt[:3, :3]))
            errors["own_trans_err_mm"].append(float(np.linalg.norm(own[:3, 3] - T_gt[:3, 3])))
        scored, posed = score_corners(match[0].corners_px, truth, lens, pipeline.pose_method)
        errors["corner_err_px"].append(scored["corner_err_px"])
        if not posed:
            pose_failures += 1
            continue
        errors["rot_err_deg"].append(scored["rot_err_deg"])
        errors["trans_err_mm"].append(scored["trans_err_mm"])
    seen = len(images) - failures
    return {
        "images": len(images),
        "recall": hits / seen if seen else float("nan"),
        "false_ids": false_ids,
        **{k: float(np.median(v)) if v else float("nan") for k, v in errors.items()},
        "pose_failures": pose_failures,
        "backend_failures": failures,
    }


@dataclass(frozen=True)
class _SweepTask:
    """One render of a sweep (a seed and the points sharing its crop), scored by every pipeline."""

    config: SweepConfig
    pipelines: tuple[PipelineConfig, ...]
    seed: int
    group: tuple[SweepPoint, ...]
    indices: tuple[int, ...]  # of the group's points in config.points()


def _sweep_worker(variant: str, threads: int | None, config: SweepConfig) -> MarkerRenderer:
    """A sweep worker's context: its renderer, built once."""
    init_worker(variant, threads)
    return MarkerRenderer(config.camera.lens, config.dictionary, config.marker_id, config.spp)


def _sweep_task(task: _SweepTask, renderer: MarkerRenderer) -> list[dict]:
    """The rows of one render: every point of the group, every pipeline."""
    config, lens = task.config, task.config.camera.lens
    render, radiance, rng = clean_render(config, renderer, task.group[0], task.seed)
    origin = (render.window.x0, render.window.y0)
    truth = MarkerTruth.of(lens, config.marker_id, config.size_mm, render.T_cam_marker)
    rows = []
    for index, point in zip(task.indices, task.group, strict=True):
        profile = config.camera.at_psf_scale(point.psf_scale)
        profile = dataclasses.replace(
            profile, sensor=dataclasses.replace(profile.sensor, read_noise_e=point.read_noise_e)
        )
        irradiance = optical_image(motion_blur(radiance, point.blur_px), profile, origin)
        images = camera_images(
            profile,
            irradiance,
            origin,
            config.images,
            copy.deepcopy(rng),  # the same noise draw for every level sharing it
            get_lighting(point.lighting).exposure,
        )
        numeric = point.axis in NUMERIC_AXES
        for pipeline in task.pipelines:
            row = score_images(pipeline, images, origin, truth, lens)
            rows.append(
                {
                    "point": index,
                    "axis": point.axis,
                    "level": f"{point.level:g}" if numeric else point.level,
                    "level_value": float(point.level) if numeric else float("nan"),
                    "psf_scale": point.psf_scale,
                    "seed": task.seed,
                    "pipeline": pipeline.name,
                    **row,
                }
            )
    return rows


def sweep_pipelines(pipelines: list[PipelineConfig], config: SweepConfig) -> list[PipelineConfig]:
    """The pipelines as the sweep runs them, the sweep's family replacing each one's.

    Refused before any rendering: an empty or ambiguous list, or a pipeline whose backend
    cannot detect the family (ValueError, one line), a peer not installed
    (:class:`pipeline.backends.BackendUnavailableError`, saying how to install it).
    """
    pipelines = list(pipelines)
    if not pipelines:
        raise ValueError("pipelines: need at least one pipeline")
    names = [p.name for p in pipelines]
    if len(set(names)) != len(names):
        raise ValueError(f"pipelines: names must be distinct, got {names}")
    out = []
    for p in pipelines:
        try:
            p = p.with_family(config.dictionary)
        except ValueError as exc:
            raise ValueError(f"pipeline {p.name!r} in the sweeps: {exc}") from None
        for backend in p.backends:
            require(backend)
        out.append(p)
    return out


def run_sweeps(
    pipelines: list[PipelineConfig],
    config: SweepConfig,
    variant: str | None = None,
    progress: bool = True,
    workers: int = 1,
    executor: str = "pool",
    scheduler: str | None = None,
) -> pd.DataFrame:
    """Every pipeline at every (axis, level, seed): one row each.

    Columns: ``axis``, ``level`` (str: ``f"{value:g}"`` or the lighting's name), ``level_value``
    (float; NaN on the lighting axis), ``psf_scale`` (the images' PSF: the level on the
    ``psf_scale`` axis, the base point's elsewhere), ``seed`` (0 .. seeds-1), ``pipeline`` (its
    name), ``images``, ``recall`` (images where the right id was found / images the backend did not
    crash on), ``false_ids`` (detections of any other id, summed over the images),
    ``corner_err_px``, ``rot_err_deg``, ``trans_err_mm``, ``own_rot_err_deg``,
    ``own_trans_err_mm`` (medians, :func:`score_images`; ``own_*``: the backend's own pose, NaN
    for OpenCV), ``pose_failures`` (right id found but no pose:
    :func:`pipeline.pose.estimate_pose` raised, e.g. ``pose_method="fisheye"`` at or past
    90 deg, or returned a non-finite pose) and ``backend_failures`` (images the backend crashed
    on). The pipelines are checked first (:func:`sweep_pipelines`). The config goes to a file
    beside the table (:func:`bench.evaluate.sweep_report.write_sweeps`).

    Each distinct crop is rendered once per seed (points sharing a render: the blur, noise
    and PSF levels, and the base point met on several axes) and every pipeline sees the same images.
    Each (seed, crop) is a task on ``executor`` (:class:`~bench.common.executor.TaskPool`).
    """
    pipelines = sweep_pipelines(pipelines, config)
    names = [p.name for p in pipelines]
    chosen = init_worker(variant)
    inline = effective_executor(executor, workers, scheduler) == "inline"
    points = config.points()
    point_index = {p: i for i, p in enumerate(points)}
    groups: dict[tuple, list[SweepPoint]] = {}
    for point in points:
        groups.setdefault(point.render_key, []).append(point)
    tasks = [
        _SweepTask(config, tuple(pipelines), seed, tuple(g), tuple(point_index[p] for p in g))
        for seed in range(config.seeds)
        for g in groups.values()
    ]
    setup_args = (chosen, None if inline else 1, config)
    rows = []
    with TaskPool(workers, _sweep_worker, setup_args, executor, scheduler) as pool:
        for part in pool.map(_sweep_task, tasks, "sweep renders", progress, unit="render"):
            rows += part
    # Rows in the config's order: axis, level, then pipeline (as given) and seed.
    table = pd.DataFrame(rows)
    table["pipeline_index"] = table["pipeline"].map({n: i for i, n in enumerate(names)})
    table = table.sort_values(["point", "pipeline_index", "seed"], kind="stable")
    table = table.drop(columns=["point", "pipeline_index"]).reset_index(drop=True)
    return table
