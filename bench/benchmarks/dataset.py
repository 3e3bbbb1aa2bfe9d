"""``whiskerbench bench dataset``: frames/s of band and full-frame rendering, same run, same frames.

It also checks the band shortcut: both modes' frames go through the same detector, and the
detections (ids and corners) are compared. The zone where markers can be is sampled identically
in both modes, so any difference comes from pixels outside the band.
"""

from __future__ import annotations

import dataclasses
import os
import time
from pathlib import Path
from typing import TYPE_CHECKING

import cv2
import numpy as np

from bench.common.atomic import write_bytes, write_json
from bench.common.manifest import RunClock, build_manifest, hash_files, write_manifest
from bench.common.run_folder import claim_out
from bench.dataset.config import DatasetConfig
from bench.dataset.sample import sample_recorder, simulate_sample
from bench.evaluate.speed import pick_sample
from pipeline.detect import DetectorConfig, detect_markers
from renderers.variant import init_worker

if TYPE_CHECKING:
    from renderers.frames import FrameRecorder


def _time_frames(
    frames: FrameRecorder, indices: np.ndarray
) -> tuple[list[np.ndarray], float, float, float]:
    """(images, render s, camera twin s, total s) after one warm-up frame (kernels compile)."""
    frames.frame(int(indices[0]))
    frames.reset_timers()
    t0 = time.perf_counter()
    images = [frames.frame(int(f)) for f in indices]
    twin_s = frames.optics_s + frames.sensor_s
    return images, frames.render_s, twin_s, time.perf_counter() - t0


def _detections(image: np.ndarray, detector: DetectorConfig) -> dict[int, np.ndarray]:
    return {d.marker_id: d.corners_px for d in detect_markers(image, detector)}


def write_still(path: Path, image: np.ndarray, labels, frame: int, zone) -> None:
    """The zone of one frame with its ground truth drawn, as a PNG (docs/datasets.md's still)."""
    from bench.common.video import draw_preview
    from bench.dataset.labels import corners_of_frame

    drawn = draw_preview(image, *corners_of_frame(labels, frame))
    crop = drawn[zone.y0 : zone.y0 + zone.height, zone.x0 : zone.x0 + zone.width]
    write_bytes(path, cv2.imencode(".png", crop)[1].tobytes())


def bench_dataset(
    config: DatasetConfig,
    frames: int = 30,
    variant: str | None = None,
    out_dir: Path | None = None,
) -> dict:
    """Time band and full-frame rendering on the same frames; print and return the figures.

    With ``out_dir``, also write the figures (``bench.json``) and a still of the timed frame
    with the largest deflection, ground truth drawn (``still.png``), and ``manifest.json``; the
    folder is claimed before any work (FieldError on ``out`` if another command's).
    """
    clock = RunClock()
    if out_dir is not None:
        claim_out(out_dir, "bench-dataset")
    chosen = init_worker(variant)
    sample = pick_sample(config)
    sim = simulate_sample(config, sample)
    # the frames around the largest deflection: whiskers bent, the busiest scene
    deflection = sim.labels.groupby("frame")["deflection_mm"].max().to_numpy()
    start = int(np.clip(np.argmax(deflection) - frames // 2, 0, max(0, len(deflection) - frames)))
    indices = np.arange(start, min(start + frames, len(deflection)))
    print(
        f"sample {sample.sample_id}: frames {indices[0]}-{indices[-1]} (largest deflection "
        f"{deflection.max():.1f} mm), variant {chosen}, camera {config.camera.name}"
    )
    results = {}
    for mode, full in (("band", False), ("full", True)):
        sampling = dataclasses.replace(config.sampling, full_frame=full)
        t0 = time.perf_counter()
        recorder = sample_recorder(config, sample, sim, sampling)
        setup_s = time.perf_counter() - t0
        images, render_s, twin_s, total_s = _time_frames(recorder, indices)
        results[mode] = {
            "images": images,
            "rays_per_frame": recorder.renderer.rays_per_frame,
            "region": recorder.renderer.region,
            "zone": recorder.renderer.zone,
            "setup_s": setup_s,
            "render_fps": len(indices) / render_s,
            "twin_s_per_frame": twin_s / len(indices),
            "frame_fps": len(indices) / total_s,
        }
        print(
            f"{mode:>5}: region {recorder.renderer.region.width}x{recorder.renderer.region.height}"
            f" px, {recorder.renderer.rays_per_frame / 1e6:.2f} M rays/frame, "
            f"render {results[mode]['render_fps']:.1f} frames/s, camera twin "
            f"{results[mode]['twin_s_per_frame']:.3f} s/frame, both "
            f"{results[mode]['frame_fps']:.1f} frames/s (setup {setup_s:.1f} s)"
        )
    ratio = results["band"]["render_fps"] / results["full"]["render_fps"]
    print(f"band / full render speed: {ratio:.1f}x")

    detector = DetectorConfig(corner_refinement="subpix")
    same_ids, max_diff, n_det = 0, 0.0, 0
    for band_img, full_img in zip(
        results["band"]["images"], results["full"]["images"], strict=True
    ):
        a, b = _detections(band_img, detector), _detections(full_img, detector)
        same_ids += set(a) == set(b)
        n_det += len(a)
        for marker_id in set(a) & set(b):
            max_diff = max(max_diff, float(np.abs(a[marker_id] - b[marker_id]).max()))
    print(
        f"detections: identical id sets in {same_ids}/{len(indices)} frames "
        f"({n_det} markers found in band frames); largest corner difference {max_diff:.3f} px"
    )
    figures = {
        "sample": sample.sample_id,
        "variant": chosen,
        "camera_profile": config.camera.name,
        "band_render_fps": results["band"]["render_fps"],
        "full_render_fps": results["full"]["render_fps"],
        "band_frame_fps": results["band"]["frame_fps"],
        "full_frame_fps": results["full"]["frame_fps"],
        "twin_s_per_frame": {m: results[m]["twin_s_per_frame"] for m in results},
        "ratio": ratio,
        "same_id_frames": same_ids,
        "frames": len(indices),
        "max_corner_diff_px": max_diff,
        "band_px": dataclasses.asdict(results["band"]["region"]),
        "rays_per_frame": {m: results[m]["rays_per_frame"] for m in results},
        "cpu_count": os.cpu_count(),
    }
    if out_dir is not None:
        pick = int(np.argmax(deflection[indices]))
        zone = results["band"]["zone"]
        write_still(
            Path(out_dir) / "still.png",
            results["band"]["images"][pick],
            sim.labels,
            int(indices[pick]),
            zone,
        )
        write_json(Path(out_dir) / "bench.json", figures)
        written = [Path(out_dir) / n for n in ("bench.json", "still.png")]
        config_record = {"dataset": config.to_json(), "frames": frames}
        record = build_manifest(
            "bench-dataset",
            clock,
            config_record,
            seed=config.seed,
            variant=chosen,
            outputs=hash_files(written, Path(out_dir)),
        )
        write_manifest(Path(out_dir), record)
        print(f"wrote {out_dir}/bench.json and still.png (frame {indices[pick]})")
    return figures
