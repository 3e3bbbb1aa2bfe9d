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
    (:func:`motion_blur`);
``read_noise_e``
    sensor noise, as the rms read noise (electrons) of the camera profile's well.

Images come from the camera twin (``camera``, a :class:`scenes.profile.CameraProfile`, default
``prototype``): the motion blur acts on the clean radiance, then the profile's optics, sensor
and stream stages run, the read noise replaced by the point's.

Each distinct crop is rendered once per seed (:func:`clean_render`, composed from
:mod:`bench.study.cells`'s renderer and seeds), ``images`` camera images are drawn from it
and every pipeline gets the same images. A seed fixes the render's jitter and the noise through
:meth:`bench.detectability.Cell.seed_sequence`, so a seed's images at a point do not depend on
the rest of the grid; the levels of the blur and the noise axes share one render and one noise
draw per seed, so that only the level differs between them.

:func:`run_sweeps` gives one row per (axis, level, seed, pipeline), :func:`boundaries` reads off
where recall falls below 95 % and whether the seeds agree, :func:`plot_sweeps` draws it all.

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
import json

import matplotlib

from bench.evaluate.sweep_config import NUMERIC_AXES, SweepConfig, SweepPoint  # noqa: E402
from renderers.motion_blur import motion_blur  # noqa: E402

matplotlib.use("Agg")
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
from tqdm import tqdm  # noqa: E402

from bench.study.cells import (  # noqa: E402
    camera_images,
    clean_radiance,
    init_worker,
    render_cell,
)
from bench.study.config import Cell, StudyConfig  # noqa: E402
from pipeline.detect import detect_markers  # noqa: E402
from pipeline.pose import estimate_pose  # noqa: E402
from pipeline.presets import PipelineConfig  # noqa: E402
from renderers.camera_twin import optical_image  # noqa: E402
from scenes.conventions import (  # noqa: E402
    marker_corners_marker,
    rotation_angle_deg,
    transform_points,
)

# --- Rendering --------------------------------------------------------------------------------


def _study(config: SweepConfig) -> StudyConfig:
    """The detectability study's config for the sweep's marker: its renderer cache and seeds."""
    return StudyConfig(
        sizes_mm=(config.size_mm,),
        alphas_deg=(config.base_alpha_deg,),
        phis_deg=(config.base_phi_deg,),
        images=config.images,
        distance_mm=config.distance_mm,
        lightings=(config.base_lighting,),
        dictionary=config.dictionary,
        marker_id=config.marker_id,
        spp=config.spp,
        camera=config.camera,
    )


def clean_render(config: SweepConfig, point: SweepPoint, seed: int) -> dict:
    """The clean linear radiance of one point's crop, before any camera stage.

    The study's pose, crop (with ``point.margin_px``), renderer and seeds
    (:func:`bench.detectability.render_cell`); a sweep needs the radiance itself because motion
    blur acts on it before the optics. Returns ``window``, ``radiance`` ((H, W, 3), or
    (N, H, W, 3) under a canopy, one shadow position per image), ``rng`` (the noise generator,
    already advanced past the canopy draws: copy it for each set of images) and
    ``T_cam_marker``.
    """
    study = _study(config)
    cell = Cell(point.lighting, config.size_mm, point.alpha_deg, point.phi_deg)
    render = render_cell(study, cell, margin_px=point.margin_px)
    rng = np.random.default_rng(cell.seed_sequence(seed).generate_state(2)[1])
    radiance = clean_radiance(study, render, point.lighting, config.images, rng)
    return {
        "window": render.window,
        "radiance": radiance,
        "rng": rng,
        "T_cam_marker": render.T_cam_marker,
    }


# --- Scoring ----------------------------------------------------------------------------------


def score_images(
    pipeline: PipelineConfig,
    images: np.ndarray,
    offset_px: tuple[int, int],
    T_gt: np.ndarray,
    config: SweepConfig,
) -> dict:
    """Detect and pose the marker in each image; the summary row of one pipeline.

    ``images``: (N, H, W) uint8 crops whose top-left pixel is ``offset_px`` in the full frame.
    Ground truth and errors as in :mod:`bench.study.cells`: an image's corner error is the mean
    over the 4 corners of the distance (px) to the projected true corner; medians are over the
    images where the right id was found (pose errors: where the pose could also be solved).
    """
    camera = config.camera.lens
    gt_px = camera.project(transform_points(T_gt, marker_corners_marker(config.size_mm)))
    hits = false_ids = pose_failures = 0
    corner_err, rot_err, trans_err = [], [], []
    for image in images:
        detections = detect_markers(image, pipeline.detector, offset_px, camera=camera)
        match = [d for d in detections if d.marker_id == config.marker_id]
        false_ids += len(detections) - len(match)
        if not match:
            continue
        hits += 1
        corners = match[0].corners_px
        corner_err.append(float(np.linalg.norm(corners - gt_px, axis=1).mean()))
        try:
            pose = estimate_pose(corners, config.size_mm, camera, pipeline.pose_method)
        except ValueError:
            pose_failures += 1
            continue
        if not np.isfinite(pose.T_cam_marker).all():  # IPPE can return NaN without raising
            pose_failures += 1
            continue
        rot_err.append(rotation_angle_deg(pose.T_cam_marker[:3, :3], T_gt[:3, :3]))
        trans_err.append(float(np.linalg.norm(pose.T_cam_marker[:3, 3] - T_gt[:3, 3])))

    def median(values: list[float]) -> float:
        return float(np.median(values)) if values else float("nan")

    return {
        "images": len(images),
        "recall": hits / len(images),
        "false_ids": false_ids,
        "corner_err_px": median(corner_err),
        "rot_err_deg": median(rot_err),
        "trans_err_mm": median(trans_err),
        "pose_failures": pose_failures,
    }


def run_sweeps(
    pipelines: list[PipelineConfig],
    config: SweepConfig,
    variant: str | None = None,
    progress: bool = True,
) -> pd.DataFrame:
    """Every pipeline at every (axis, level, seed): one row each.

    Columns: ``axis``, ``level`` (str: ``f"{value:g}"`` or the lighting's name), ``level_value``
    (float; NaN on the lighting axis), ``seed`` (0 .. seeds-1), ``pipeline`` (its name),
    ``images``, ``recall`` (images where the right id was found / images), ``false_ids``
    (detections of any other id, summed over the images), ``corner_err_px``, ``rot_err_deg``,
    ``trans_err_mm`` (medians, :func:`score_images`) and ``pose_failures`` (right id found but
    no pose: :func:`pipeline.pose.estimate_pose` raised, e.g. ``pose_method="fisheye"`` at or
    past 90 deg, or returned a non-finite pose). ``table.attrs["sweep_config"]``
    holds the config and pipelines as JSON.

    Each distinct crop is rendered once per seed (points sharing a render: the blur and noise
    levels, and the base point met on several axes) and every pipeline sees the same images.
    """
    pipelines = list(pipelines)
    if not pipelines:
        raise ValueError("pipelines: need at least one pipeline")
    names = [p.name for p in pipelines]
    if len(set(names)) != len(names):
        raise ValueError(f"pipelines: names must be distinct, got {names}")
    pipelines = [
        dataclasses.replace(
            p, detector=dataclasses.replace(p.detector, dictionary=config.dictionary)
        )
        for p in pipelines
    ]
    init_worker(variant)

    points = config.points()
    point_index = {p: i for i, p in enumerate(points)}
    groups: dict[tuple, list[SweepPoint]] = {}
    for point in points:
        groups.setdefault(point.render_key, []).append(point)
    jobs = [(seed, points) for seed in range(config.seeds) for points in groups.values()]

    study = _study(config)
    rows = []
    for seed, group in tqdm(jobs, desc="sweep renders", unit="render", disable=not progress):
        clean = clean_render(config, group[0], seed)
        window = clean["window"]
        origin = (window.x0, window.y0)
        for point in group:
            profile = dataclasses.replace(
                config.camera,
                sensor=dataclasses.replace(config.camera.sensor, read_noise_e=point.read_noise_e),
            )
            irradiance = optical_image(
                motion_blur(clean["radiance"], point.blur_px), profile, origin
            )
            images = camera_images(
                study,
                profile,
                point.lighting,
                irradiance,
                origin,
                config.images,
                copy.deepcopy(clean["rng"]),  # the same noise draw for every level sharing it
            )
            numeric = point.axis in NUMERIC_AXES
            for pipeline in pipelines:
                row = score_images(
                    pipeline, images, (window.x0, window.y0), clean["T_cam_marker"], config
                )
                rows.append(
                    {
                        "point": point_index[point],
                        "axis": point.axis,
                        "level": f"{point.level:g}" if numeric else point.level,
                        "level_value": float(point.level) if numeric else float("nan"),
                        "seed": seed,
                        "pipeline": pipeline.name,
                        **row,
                    }
                )
    # Rows in the config's order: axis, level, then pipeline (as given) and seed.
    table = pd.DataFrame(rows)
    table["pipeline_index"] = table["pipeline"].map({n: i for i, n in enumerate(names)})
    table = table.sort_values(["point", "pipeline_index", "seed"], kind="stable")
    table = table.drop(columns=["point", "pipeline_index"]).reset_index(drop=True)
    table.attrs["sweep_config"] = json.dumps(
        {"config": config.to_json(), "pipelines": [p.to_json() for p in pipelines]}, default=str
    )
    return table
