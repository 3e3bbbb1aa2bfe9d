"""The detectability study end to end on a tiny grid: outputs, determinism, resume, crashes."""

import json

import pandas as pd
import pytest

from bench import detectability
from bench.detectability import StudyConfig, StudyConfigError
from bench.study import run_study

TINY = dict(sizes_mm=(8.8,), alphas_deg=(0.0, 85.0), phis_deg=(0.0, 60.0), images=6)


def run(tmp_path, name="run", **kwargs):
    config = StudyConfig(**{**TINY, **kwargs})
    out = tmp_path / name
    return config, out, run_study(config, out, progress=False)


def test_outputs(variant, tmp_path):
    config, out, manifest = run(tmp_path)
    for name in (
        "images.parquet",
        "summary.csv",
        "max_phi.csv",
        "max_phi.png",
        "heatmap.png",
        "pose_error.png",
        "manifest.json",
        "config.json",
    ):
        assert (out / name).stat().st_size > 0, name
    images = pd.read_parquet(out / "images.parquet")
    assert len(images) == 4 * 6
    for column in (
        "size_mm",
        "alpha_deg",
        "phi_deg",
        "lighting",
        "image_index",
        "detected",
        "id_ok",
        "gt_x0_px",
        "gt_y3_px",
        "det_x0_px",
        "corner_err_px",
        "rot_err_deg",
        "trans_err_mm",
        "ambiguity_ratio",
    ):
        assert column in images.columns, column
    frontal = images[(images.alpha_deg == 0) & (images.phi_deg == 0)]
    assert frontal.id_ok.all() and (frontal.corner_err_px < 1.0).all()
    summary = pd.read_csv(out / "summary.csv")
    assert len(summary) == 4 and {"rate_lo", "rate_hi", "detection_rate"} <= set(summary.columns)
    assert (summary.rate_lo <= summary.detection_rate).all()
    assert len(pd.read_csv(out / "max_phi.csv")) == 2
    written = json.loads((out / "manifest.json").read_text())
    assert written["variant"] == variant and written["seed"] == 0
    assert written["versions"]["mitsuba"] and written["images_per_s"] > 0
    assert set(written["wall_s"]) >= {"cells_s", "tables_s", "plots_s", "total_s"}
    assert not list(out.rglob("*.tmp*"))


def test_same_seed_same_summary_other_seed_other_images(variant, tmp_path):
    _, a, _ = run(tmp_path, "a")
    _, b, _ = run(tmp_path, "b")
    _, c, _ = run(tmp_path, "c", seed=1)
    assert (a / "summary.csv").read_bytes() == (b / "summary.csv").read_bytes()
    pa, pc = (pd.read_parquet(x / "images.parquet") for x in (a, c))
    assert not pa.corner_err_px.equals(pc.corner_err_px)


def test_resume_skips_finished_cells_and_gives_the_same_answer(variant, tmp_path):
    config, out, first = run(tmp_path)
    summary = (out / "summary.csv").read_bytes()
    (out / "cells" / f"{config.cells()[1].key}.parquet").unlink()
    second = run_study(config, out, progress=False)
    assert (second["cells_computed"], second["cells_resumed"]) == (1, 3)
    assert (out / "summary.csv").read_bytes() == summary


def test_a_crash_leaves_no_half_written_file_and_the_rerun_finishes(variant, tmp_path, monkeypatch):
    config = StudyConfig(**TINY)
    out = tmp_path / "crash"
    real, calls = detectability.run_cell, []

    def crash_on_third(*args, **kwargs):
        calls.append(1)
        if len(calls) == 3:
            raise KeyboardInterrupt
        return real(*args, **kwargs)

    monkeypatch.setattr("bench.study.run_cell", crash_on_third)
    with pytest.raises(KeyboardInterrupt):
        run_study(config, out, progress=False)
    assert len(list((out / "cells").glob("*.parquet"))) == 2
    assert not (out / "summary.csv").exists() and not list(out.rglob("*.tmp*"))
    monkeypatch.setattr("bench.study.run_cell", real)
    manifest = run_study(config, out, progress=False)
    assert manifest["cells_resumed"] == 2 and (out / "summary.csv").exists()


def test_another_config_in_the_same_folder_is_refused(variant, tmp_path):
    _, out, _ = run(tmp_path)
    with pytest.raises(StudyConfigError, match="another configuration"):
        run_study(StudyConfig(**{**TINY, "images": 7}), out, progress=False)


def test_save_images(variant, tmp_path):
    config = StudyConfig(**{**TINY, "alphas_deg": (0.0,), "phis_deg": (0.0,), "images": 3})
    out = tmp_path / "saved"
    run_study(config, out, save_images=True, progress=False)
    images = pd.read_parquet(out / "images.parquet")
    assert all((out / p).stat().st_size > 0 for p in images.image_path)


def test_crop_frames_every_visible_marker_corner_even_past_90_degrees():
    """At alpha 92 the carrier's far vertices are past theta_max while the marker's corners are
    not: framed by its vertices alone the crop missed corners; framed by points along its
    edges it holds them all."""
    import numpy as np

    from bench.detectability import carrier_outline
    from renderers.window import Window
    from scenes.camera import default_camera
    from scenes.conventions import marker_corners_marker, transform_points
    from scenes.marker import MarkerSpec, carrier_mesh
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
