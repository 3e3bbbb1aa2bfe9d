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
import math
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
from tqdm import tqdm  # noqa: E402

from bench.common.atomic import atomic_path  # noqa: E402
from bench.study.cells import (  # noqa: E402
    Cell,
    StudyConfig,
    camera_images,
    clean_radiance,
    init_worker,
    render_cell,
)
from pipeline.detect import detect_markers  # noqa: E402
from pipeline.pose import estimate_pose  # noqa: E402
from pipeline.presets import PipelineConfig  # noqa: E402
from renderers.camera_twin import optical_image  # noqa: E402
from scenes.conventions import (  # noqa: E402
    marker_corners_marker,
    rotation_angle_deg,
    transform_points,
)
from scenes.lighting import get_lighting  # noqa: E402
from scenes.marker import MarkerSpec, check_dictionary  # noqa: E402
from scenes.profile import CameraProfile, load_profile  # noqa: E402
from scenes.study import MAX_PHI_DEG  # noqa: E402
from scenes.validation import FieldError  # noqa: E402

AXES = ("alpha_deg", "phi_deg", "lighting", "blur_px", "read_noise_e")
NUMERIC_AXES = ("alpha_deg", "phi_deg", "blur_px", "read_noise_e")
#: Recall at or above this is "detected" (SPEC 4's 95 % of the images).
RECALL_OK = 0.95
#: Margin (px) of the rendered crop around the marker's carrier, as in the detectability study;
#: a motion-blurred crop gets half the blur length more so the smear stays inside it.
CROP_MARGIN_PX = 16


class SweepConfigError(FieldError):
    """A bad sweep setting; ``field`` names the SweepConfig field it concerns."""


@dataclass(frozen=True)
class SweepConfig:
    """The base point, the levels of each axis, and how many seeds and images per level."""

    # --- base point
    base_alpha_deg: float = 40.0
    base_phi_deg: float = 30.0
    base_lighting: str = "sun"
    base_blur_px: float = 0.0
    size_mm: float = 13.2
    distance_mm: float = 200.0
    dictionary: str = "4x4_50"
    marker_id: int = 0
    #: The camera twin; its ``sensor.read_noise_e`` is the base point's, the noise axis replaces it.
    camera: CameraProfile = field(default_factory=lambda: load_profile("prototype"))
    # --- axes: each varies one thing from the base point
    alphas_deg: tuple[float, ...] = (
        0.0, 20.0, 40.0, 60.0, 70.0, 80.0, 85.0, 88.0, 90.0, 91.0, 92.0
    )  # fmt: skip
    alpha_axis_phi_deg: float = 0.0
    phis_deg: tuple[float, ...] = (
        0.0, 10.0, 20.0, 30.0, 35.0, 40.0, 45.0, 50.0, 55.0, 60.0, 70.0
    )  # fmt: skip
    lightings: tuple[str, ...] = ("lab", "sun", "backlit", "canopy")
    blur_px: tuple[float, ...] = (0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 8.0)
    read_noise_e: tuple[float, ...] = (3.0, 50.0, 100.0, 150.0, 200.0, 250.0, 300.0, 400.0)
    # --- repetition
    seeds: int = 5
    images: int = 20
    spp: int = 16

    def __post_init__(self) -> None:
        def fail(name: str, message: str) -> None:
            raise SweepConfigError(name, message)

        for name in ("alphas_deg", "phis_deg", "blur_px", "read_noise_e"):
            try:
                values = tuple(float(v) for v in getattr(self, name))
            except (TypeError, ValueError):
                fail(name, f"{getattr(self, name)!r}: must be a sequence of numbers")
            if not values:
                fail(name, "needs at least one level")
            if not all(math.isfinite(v) for v in values):
                fail(name, f"{list(values)}: every level must be finite")
            if len(set(values)) != len(values):
                fail(name, f"{list(values)}: levels must be distinct")
            object.__setattr__(self, name, values)
        lightings = (self.lightings,) if isinstance(self.lightings, str) else self.lightings
        object.__setattr__(self, "lightings", tuple(lightings))
        if not self.lightings:
            fail("lightings", "needs at least one lighting")
        if len(set(self.lightings)) != len(self.lightings):
            fail("lightings", f"{list(self.lightings)}: lightings must be distinct")
        for name, value in [("lightings", n) for n in self.lightings] + [
            ("base_lighting", self.base_lighting)
        ]:
            try:
                get_lighting(value)
            except ValueError as exc:
                fail(name, str(exc))
        for name in ("base_alpha_deg", "base_phi_deg", "base_blur_px", "alpha_axis_phi_deg"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | float | np.number):
                fail(name, f"{value!r}: must be a number")
            object.__setattr__(self, name, float(value))

        if not isinstance(self.camera, CameraProfile):
            fail("camera", f"{self.camera!r}: must be a CameraProfile")
        theta_max = self.camera.lens.theta_max_deg
        for name, values in (
            ("alphas_deg", self.alphas_deg),
            ("base_alpha_deg", (self.base_alpha_deg,)),
        ):
            if any(not 0 <= a <= theta_max for a in values):
                fail(name, f"{_show(values)}: allowed range is 0..{theta_max:g} deg (theta_max)")
        for name, values in (
            ("phis_deg", self.phis_deg),
            ("base_phi_deg", (self.base_phi_deg,)),
            ("alpha_axis_phi_deg", (self.alpha_axis_phi_deg,)),
        ):
            if any(not 0 <= p <= MAX_PHI_DEG for p in values):
                fail(name, f"{_show(values)}: allowed range is 0..{MAX_PHI_DEG:g} deg")
        for name, values in (
            ("blur_px", self.blur_px),
            ("base_blur_px", (self.base_blur_px,)),
            ("read_noise_e", self.read_noise_e),
        ):
            if any(not (math.isfinite(v) and v >= 0) for v in values):
                fail(name, f"{_show(values)}: every value must be a finite number >= 0")
        for name in ("size_mm", "distance_mm"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
                fail(name, f"{value!r}: must be a number > 0 mm")
        for name in ("seeds", "images", "spp"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 1:
                fail(name, f"{value!r}: must be an integer >= 1")
        try:
            object.__setattr__(self, "dictionary", check_dictionary(self.dictionary))
            MarkerSpec(self.dictionary, self.marker_id, self.size_mm)
        except ValueError as exc:
            fail("dictionary", str(exc))

    def to_json(self) -> dict:
        out = dataclasses.asdict(self)
        out["camera"] = self.camera.to_json()
        return out

    def points(self) -> list[SweepPoint]:
        """Every (axis, level) of the sweep as the scene and sensor it describes."""
        base = {
            "lighting": self.base_lighting,
            "alpha_deg": self.base_alpha_deg,
            "phi_deg": self.base_phi_deg,
            "blur_px": self.base_blur_px,
            "read_noise_e": float(self.camera.sensor.read_noise_e),
        }
        # A blurred crop is wider by half the smear; the blur axis renders one crop big enough
        # for its longest smear, shared by its levels.
        base_margin = CROP_MARGIN_PX + math.ceil(self.base_blur_px / 2)
        blur_margin = CROP_MARGIN_PX + math.ceil(max(self.blur_px) / 2)
        points = []
        for axis, levels in (
            ("alpha_deg", self.alphas_deg),
            ("phi_deg", self.phis_deg),
            ("lighting", self.lightings),
            ("blur_px", self.blur_px),
            ("read_noise_e", self.read_noise_e),
        ):
            for level in levels:
                values = dict(base, **{axis: level})
                if axis == "alpha_deg":
                    values["phi_deg"] = self.alpha_axis_phi_deg
                margin = blur_margin if axis == "blur_px" else base_margin
                points.append(SweepPoint(axis, level, margin_px=margin, **values))
        return points


#: A smoke-test sweep (``whiskerbench compare --quick``): two or three levels per axis, 2 seeds.
QUICK_SWEEP = SweepConfig(
    alphas_deg=(0.0, 60.0, 90.0),
    phis_deg=(0.0, 40.0, 60.0),
    lightings=("sun", "canopy"),
    blur_px=(0.0, 4.0),
    read_noise_e=(3.0, 200.0),
    seeds=2,
    images=6,
    spp=4,
)


@dataclass(frozen=True)
class SweepPoint:
    """One (axis, level): the marker pose, lighting, blur and noise it is rendered with."""

    axis: str
    level: float | str
    lighting: str
    alpha_deg: float
    phi_deg: float
    blur_px: float
    read_noise_e: float
    margin_px: int

    @property
    def render_key(self) -> tuple:
        """Points with the same key share one clean render (per seed)."""
        return (self.lighting, self.alpha_deg, self.phi_deg, self.margin_px)


def _show(values: Iterable[float]) -> str:
    values = list(values)
    return f"{values[0]:g}" if len(values) == 1 else str(values)


# --- Motion blur ----------------------------------------------------------------------------


def motion_kernel(length_px: float) -> np.ndarray:
    """Weights of a horizontal box of ``length_px``, sampled on whole pixels: (2m + 1,) float32.

    Tap ``k`` (offset ``k - m`` px) gets the overlap of pixel ``[k - m - 0.5, k - m + 0.5]`` with
    the box ``[-L/2, L/2]``, divided by ``L``: an odd whole ``L`` gives ``L`` equal taps, an even
    one ``L - 1`` full taps and a half tap at each end. The box is centred, so the blurred marker
    sits at its mid-exposure position (the ground truth). ``L <= 1`` is no blur: ``[1]``.
    """
    if not (math.isfinite(length_px) and length_px >= 0):
        raise ValueError(f"length_px={length_px!r}: must be a finite number >= 0")
    if length_px <= 1:
        return np.ones(1, np.float32)
    half = length_px / 2
    m = math.ceil(half - 0.5)
    k = np.arange(-m, m + 1, dtype=float)
    overlap = np.clip(np.minimum(k + 0.5, half) - np.maximum(k - 0.5, -half), 0.0, None)
    return (overlap / length_px).astype(np.float32)


def motion_blur(radiance: np.ndarray, length_px: float) -> np.ndarray:
    """Horizontal motion blur of linear radiance: the scene moves ``length_px`` px along image x
    during the exposure (a box of that length, :func:`motion_kernel`), so it belongs before the
    camera response (noise is added after the light is integrated).

    ``radiance``: (..., H, W, C) float, any leading axes (e.g. N canopy images); image edges are
    extended by their last pixel. Returns the same shape, float32.
    """
    weights = motion_kernel(length_px)
    if len(weights) == 1:
        return radiance
    m = len(weights) // 2
    width = radiance.shape[-2]
    pad = [(0, 0)] * radiance.ndim
    pad[-2] = (m, m)
    padded = np.pad(np.asarray(radiance, np.float32), pad, mode="edge")
    out = np.zeros(radiance.shape, np.float32)
    for k, w in enumerate(weights):
        out += w * padded[..., k : k + width, :]
    return out


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


# --- Reading the table ------------------------------------------------------------------------


def boundaries(table: pd.DataFrame, threshold: float = RECALL_OK) -> pd.DataFrame:
    """Where recall falls below ``threshold``, per (pipeline, axis); one row each.

    Numeric axes all get harder as the value grows (and their smallest level is the easy end),
    so each is walked upward from its smallest level: ``last_ok`` is the last level before the
    first level whose mean recall over seeds is below ``threshold`` (NaN if the first level
    already fails), ``first_fail`` that level (NaN if none fails). ``fail_min``, ``fail_max``,
    ``fail_std`` are the per-seed recall at ``first_fail`` (std over seeds, ddof 0).
    ``stable``: every seed is on the same side of ``threshold`` as the mean at both levels
    (all >= at ``last_ok``, all < at ``first_fail``; a missing level is not checked).
    ``recovers``: some level past ``first_fail`` has a mean recall >= ``threshold`` again
    (the boundary is not a single crossing).

    On the categorical lighting axis ``failing`` lists the lightings with mean recall below
    ``threshold`` (config order), and ``stable`` says every seed agrees with the mean on every
    lighting. ``failing`` is given for numeric axes too (all failing levels).
    """
    rows = []
    for (pipeline, axis), part in table.groupby(["pipeline", "axis"], sort=False):
        numeric = axis in NUMERIC_AXES
        per_level = part.groupby("level", sort=False)["recall"]
        stats = pd.DataFrame(
            {
                "mean": per_level.mean(),
                "min": per_level.min(),
                "max": per_level.max(),
                "std": per_level.std(ddof=0),
            }
        )
        if numeric:
            values = part.groupby("level", sort=False)["level_value"].first()
            stats = stats.assign(value=values).sort_values("value")
        ok = stats["mean"] >= threshold
        agree = np.where(ok, stats["min"] >= threshold, stats["max"] < threshold)
        row = {
            "pipeline": pipeline,
            "axis": axis,
            "last_ok": float("nan"),
            "first_fail": float("nan"),
            "fail_min": float("nan"),
            "fail_max": float("nan"),
            "fail_std": float("nan"),
            "stable": bool(agree.all()),
            "recovers": False,
            "failing": ",".join(stats.index[~ok.to_numpy()]),
        }
        if numeric:
            failing = np.flatnonzero(~ok.to_numpy())
            if len(failing):
                i = int(failing[0])
                first = stats.iloc[i]
                row.update(
                    first_fail=first["value"],
                    fail_min=first["min"],
                    fail_max=first["max"],
                    fail_std=first["std"],
                    recovers=bool(ok.to_numpy()[i + 1 :].any()),
                )
                checked = [i] if i == 0 else [i - 1, i]
                row["last_ok"] = stats["value"].iloc[i - 1] if i > 0 else float("nan")
            else:
                checked = [len(stats) - 1]
                row["last_ok"] = stats["value"].iloc[-1]
            row["stable"] = bool(agree[checked].all())
        rows.append(row)
    out = pd.DataFrame(rows)
    order = {
        "axis": {a: i for i, a in enumerate(AXES)},
        "pipeline": {n: i for i, n in enumerate(dict.fromkeys(table["pipeline"]))},
    }
    return out.sort_values(
        ["pipeline", "axis"], key=lambda c: c.map(order[c.name]), kind="stable"
    ).reset_index(drop=True)


_AXIS_LABELS = {
    "alpha_deg": "alpha (deg), phi 0",
    "phi_deg": "phi (deg)",
    "lighting": "lighting",
    "blur_px": "motion blur (px)",
    "read_noise_e": "read noise (e-)",
}


def plot_sweeps(table: pd.DataFrame, path: Path) -> None:
    """One PNG: recall (top) and median rotation error (bottom, log) against each axis.

    One colour per pipeline: the line is the mean over seeds, the dots each seed's value, so
    the seed spread is visible; the dashed line is the 95 % recall threshold. Written
    atomically.
    """
    pipelines = list(dict.fromkeys(table["pipeline"]))
    colours = {p: plt.get_cmap("tab10")(i % 10) for i, p in enumerate(pipelines)}
    axes_present = [a for a in AXES if a in set(table["axis"])]
    fig, grid = plt.subplots(
        2, len(axes_present), figsize=(3.3 * len(axes_present), 6.2), dpi=110, squeeze=False
    )
    for c, axis in enumerate(axes_present):
        part = table[table["axis"] == axis]
        if axis == "lighting":
            categories = list(dict.fromkeys(part["level"]))
            x_of = {name: float(i) for i, name in enumerate(categories)}
            x = part["level"].map(x_of)
        else:
            x = part["level_value"]
        part = part.assign(x=x.to_numpy())
        spread = 0.012 * (part["x"].max() - part["x"].min() or 1.0)
        for k, pipeline in enumerate(pipelines):
            mine = part[part["pipeline"] == pipeline]
            if mine.empty:
                continue
            # Dots are nudged apart per pipeline; mean lines are not (a shifted steep line would
            # show a boundary where there is none); equal lines stay visible as they narrow.
            nudge = (k - (len(pipelines) - 1) / 2) * spread
            width = 1.0 + 2.2 * (len(pipelines) - 1 - k) / max(len(pipelines) - 1, 1)
            style = "o" if axis == "lighting" else "-"  # categories are not joined by lines
            for r, column in enumerate(("recall", "rot_err_deg")):
                ax = grid[r, c]
                mean = mine.groupby("x")[column].mean().sort_index()
                label = pipeline if (r, c) == (0, 0) else None
                ax.plot(mean.index, mean.to_numpy(), style, color=colours[pipeline], lw=width,
                        ms=2 + 1.5 * width, mfc="none", label=label)  # fmt: skip
                ax.plot(mine["x"] + nudge, mine[column], ".", color=colours[pipeline], ms=3,
                        alpha=0.55)  # fmt: skip
        top, bottom = grid[0, c], grid[1, c]
        top.axhline(RECALL_OK, color="k", ls="--", lw=0.8)
        top.set_ylim(-0.03, 1.03)
        top.set_title(_AXIS_LABELS.get(axis, axis), fontsize=9)
        bottom.set_yscale("log")
        bottom.set_xlabel(_AXIS_LABELS.get(axis, axis), fontsize=8)
        if axis == "lighting":
            for ax in (top, bottom):
                ax.set_xticks(range(len(categories)), categories, fontsize=8)
        for ax in (top, bottom):
            ax.tick_params(labelsize=7)
            ax.grid(alpha=0.3, lw=0.5)
    grid[0, 0].set_ylabel("recall")
    grid[1, 0].set_ylabel("median rotation error (deg)")
    grid[0, 0].legend(fontsize=7, loc="lower left")
    fig.suptitle("recall and pose error per axis: line = mean over seeds, dots = seeds", fontsize=9)
    fig.tight_layout()
    with atomic_path(Path(path)) as tmp:
        fig.savefig(tmp, format="png")
    plt.close(fig)
