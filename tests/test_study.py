"""The detectability study end to end on a tiny grid: outputs, determinism, resume, crashes,
adaptive image counts, tilt refinement and the PSF band."""

import json

import pandas as pd
import pytest

from bench.study import cells
from bench.study.cells import settled
from bench.study.config import IMAGE_STEPS, Cell, StudyConfig, StudyConfigError
from bench.study.run import _refinement_cells, run_study

# A coarse tilt resolution keeps the refinement to one round on this grid.
TINY = dict(
    sizes_mm=(13.2,), alphas_deg=(0.0, 85.0), phis_deg=(0.0, 60.0), images=6,
    phi_resolution_deg=30.0,
)  # fmt: skip


def run(tmp_path, name="run", **kwargs):
    config = StudyConfig(**{**TINY, **kwargs})
    out = tmp_path / name
    return config, out, run_study(config, out, progress=False)


@pytest.fixture(scope="session")
def tiny_study(tmp_path_factory, worker_id, variant):
    """The TINY study, run once per test run with its figures drawn: read, never written (the
    tests that write into it take a copy, :func:`tiny_copy`)."""
    from conftest import built_once

    def build(out):
        run_study(StudyConfig(**TINY), out, progress=False)

    return built_once(tmp_path_factory, worker_id, "tiny-study", build)


def tiny_copy(tiny_study, tmp_path):
    """A copy of the shared TINY study to write into: (config, folder, its manifest)."""
    import shutil

    out = tmp_path / "run"
    shutil.copytree(tiny_study, out)
    return StudyConfig(**TINY), out, json.loads((out / "manifest.json").read_text())


@pytest.mark.slow
def test_outputs(variant, tiny_study):
    config, out = StudyConfig(**TINY), tiny_study
    for name in (
        "images.parquet",
        "summary.csv",
        "max_phi.csv",
        "max_phi_by_scale.csv",
        "max_phi.png",
        "heatmap.png",
        "pose_error.png",
        "manifest.json",
        "config.json",
    ):
        assert (out / name).stat().st_size > 0, name
    images = pd.read_parquet(out / "images.parquet")
    grid = images[images.phi_deg.isin(config.phis_deg)]
    assert len(grid) == 4 * 6
    for column in (
        "size_mm", "alpha_deg", "phi_deg", "lighting", "psf_scale", "image_index", "detected",
        "id_ok", "gt_x0_px", "gt_y3_px", "det_x0_px_lines", "det_y3_px_subpix",
        "corner_err_px_lines", "corner_err_px_subpix", "rot_err_deg_lines", "trans_err_mm_subpix",
        "ambiguity_ratio_lines",
    ):  # fmt: skip
        assert column in images.columns, column
    frontal = images[(images.alpha_deg == 0) & (images.phi_deg == 0)]
    assert frontal.id_ok.all() and (frontal.corner_err_px_lines < 1.0).all()
    assert set(images.detector) == {"opencv"} and not images.backend_failed.any()
    summary = pd.read_csv(out / "summary.csv")
    assert set(summary.detector) == {"opencv"} and (summary.backend_failures == 0).all()
    assert {"rate_lo", "rate_hi", "detection_rate", "decided"} <= set(summary.columns)
    assert {"trans_err_mm_lines_p95", "trans_err_mm_subpix_max"} <= set(summary.columns)
    assert (summary.rate_lo <= summary.detection_rate).all()
    assert len(pd.read_csv(out / "max_phi.csv")) == 2
    written = json.loads((out / "manifest.json").read_text())
    assert written["variant"] == variant and written["seed"] == 0
    assert written["camera_profile"] == "prototype" and written["backend_failures"] == {}
    assert (written["detector"], written["family"]) == ("opencv", "4x4_50")
    assert written["versions"]["mitsuba"] and written["images_per_s"] > 0
    assert set(written["wall_s"]) >= {"cells_s", "tables_s", "plots_s", "total_s"}
    assert sum(written["images_per_cell"].values()) == len(images) == written["images_total"]
    assert not list(out.rglob("*.tmp*"))


def test_crops_start_on_the_mjpeg_block_grid(variant):
    config = StudyConfig(**TINY)
    assert config.camera.crop_grid_px == 16
    renderer = cells.study_renderer(config)
    render = cells.render_cell(renderer, Cell("sun", 13.2, 40.0, 30.0), 0, 200.0, 16)
    w = render.window
    assert w.x0 % 16 == 0 and w.y0 % 16 == 0 and w.width % 16 == 0


@pytest.mark.slow
@pytest.mark.usefixtures("figures_not_drawn")  # the tables are the answer; drawn in test_outputs
def test_same_seed_same_summary_other_seed_other_images(variant, tiny_study, tmp_path):
    a = tiny_study  # another run of the same config (in another process under xdist)
    _, b, _ = run(tmp_path, "b")
    _, c, _ = run(tmp_path, "c", seed=1)
    assert (a / "summary.csv").read_bytes() == (b / "summary.csv").read_bytes()
    pa, pc = (pd.read_parquet(x / "images.parquet") for x in (a, c))
    assert not pa.corner_err_px_lines.equals(pc.corner_err_px_lines)


@pytest.mark.slow
@pytest.mark.usefixtures("figures_not_drawn")  # the tables are the answer; drawn in test_outputs
def test_resume_skips_finished_cells_and_gives_the_same_answer(variant, tiny_study, tmp_path):
    config, out, first = tiny_copy(tiny_study, tmp_path)
    summary = (out / "summary.csv").read_bytes()
    (out / "cells" / f"{config.cells()[1].output_name(1.0)}.parquet").unlink()
    second = run_study(config, out, progress=False)
    assert second["cells_computed"] == 1
    assert second["cells_resumed"] == first["cells_total"] - 1
    assert (out / "summary.csv").read_bytes() == summary


@pytest.mark.slow
@pytest.mark.usefixtures("figures_not_drawn")  # the tables are the answer; drawn in test_outputs
def test_a_crash_leaves_no_half_written_file_and_the_rerun_finishes(variant, tmp_path, monkeypatch):
    config = StudyConfig(**TINY)
    out = tmp_path / "crash"
    real, calls = cells.run_cell, []

    def crash_on_third(*args, **kwargs):
        calls.append(1)
        if len(calls) == 3:
            raise KeyboardInterrupt
        return real(*args, **kwargs)

    monkeypatch.setattr("bench.study.run.run_cell", crash_on_third)
    with pytest.raises(KeyboardInterrupt):
        run_study(config, out, progress=False)
    assert len(list((out / "cells").glob("*.parquet"))) == 2
    assert not (out / "summary.csv").exists() and not list(out.rglob("*.tmp*"))
    monkeypatch.setattr("bench.study.run.run_cell", real)
    manifest = run_study(config, out, progress=False)
    assert manifest["cells_resumed"] == 2 and (out / "summary.csv").exists()


@pytest.mark.slow
def test_another_config_in_the_same_folder_is_refused(variant, tiny_study, tmp_path):
    _, out, _ = tiny_copy(tiny_study, tmp_path)
    with pytest.raises(StudyConfigError, match="another configuration"):
        run_study(StudyConfig(**{**TINY, "images": 7}), out, progress=False)


@pytest.mark.slow
@pytest.mark.usefixtures("figures_not_drawn")  # not a test of figures: test_outputs
def test_save_images(variant, tmp_path):
    config = StudyConfig(**{**TINY, "alphas_deg": (0.0,), "phis_deg": (0.0,), "images": 3})
    out = tmp_path / "saved"
    run_study(config, out, save_images=True, progress=False)
    images = pd.read_parquet(out / "images.parquet")
    assert all((out / p).stat().st_size > 0 for p in images.image_path)


@pytest.mark.parametrize("field, value", [("sizes_mm", (13.2, 13.2)), ("psf_scales", (1, 1.0))])
def test_a_value_listed_twice_is_refused(field, value):
    with pytest.raises(StudyConfigError, match="listed twice") as info:
        StudyConfig(**{**TINY, field: value})
    assert info.value.field == field


@pytest.mark.parametrize("images", [True, 0, 2.5, 10**9])
def test_an_image_count_that_is_no_count_is_refused(images):
    with pytest.raises(StudyConfigError, match="must be an integer in 1") as info:
        StudyConfig(**{**TINY, "images": images})
    assert info.value.field == "images"


def test_wilson_settles_a_cell_at_the_first_count_that_excludes_095():
    assert settled(0, IMAGE_STEPS[0])  # never detected: settled after the first batch
    assert not settled(30, 30) and not settled(72, 72) and settled(73, 73) and settled(80, 80)
    assert not settled(152, 160)  # 0.95 inside the interval: keep drawing


@pytest.mark.slow
@pytest.mark.usefixtures("figures_not_drawn")  # not a test of figures: test_outputs
def test_adaptive_sampling_stops_when_settled(variant, tmp_path):
    """A sharp frontal 13.2 mm marker is always found: 80 images settle it; a marker past the
    image circle's reach is never found: 10 do."""
    config, out, manifest = run(
        tmp_path, images=240, alphas_deg=(0.0,), phis_deg=(0.0, 85.0), psf_scales=(0.0,)
    )
    used = manifest["images_per_cell"]
    assert used[Cell("sun", 13.2, 0.0, 0.0).output_name(0.0)] == 80
    assert used[Cell("sun", 13.2, 0.0, 85.0).output_name(0.0)] == 10


def test_refinement_bisects_between_the_last_pass_and_the_first_fail():
    config = StudyConfig(**{**TINY, "phi_resolution_deg": 2.5})
    rates = pd.DataFrame(
        {
            "lighting": "sun", "psf_scale": [1.0] * 4 + [0.5] * 2, "size_mm": 13.2,
            "alpha_deg": 0.0, "phi_deg": [0.0, 10.0, 20.0, 30.0, 0.0, 10.0],
            "rate": [1.0, 1.0, 0.96, 0.2, 1.0, 1.0],
        }
    )  # fmt: skip
    plan = _refinement_cells(config, rates)
    assert plan == [(Cell("sun", 13.2, 0.0, 25.0), (1.0,))]  # scale 0.5 passes all: censored
    rates.loc[len(rates)] = ["sun", 1.0, 13.2, 0.0, 25.0, 0.5]
    rates.loc[len(rates)] = ["sun", 1.0, 13.2, 0.0, 22.5, 0.99]
    assert _refinement_cells(config, rates) == []  # 22.5 -> 25: within 2.5 deg


@pytest.mark.slow
@pytest.mark.usefixtures("figures_not_drawn")  # not a test of figures: test_outputs
def test_band_renders_each_geometry_once_for_every_scale(variant, tmp_path, monkeypatch):
    real, renders = cells.render_cell, []

    def counting(*args, **kwargs):
        renders.append(args[1])
        return real(*args, **kwargs)

    monkeypatch.setattr("bench.study.cells.render_cell", counting)
    config, out, manifest = run(
        tmp_path, alphas_deg=(0.0,), phis_deg=(0.0,), psf_scales=(0.5, 1.0, 1.5)
    )
    assert len(renders) == 1
    band = pd.read_csv(out / "max_phi.csv")
    assert {"band_lo_deg", "band_hi_deg"} <= set(band.columns)
    assert set(pd.read_parquet(out / "images.parquet").psf_scale) == {0.5, 1.0, 1.5}


def test_crop_frames_every_visible_marker_corner_even_past_90_degrees():
    """At alpha 92 the carrier's far vertices are past theta_max while the marker's corners are
    not: framed by its vertices alone the crop missed corners; framed by points along its
    edges it holds them all."""
    import numpy as np

    from renderers.window import Window
    from scenes.camera import default_camera
    from scenes.conventions import marker_corners_marker, transform_points
    from scenes.marker import MarkerSpec, carrier_mesh, carrier_outline
    from scenes.study import study_pose

    camera, spec = default_camera(), MarkerSpec("4x4_50", 0, 13.2)
    T = study_pose(92.0, 0.0, 200.0)
    vertices = camera.project(transform_points(T, carrier_mesh(spec).vertices))
    assert np.isnan(vertices).any()  # the case the outline is for
    window = Window.around(camera.project(carrier_outline(T, spec)), camera)
    corners = camera.project(transform_points(T, marker_corners_marker(13.2)))
    assert np.isfinite(corners).all()
    by_vertices = Window.around(vertices, camera)
    assert (corners[:, 0] >= by_vertices.x0 + by_vertices.width).any()  # the old crop cut it
    assert (corners[:, 0] >= window.x0).all() and (corners[:, 0] < window.x0 + window.width).all()
    assert (corners[:, 1] >= window.y0).all() and (corners[:, 1] < window.y0 + window.height).all()


def test_reading_each_code_cell_with_more_pixels_recovers_a_blurred_marker(variant):
    """Under the literature-derived blur (1.12 px on the axis, the prototype's table before its
    calibration) OpenCV's default 4 px per code cell misreads bits of a legible 13.2 mm marker
    at alpha 60; reading 8 px per cell finds it in every image."""
    from pipeline.detect import DetectorConfig, detect_markers

    prototype = StudyConfig(**TINY).camera
    blurred = prototype.with_psf_scale(1.12 / prototype.psf.sigma_radial_px[0])
    config = StudyConfig(**{**TINY, "camera": blurred})
    renderer = cells.study_renderer(config)
    images, window, _ = cells.cell_images(config, Cell("sun", 13.2, 60.0, 0.0), renderer, 20)
    found = {
        px: sum(
            any(d.marker_id == 0 for d in detect_markers(im, det, (window.x0, window.y0)))
            for im in images
        )
        for px, det in ((4, DetectorConfig(cell_px=4)), (8, DetectorConfig(cell_px=8)))
    }
    assert found[8] == len(images) > found[4]


def test_cell_px_option_is_validated():
    from bench.cli.main import main

    assert main(["detectability", "--cell-px", "1", "--out", "/nonexistent/never"]) == 2
