"""``whiskerbench bench render``: the project's renderer against Blender Cycles in one run.

Two scenes, each rendered by both at the same resolution, samples per pixel, direct light only
and thread count, in the ``sun`` preset through the prototype lens: ``marker``, the study's marker
and pose (the full 2592 x 1944 frame, or a crop around the marker), rendered by the project as the
study renders it (:class:`~renderers.marker_renderer.MarkerRenderer`: exact sky term, sun per
sample, adaptive anti-aliasing; a full frame is the marker's crop traced and the open sky
elsewhere, :mod:`renderers.sky_frame`, checked against the frame with every pixel traced and
that frame's own seed spread); ``array``, the whisker array in foliage
(:mod:`bench.benchmarks.render_array`), rendered as the dataset renders it. Cycles renders the
same plain data (:mod:`bench.benchmarks.cycles_scene`). Each
renders twice: the first render includes loading the scene and compiling kernels, the second is
the per-frame cost of a scene already loaded (what a study or a dataset pays) and is the one the
ratio and the target use. Both images go through the same noise-free camera (luminance, the
preset's exposure, sRGB, 8 bit) and the study's detector, and are scored against the projected
true corners, so a speed-up bought with a wrong image shows. Without ``bpy`` Cycles is skipped
with a note and the project side is still timed.
"""

from __future__ import annotations

import os
import platform
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from bench.benchmarks.cycles_scene import marker_parts
from bench.common.atomic import write_bytes, write_json
from bench.common.manifest import RunClock, build_manifest, hash_files, write_manifest
from bench.common.marker_score import MarkerTruth, find_marker
from bench.common.run_folder import claim_out
from bench.study.config import StudyConfig, profile_from_option
from renderers.marker_renderer import MarkerRenderer
from renderers.sensor import LUMINANCE_RGB, quantize
from renderers.variant import init_worker
from renderers.window import Window
from scenes.camera import FisheyeCamera
from scenes.lighting import get_lighting
from scenes.marker import MarkerSpec
from scenes.study import study_pose
from scenes.validation import FieldError

SCENES = ("marker", "array")
#: The scene: the study's marker (13.2 mm) off the axis and tilted, in the sun, prototype lens.
SIZE_MM, ALPHA_DEG, PHI_DEG, LIGHTING, CAMERA = 13.2, 30.0, 20.0, "sun", "prototype"
#: The issue's target: the project at least this many times faster than Cycles.
TARGET_RATIO = 10.0
#: The crop + sky frame is faithful when it differs from the traced frame by at most this many
#: times what two traced frames of other seeds differ by (share of pixels differing outside the
#: crop, mean |difference| inside it).
SPREAD_FACTOR = 1.5


def camera_image(radiance: np.ndarray, exposure: float) -> np.ndarray:
    """A noise-free 8-bit grey image of linear RGB radiance: luminance, exposure, sRGB."""
    return quantize((radiance @ LUMINANCE_RGB.astype(np.float32)) * np.float32(exposure), "srgb")


def _marker_outcome(image: np.ndarray, window: Window, config: StudyConfig, truth) -> dict:
    lens = config.camera.lens
    _, found = find_marker(image, config.detector, (window.x0, window.y0), truth, lens)
    corners = found[0] if found else None
    error = np.linalg.norm(corners - truth.corners_px, axis=1).mean() if found else np.nan
    return {"detected": bool(found), "corner_err_px": float(error), "corners": corners}


@dataclass(frozen=True)
class _Scene:
    """A scene of the benchmark, ready for both renderers."""

    lens: FisheyeCamera
    window: Window
    project: Callable[[int], tuple]  # seed -> (radiance, None, None): timed by the caller
    cycles_parts: Callable[[], list]  # the same meshes for Cycles (built only when it runs)
    outcome: Callable[[np.ndarray], dict]  # detection on an 8-bit image; "detected" compares
    describe: Callable[[dict], str]  # an outcome in words
    exposure: float
    what: str
    traced: Callable[[int], tuple] | None = None  # every pixel traced, for a full frame
    crop: Window | None = None  # the window the fast full frame traces


def _marker_scene(spp: int, crop: bool) -> _Scene:
    """The study's marker, pose and preset; the full frame or a crop around the marker."""
    config = StudyConfig(camera=profile_from_option(CAMERA))
    lens, lighting = config.camera.lens, get_lighting(LIGHTING)
    T = study_pose(ALPHA_DEG, PHI_DEG, config.distance_mm)
    truth = MarkerTruth.of(lens, config.marker_id, SIZE_MM, T)
    renderer = MarkerRenderer(lens, config.dictionary, config.marker_id, spp)
    grid = config.camera.crop_grid_px
    marker_window = renderer.crop(T, SIZE_MM, grid)
    window = marker_window if crop else Window.full(lens)

    def traced(seed: int):
        return renderer.render(LIGHTING, T, SIZE_MM, window, seed).radiance(), None, None

    def project(seed: int):
        if crop:
            return traced(seed)
        return renderer.render_frame(LIGHTING, T, SIZE_MM, grid, seed), None, None

    def describe(found: dict) -> str:
        if found["detected"]:
            return f"marker detected, corner error {found['corner_err_px']:.2f} px"
        return "marker NOT detected"

    marker = MarkerSpec(config.dictionary, config.marker_id, SIZE_MM)
    return _Scene(
        lens,
        window,
        project,
        lambda: marker_parts(marker, T),
        lambda image: _marker_outcome(image, window, config, truth),
        describe,
        lighting.exposure,
        f"one marker ({SIZE_MM:g} mm, alpha {ALPHA_DEG:g}, phi {PHI_DEG:g} deg, "
        f"{config.distance_mm:g} mm)",
        traced=None if crop else traced,
        crop=None if crop else marker_window,
    )


def _array_scene(spp: int) -> _Scene:
    """The array in foliage (:mod:`bench.benchmarks.render_array`): always the full frame."""
    from bench.benchmarks.render_array import SAMPLE, array_frame, array_outcome

    frame = array_frame(spp)
    lens = frame.config.camera.lens

    def describe(found: dict) -> str:
        return (
            f"{len(found['detected'])} of {found['visible']} visible markers detected, corner "
            f"error {found['corner_err_px']:.2f} px"
        )

    return _Scene(
        lens,
        Window.full(lens),
        lambda _seed: (frame.render_project(), None, None),
        frame.cycles_parts,
        lambda image: array_outcome(image, frame),
        describe,
        frame.exposure,
        "the whisker array in {foliage} foliage at the {distance} distance, mid-sample".format(
            **SAMPLE
        ),
    )


def _time(render) -> tuple[list[np.ndarray], list[float], list[float]]:
    """([radiance], [wall s] and [CPU s] of both renders, seeds 1 and 2)."""
    images, walls, cpus = [], [], []
    for seed in (1, 2):
        t0, c0 = time.perf_counter(), time.process_time()
        radiance, wall, cpu = render(seed)
        walls.append(wall if wall is not None else time.perf_counter() - t0)
        cpus.append(cpu if cpu is not None else time.process_time() - c0)
        images.append(radiance)
    return images, walls, cpus


def bench_render(
    scene: str = "marker",
    spp: int = 4,
    threads: int | None = None,
    variant: str | None = None,
    out: Path | None = None,
    crop: bool = False,
    use_cycles: bool = True,
) -> dict:
    """Render the scene with the project and Cycles; print and return times, ratios, detections.

    ``crop``: a window around the marker instead of the full frame (the tests' fast path);
    ``use_cycles=False`` times the project only. With ``out``, also writes ``bench.json``, both
    8-bit images and ``manifest.json`` (the folder claimed before any work).
    """
    if scene not in SCENES:
        raise FieldError("scene", f"{scene!r}: choose from {', '.join(SCENES)}")
    if spp < 1 or (threads is not None and threads < 1):
        raise ValueError(f"spp={spp}, threads={threads}: both must be >= 1")
    if crop and scene != "marker":
        raise ValueError(f"crop: only the marker scene has a crop, not {scene!r}")
    threads = threads or os.cpu_count() or 1
    clock = RunClock()
    if out is not None:
        claim_out(out, "bench-render")
    chosen = init_worker(variant, threads)
    bench = _marker_scene(spp, crop) if scene == "marker" else _array_scene(spp)
    window = bench.window
    print(
        f"render benchmark: {bench.what} in the {LIGHTING} preset, {CAMERA} lens, {window.width}x"
        f"{window.height} px, {spp} spp, direct light, {threads} threads ({platform.node()}, "
        f"{os.cpu_count()} cores)"
    )
    rows = {"project": _run("project", chosen, bench.project, bench)}
    spread = {}
    if bench.traced is not None:
        name = "project, every pixel traced"
        rows["traced"] = _run(name, chosen, bench.traced, bench, keep_first=True)
        spread = _against_traced(rows, bench.crop)
    bpy = None
    if use_cycles:
        from bench.benchmarks.cycles_scene import INSTALL_HINT, import_bpy

        bpy = import_bpy()
        if bpy is None:
            print(f"  Cycles: skipped, bpy is not installed ({INSTALL_HINT})")
    if bpy is not None:
        from bench.benchmarks.cycles_scene import CyclesScene

        parts = bench.cycles_parts()
        cycles = CyclesScene(bpy, bench.lens, parts, get_lighting(LIGHTING), spp, threads)
        name = f"Cycles {bpy.app.version_string}"
        rows["cycles"] = _run(name, "CPU", lambda _: cycles.render(window), bench)
    figures = _verdict(rows, spread)
    figures.update(
        scene=scene,
        spp=spp,
        threads=threads,
        window=[window.x0, window.y0, window.width, window.height],
        node=platform.node(),
        cpu_count=os.cpu_count(),
    )
    if out is not None:
        _write(Path(out), figures, rows, clock, chosen)
    return figures


def _run(name: str, device: str, render, bench: _Scene, keep_first: bool = False) -> dict:
    """Time one renderer's two renders, detect on the second; print one line. ``keep_first``:
    also keep the first render's 8-bit image (another seed: the traced frame's spread)."""
    radiances, walls, cpus = _time(render)
    image = camera_image(radiances[1], bench.exposure)
    found = bench.outcome(image)
    print(
        f"  {name} ({device}): first render {walls[0]:.2f} s wall / {cpus[0]:.2f} s CPU, "
        f"then {walls[1]:.2f} s wall / {cpus[1]:.2f} s CPU; {bench.describe(found)}"
    )
    row = {"name": name, "device": device, "wall_s": walls, "cpu_s": cpus, "image": image, **found}
    if keep_first:
        row["first_image"] = camera_image(radiances[0], bench.exposure)
    return row


def _against_traced(rows: dict, crop: Window) -> dict:
    """The fast full frame (crop + sky) against the traced one, beside the traced frame's own
    spread over seeds 1 and 2: the share of pixels differing outside the crop, the mean 8-bit
    |difference| inside it; ``within_seed_spread`` when neither exceeds SPREAD_FACTOR x."""
    inside = np.zeros(rows["traced"]["image"].shape, bool)
    inside[crop.y0 : crop.y0 + crop.height, crop.x0 : crop.x0 + crop.width] = True

    def apart(a: np.ndarray, b: np.ndarray) -> dict:
        d = np.abs(a.astype(np.int16) - b)
        return {
            "outside_differ": float((d[~inside] > 0).mean()),
            "inside_mean": float(d[inside].mean()),
        }

    traced = rows["traced"]["image"]
    fast, spread = (
        apart(rows["project"]["image"], traced),
        apart(rows["traced"]["first_image"], traced),
    )
    within = all(fast[k] <= SPREAD_FACTOR * spread[k] for k in fast)
    print(
        f"  crop + sky against every pixel traced: {fast['outside_differ']:.3%} of pixels outside "
        f"the crop differ, mean |d| {fast['inside_mean']:.3f} grey inside; two traced seeds: "
        f"{spread['outside_differ']:.3%}, {spread['inside_mean']:.3f}: "
        + ("within the seed spread" if within else f"OUTSIDE {SPREAD_FACTOR:g}x the seed spread")
    )
    return {"against_traced": fast, "traced_seed_spread": spread, "within_seed_spread": within}


def _verdict(rows: dict, spread: dict) -> dict:
    """Ratios Cycles / project (second renders), detection agreement, the target met or missed
    (a fast full frame must also be within the traced frame's seed spread)."""
    figures = {
        k: {f: v[f] for f in ("name", "device", "wall_s", "cpu_s", "detected", "corner_err_px")}
        for k, v in rows.items()
    }
    figures.update(spread)
    if "cycles" not in rows:
        return figures
    p, c = rows["project"], rows["cycles"]
    wall, cpu = c["wall_s"][1] / p["wall_s"][1], c["cpu_s"][1] / p["cpu_s"][1]
    equal = p["detected"] == c["detected"]
    between = (
        float(np.linalg.norm(p["corners"] - c["corners"], axis=1).mean())
        if equal and p["detected"]
        else float("nan")
    )
    met = equal and min(wall, cpu) >= TARGET_RATIO and spread.get("within_seed_spread", True)
    print(
        f"  ratio Cycles / project (second renders): wall {wall:.1f}x, CPU {cpu:.1f}x; "
        f"detection {'equal' if equal else 'DIFFERS'}"
        + (f", corners {between:.2f} px apart" if np.isfinite(between) else "")
        + f"; target >= {TARGET_RATIO:g}x at equal detection: {'met' if met else 'MISSED'}"
    )
    if "traced" in rows:
        t = rows["traced"]
        print(
            f"  ratio Cycles / project with every pixel traced: wall "
            f"{c['wall_s'][1] / t['wall_s'][1]:.1f}x, CPU {c['cpu_s'][1] / t['cpu_s'][1]:.1f}x"
        )
    figures.update(
        ratio_wall=wall,
        ratio_cpu=cpu,
        detection_equal=equal,
        corners_apart_px=between,
        target_ratio=TARGET_RATIO,
        target_met=met,
    )
    return figures


def _write(out: Path, figures: dict, rows: dict, clock: RunClock, variant: str) -> None:
    paths = [out / "bench.json"]
    write_json(paths[0], figures)
    for key, row in rows.items():
        paths.append(out / f"{key}.png")
        write_bytes(paths[-1], cv2.imencode(".png", row["image"])[1].tobytes())
    config = {k: figures[k] for k in ("scene", "spp", "threads", "window")}
    record = build_manifest(
        "bench-render", clock, config, variant=variant, outputs=hash_files(paths, out)
    )
    write_manifest(out, record)
    print(f"wrote {out}/bench.json and the images detected on")
