"""The marker detectability study (SPEC section 4), one independent task per cell.

A cell is (lighting, size, alpha, phi). Its noise-free image is rendered once, as a crop around
the marker: the detector only ever looks at the marker and its surroundings, and the rest of
the frame changes nothing it sees (``whiskerbench bench detectability`` measures the saving
against full frames). The cell's N images are then drawn from the camera-response model: new
sensor noise per image and, under ``canopy``, a new leaf-shadow position per image. Each image
is detected and posed, and the cell's rows are written atomically to ``cells/<key>.parquet``,
so an interrupted study resumes where it stopped.
"""

from __future__ import annotations

import dataclasses
import math
import time
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import pandas as pd

from bench.atomic import atomic_path, write_bytes
from pipeline.detect import DetectorConfig, detect_markers
from pipeline.pose import estimate_pose
from renderers.response import LUMINANCE_RGB, CameraResponse, apply_response
from scenes.camera import FisheyeCamera, default_camera
from scenes.conventions import marker_corners_marker, rotation_angle_deg, transform_points
from scenes.lighting import get_lighting
from scenes.marker import MarkerSpec, carrier_mesh, check_dictionary
from scenes.study import MAX_PHI_DEG, study_pose
from scenes.validation import FieldError

DEFAULT_SIZES_MM = (8.8, 11.0, 13.2, 17.6)
DEFAULT_ALPHAS_DEG = (0.0, 20.0, 40.0, 60.0, 70.0, 80.0, 85.0, 90.0)
DEFAULT_PHIS_DEG = tuple(float(p) for p in range(0, 80, 10))


class StudyConfigError(FieldError):
    """A bad study setting; ``field`` names the StudyConfig field it concerns."""


@dataclass(frozen=True)
class StudyConfig:
    """Everything that determines the study's numbers (and nothing that does not)."""

    sizes_mm: tuple[float, ...] = DEFAULT_SIZES_MM
    alphas_deg: tuple[float, ...] = DEFAULT_ALPHAS_DEG
    phis_deg: tuple[float, ...] = DEFAULT_PHIS_DEG
    images: int = 60
    distance_mm: float = 200.0
    lightings: tuple[str, ...] = ("sun",)
    dictionary: str = "4x4_50"
    marker_id: int = 0
    seed: int = 0
    spp: int = 16
    camera: FisheyeCamera = field(default_factory=default_camera)
    response: CameraResponse = field(default_factory=CameraResponse)
    # "lines": corners from straight border edges in a rectified view (0.02 px median error);
    # OpenCV's subpix sits ~0.4 px inside the outer corners and would dominate the pose errors.
    detector: DetectorConfig = field(
        default_factory=lambda: DetectorConfig(corner_refinement="lines")
    )

    def __post_init__(self) -> None:
        def fail(name: str, message: str) -> None:
            raise StudyConfigError(name, message)

        for name in ("sizes_mm", "alphas_deg", "phis_deg", "lightings"):
            values = tuple(getattr(self, name))
            if not values:
                fail(name, "needs at least one value")
            object.__setattr__(self, name, values)
        if any(not (math.isfinite(s) and s > 0) for s in self.sizes_mm):
            fail("sizes_mm", f"{list(self.sizes_mm)}: every size must be > 0 mm")
        theta_max = self.camera.theta_max_deg
        if any(not 0 <= a <= theta_max for a in self.alphas_deg):
            fail(
                "alphas_deg",
                f"{list(self.alphas_deg)}: allowed range is 0..{theta_max:g} deg "
                "(the camera's theta_max)",
            )
        if any(not 0 <= p <= MAX_PHI_DEG for p in self.phis_deg):
            fail("phis_deg", f"{list(self.phis_deg)}: allowed range is 0..{MAX_PHI_DEG:g} deg")
        if int(self.images) != self.images or self.images < 1:
            fail("images", f"{self.images}: must be an integer >= 1")
        if not (math.isfinite(self.distance_mm) and self.distance_mm > 0):
            fail("distance_mm", f"{self.distance_mm}: must be > 0 mm")
        for name in self.lightings:
            try:
                get_lighting(name)
            except ValueError as exc:
                fail("lightings", str(exc))
        try:
            object.__setattr__(self, "dictionary", check_dictionary(self.dictionary))
            MarkerSpec(self.dictionary, self.marker_id, self.sizes_mm[0])
        except ValueError as exc:
            fail("dictionary", str(exc))
        if self.spp < 1:
            fail("spp", f"{self.spp}: must be >= 1")
        if self.detector.dictionary != self.dictionary:
            object.__setattr__(
                self, "detector", dataclasses.replace(self.detector, dictionary=self.dictionary)
            )

    def cells(self) -> list[Cell]:
        return [
            Cell(lighting, size, alpha, phi)
            for lighting in self.lightings
            for size in self.sizes_mm
            for alpha in self.alphas_deg
            for phi in self.phis_deg
        ]

    def to_json(self) -> dict:
        return dataclasses.asdict(self)


@dataclass(frozen=True)
class Cell:
    lighting: str
    size_mm: float
    alpha_deg: float
    phi_deg: float

    @property
    def key(self) -> str:
        return f"{self.lighting}_s{self.size_mm:g}_a{self.alpha_deg:g}_p{self.phi_deg:g}"

    def seed_sequence(self, seed: int) -> np.random.SeedSequence:
        """Seeds depend on the cell itself, not on the grid around it: a cell gives the same
        images whatever else the study contains."""
        key = (
            zlib.crc32(self.lighting.encode()),
            *(round(v * 1000) for v in (self.size_mm, self.alpha_deg, self.phi_deg)),
        )
        return np.random.SeedSequence(seed, spawn_key=key)


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

    key = (lighting_name, config.dictionary, config.marker_id, config.spp, config.camera)
    if key not in _STATE:
        lighting = get_lighting(lighting_name)
        scene = MarkerScene(MarkerSpec(config.dictionary, config.marker_id, 10.0), lighting)
        canopy = CanopyScene(lighting) if lighting.canopy else None
        _STATE[key] = (FisheyeRenderer(config.camera, scene, spp=config.spp), canopy)
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


def cell_images(config: StudyConfig, cell: Cell) -> tuple[np.ndarray, object, dict]:
    """Render one cell's clean crop once and draw its N camera images: (N, H, W) uint8."""
    from renderers.fisheye import canopy_visibility
    from renderers.window import Window

    camera, lighting = config.camera, get_lighting(cell.lighting)
    T_cam_marker = study_pose(cell.alpha_deg, cell.phi_deg, config.distance_mm)
    spec = MarkerSpec(config.dictionary, config.marker_id, cell.size_mm)
    window = Window.around(camera.project(carrier_outline(T_cam_marker, spec)), camera)
    renderer, canopy = renderer_for(config, cell.lighting)
    renderer.scene.set_pose(T_cam_marker, cell.size_mm)
    render_seed, noise_seed = cell.seed_sequence(config.seed).generate_state(2)
    t0 = time.perf_counter()
    rendered = renderer.render(window, seed=int(render_seed) % (1 << 31))
    rng = np.random.default_rng(noise_seed)
    if canopy is not None:
        radiance = rendered.radiance(
            canopy_visibility(canopy, lighting, rendered, config.images, rng)
        )
    else:
        radiance = rendered.radiance()
    render_s = time.perf_counter() - t0
    images = camera_images(config, cell.lighting, rendered, radiance, config.images, rng)
    return images, window, {"T_cam_marker": T_cam_marker, "render_s": render_s}


def camera_images(
    config: StudyConfig,
    lighting_name: str,
    rendered,
    radiance: np.ndarray,
    n_images: int,
    rng: np.random.Generator,
) -> np.ndarray:
    """The 8-bit grey images the camera records of a clean render: (N, H, W) uint8.

    ``radiance`` is (H, W, 3), drawn ``n_images`` times, or (N, H, W, 3), one image each; a
    fixed exposure is scaled by the lighting preset's own.
    """
    response = config.response.scaled(get_lighting(lighting_name).exposure)
    return apply_response(
        (radiance @ LUMINANCE_RGB).astype(np.float32),
        response,
        rng,
        n_images=1 if radiance.ndim == 4 else n_images,
        theta_rad=config.camera.theta_of_pixel(rendered.window.pixel_centres()),
        theta_max_rad=config.camera.theta_max_rad,
        valid=rendered.inside,
    )


def run_cell(config: StudyConfig, cell: Cell, out_dir: Path, save_images: bool = False) -> dict:
    """Compute one cell and write ``cells/<key>.parquet`` atomically; return stage timings (s)."""
    t0 = time.perf_counter()
    images, window, truth = cell_images(config, cell)
    t1 = time.perf_counter()
    T_gt = truth["T_cam_marker"]
    gt = config.camera.project(transform_points(T_gt, marker_corners_marker(cell.size_mm)))
    rows = []
    for index, image in enumerate(images):
        row = _score_image(config, cell, image, window, gt, T_gt)
        row["image_index"] = index
        if save_images:
            path = Path("images") / cell.key / f"{index:04d}.png"
            write_bytes(out_dir / path, cv2.imencode(".png", image)[1].tobytes())
            row["image_path"] = str(path)
        rows.append(row)
    table = pd.DataFrame(rows)
    for name, value in dataclasses.asdict(cell).items():
        table.insert(0, name, value)
    target = out_dir / "cells" / f"{cell.key}.parquet"
    with atomic_path(target) as tmp:
        table.to_parquet(tmp, index=False)
    return {
        "render_s": truth["render_s"],
        "response_s": t1 - t0 - truth["render_s"],
        "detect_s": time.perf_counter() - t1,
    }


def _score_image(
    config: StudyConfig, cell: Cell, image: np.ndarray, window, gt: np.ndarray, T_gt: np.ndarray
) -> dict:
    """Detect, pose and compare against ground truth: one row of images.parquet."""
    row: dict = {f"gt_{a}{k}_px": gt[k, i] for k in range(4) for i, a in enumerate("xy")}
    detections = detect_markers(
        image, config.detector, (window.x0, window.y0), camera=config.camera
    )
    match = [d for d in detections if d.marker_id == config.marker_id]
    row.update(detected=bool(detections), id_ok=bool(match), n_detections=len(detections))
    nan = float("nan")
    row.update({f"det_{a}{k}_px": nan for k in range(4) for a in "xy"})
    row.update(corner_err_px=nan, rot_err_deg=nan, trans_err_mm=nan, ambiguity_ratio=nan)
    if match:
        corners = match[0].corners_px
        row.update({f"det_{a}{k}_px": corners[k, i] for k in range(4) for i, a in enumerate("xy")})
        row["corner_err_px"] = float(np.linalg.norm(corners - gt, axis=1).mean())
        try:
            pose = estimate_pose(corners, cell.size_mm, config.camera)
        except ValueError:
            return row
        row["rot_err_deg"] = rotation_angle_deg(pose.T_cam_marker[:3, :3], T_gt[:3, :3])
        row["trans_err_mm"] = float(np.linalg.norm(pose.T_cam_marker[:3, 3] - T_gt[:3, 3]))
        row["ambiguity_ratio"] = pose.ambiguity_ratio
    return row
