"""Speed benchmarks: print their figures and ratios against a baseline measured in the same run.

``bench_detectability`` times the whole study as it runs (clean crop per cell, camera images
drawn from it through the camera twin until each cell is settled, the tilt refinement, every PSF
scale asked for) with each stage's CPU cost per image, and, for a few cells, the same work on
full 2592 x 1944 frames: render the full frame, apply the twin's optics and sensor stages to the
whole frame, detect on it. The full-frame cost is extrapolated to the
whole grid from those cells, and the detection rates of both routes are printed side by side,
so the reader sees what the crop saves and that it changes no answer.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

from bench.study.cells import camera_images, study_renderer
from bench.study.config import Cell, StudyConfig
from bench.study.run import run_study
from pipeline.detect import detect_markers
from renderers.camera_twin import optical_image
from renderers.marker_renderer import MarkerRenderer
from renderers.variant import init_worker
from renderers.window import Window
from scenes.lighting import get_lighting
from scenes.study import study_pose

FULL_FRAME_IMAGES = 4  # images drawn per full-frame cell (each is a 5-megapixel frame)


def _full_frame_cell(
    config: StudyConfig, renderer: MarkerRenderer, cell: Cell, n_images: int
) -> dict:
    """Render one cell as a full frame, draw ``n_images`` images, detect on full frames."""
    T = study_pose(cell.alpha_deg, cell.phi_deg, config.distance_mm)
    window = Window.full(config.camera.lens)
    t0 = time.perf_counter()
    rendered = renderer.render(cell.lighting, T, cell.size_mm, window, seed=1)
    t1 = time.perf_counter()
    irradiance = optical_image(rendered.radiance(), config.camera)
    rng = np.random.default_rng(0)
    exposure = config.exposure * get_lighting(cell.lighting).exposure
    images = camera_images(config.camera, irradiance, (0, 0), n_images, rng, exposure)
    t2 = time.perf_counter()
    found = [
        any(d.marker_id == config.marker_id for d in detect_markers(im, config.detector))
        for im in images
    ]
    t3 = time.perf_counter()
    return {
        "render_s": t1 - t0,
        "response_s_per_image": (t2 - t1) / n_images,
        "detect_s_per_image": (t3 - t2) / n_images,
        "rate": float(np.mean(found)),
    }


def bench_detectability(
    config: StudyConfig, variant: str | None = None, full_frame_cells: int = 2, workers: int = 1
) -> dict:
    """Time the study (crops) and full frames in one run; print figures and the ratio."""
    init_worker(variant)
    cells = config.cells()
    print(
        f"detectability benchmark: camera {config.camera.name}, {len(cells)} grid cells x "
        f"{len(config.psf_scales)} PSF scales, at most {config.images} images a cell, "
        f"{config.spp} spp, workers={workers}"
    )

    # --- Crops: the study as it runs, from scratch in a temporary folder
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        manifest = run_study(config, Path(tmp) / "run", variant=variant, workers=workers)
        crop_s = time.perf_counter() - t0
        crop_rates = pd.read_csv(Path(tmp) / "run" / "summary.csv")
    n_images = manifest["images_total"]
    print(
        f"  crops:       {crop_s:7.1f} s wall for the whole study, {manifest['cells_total']} "
        f"cells ({manifest['refinement_rounds']} refinement rounds), {n_images} images, "
        f"{n_images / crop_s:7.1f} images/s (variant {manifest['variant']})"
    )
    per_image = {k: v / n_images * 1e3 for k, v in manifest["stage_cpu_s"].items()}
    print(
        "  CPU per image (ms): "
        + ", ".join(f"{k.removesuffix('_s')} {v:.2f}" for k, v in per_image.items())
        + " (render and optics run once per cell and scale, shared by its images)"
    )

    # --- Full frames: a few cells, extrapolated to the grid
    # The largest marker facing the camera on the axis (detected, so that the comparison of the
    # two routes is about a detection, not two misses), then cells spread over the grid.
    frontal = min(cells, key=lambda c: (-c.size_mm, c.alpha_deg, c.phi_deg))
    spread = np.linspace(0, len(cells) - 1, max(1, full_frame_cells - 1) + 2)[1:-1]
    picks = [frontal] + [cells[int(i)] for i in spread][: max(0, full_frame_cells - 1)]
    full = []
    renderer = study_renderer(config)
    for cell in picks:
        result = _full_frame_cell(config, renderer, cell, FULL_FRAME_IMAGES)
        full.append(result)
        row = crop_rates[
            (crop_rates.size_mm == cell.size_mm)
            & (crop_rates.alpha_deg == cell.alpha_deg)
            & (crop_rates.phi_deg == cell.phi_deg)
            & (crop_rates.lighting == cell.lighting)
            & (crop_rates.psf_scale == config.nominal_psf_scale)
        ]
        print(
            f"  full frame {cell.key}: render {result['render_s']:.1f} s, per image twin "
            f"{result['response_s_per_image']:.2f} s + detect {result['detect_s_per_image']:.2f} s,"
            f" detection rate {result['rate']:.2f} (crop: {row.detection_rate.iloc[0]:.2f})"
        )
    per_cell = np.mean(
        [
            r["render_s"]
            + n_images
            / manifest["cells_total"]
            * (r["response_s_per_image"] + r["detect_s_per_image"])
            for r in full
        ]
    )
    full_s = per_cell * manifest["cells_total"]
    print(
        f"  full frames: {full_s:7.1f} s estimated for the whole study "
        f"({n_images / full_s:.2f} images/s), from {len(picks)} cells"
    )
    print(f"  ratio full-frame / crop: {full_s / crop_s:.0f}x")
    summary = {
        "images": n_images,
        "crop_wall_s": crop_s,
        "crop_images_per_s": n_images / crop_s,
        "full_frame_est_s": full_s,
        "ratio": full_s / crop_s,
        "variant": manifest["variant"],
        "cpu_ms_per_image": per_image,
    }
    return summary
