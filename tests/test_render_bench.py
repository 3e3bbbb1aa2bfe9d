"""``whiskerbench bench render``: the project side times and detects; Cycles (when bpy is
installed) renders the same scene to the same pixels and the same detection."""

from __future__ import annotations

import json

import numpy as np
import pytest

import bench.benchmarks.cycles_scene as cycles_scene
from bench.benchmarks.render import ALPHA_DEG, LIGHTING, PHI_DEG, SIZE_MM, bench_render


@pytest.mark.slow
def test_project_side_without_bpy(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(cycles_scene, "import_bpy", lambda: None)
    out = tmp_path / "run"
    figures = bench_render(spp=4, out=out, crop=True)  # threads: all, as Dr.Jit by default
    printed = capsys.readouterr().out
    assert "Cycles: skipped" in printed and "pip install" in printed
    assert "cycles" not in figures and "ratio_wall" not in figures
    project = figures["project"]
    assert project["detected"], printed
    assert project["corner_err_px"] < 1.0  # subpix corners on a clean render: ~0.4 px
    assert all(t > 0 for t in project["wall_s"] + project["cpu_s"])
    assert sorted(p.name for p in out.iterdir()) == [
        "bench.json", "manifest.json", "project.png"
    ]  # fmt: skip
    assert json.loads((out / "manifest.json").read_text())["kind"] == "bench-render"


@pytest.mark.slow
def test_cycles_renders_the_same_scene():
    pytest.importorskip("bpy")
    from bench.study.config import StudyConfig, profile_from_option
    from renderers.marker_renderer import MarkerRenderer
    from renderers.variant import init_worker
    from scenes.lighting import get_lighting
    from scenes.marker import MarkerSpec
    from scenes.study import study_pose

    lens = profile_from_option("prototype").lens
    T = study_pose(ALPHA_DEG, PHI_DEG, StudyConfig().distance_mm)
    init_worker(None)
    project = MarkerRenderer(lens, "4x4_50", 0, spp=4)
    window = project.crop(T, SIZE_MM, 16, margin_px=40)
    ours = project.render(LIGHTING, T, SIZE_MM, window, seed=1).radiance()
    parts = cycles_scene.marker_parts(MarkerSpec("4x4_50", 0, SIZE_MM), T)
    scene = cycles_scene.CyclesScene(
        cycles_scene.import_bpy(), lens, parts, get_lighting(LIGHTING), spp=4, threads=1
    )
    theirs, wall, cpu = scene.render(window)
    assert theirs.shape == ours.shape and wall > 0 and cpu > 0
    # The sky is evaluated exactly by both (the crop is mostly sky): equal to float precision;
    # the marker's pixels differ by anti-aliasing noise only.
    difference = np.abs(theirs - ours).sum(axis=-1)
    assert np.median(difference) < 1e-4
    assert abs(theirs.mean() - ours.mean()) < 0.01 * ours.mean()

    figures = bench_render(spp=4, crop=True)
    assert figures["project"]["detected"] and figures["cycles"]["detected"]
    assert figures["detection_equal"]
    assert figures["corners_apart_px"] < 0.5
    assert figures["ratio_wall"] > 0 and figures["ratio_cpu"] > 0


@pytest.mark.slow
def test_array_in_foliage_scene(capsys, monkeypatch):
    """The array scene: the project's full frame shows every visible marker, detected near its
    true corners; with bpy, Cycles renders the same meshes to the same detections."""
    from bench.benchmarks import render_array

    monkeypatch.setattr(cycles_scene, "import_bpy", lambda: None)
    figures = bench_render(scene="array", spp=1)
    project = figures["project"]
    frame = render_array.array_frame(1)
    visible = int(frame.truth[2].sum())
    assert visible >= 10 and len(project["detected"]) == visible, capsys.readouterr().out
    assert project["corner_err_px"] < 1.5
    parts = frame.cycles_parts()
    names = [p[0] for p in parts]
    assert names[:4] == ["prints", "carriers", "rods", "plate"] and len(names) > 4
    # the posed prints sit where the labels put the markers: each print's centre projects
    # into the middle of its true corners
    corners, ids, visible = frame.truth
    centres = np.asarray(parts[0][1].vertices).reshape(len(ids), -1, 3).mean(axis=1)
    px = frame.config.camera.lens.project(centres)
    apart = np.linalg.norm(px - corners.mean(axis=1), axis=-1)[visible]
    assert apart.max() < 1.0
