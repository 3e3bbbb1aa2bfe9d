"""Timing a pipeline on full frames: the busiest scene, its frames, single-core speed.

Shared by ``compare`` (speed beside accuracy) and ``whiskerbench bench pipeline``: the frames
are rendered whole (vegetation in every pixel), in time order around the largest deflection of a
busy sample, so ROI tracking sees real motion; each pipeline's tracking is repeated until it has
run for ``min_seconds`` and the fastest repeat counts (a slower repeat is another process's
noise on these shared machines, not the pipeline's).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Iterator
from contextlib import contextmanager

import cv2
import numpy as np
import pandas as pd

from bench.dataset.config import DatasetConfig, SampleSpec
from bench.dataset.sample import sample_recorder, simulate_sample
from pipeline.presets import PipelineConfig
from pipeline.track import MarkerSet, TrackResult, track

#: The busiest scene: dense leaves, a branch, outdoor whisking (frames from its largest
#: deflection). Every speed figure is measured on its full frames.
SPEED_SAMPLE = DatasetConfig(
    foliage=("dense",),
    distances=("intermediate",),
    branches=((0.0,),),
    protocols=("outdoor",),
    passes=1,
)


def pick_sample(config: DatasetConfig) -> SampleSpec:
    """The first sample with both foliage and a branch (the busiest scene), else the first."""
    samples = config.samples()
    busy = [s for s in samples if s.foliage != "none" and s.branches_mm]
    return (busy or samples)[0]


def full_frames(
    config: DatasetConfig, frames: int, psf_scales: tuple[float, ...] = (1.0,)
) -> tuple[dict[float, list[np.ndarray]], pd.DataFrame]:
    """``frames`` consecutive full frames around the largest deflection, recorded through the
    twin at each of ``psf_scales`` (times its PSF table as calibrated, e.g. the band's ends),
    and their labels (renumbered from 0, like the frames).

    Each frame is rendered once and recorded through one twin per scale, each with the
    sample's noise seed: the frames at two scales differ only in the lens."""
    from renderers.twin_recorder import TwinRecorder

    sample = pick_sample(config)
    sim = simulate_sample(config, sample)
    deflection = sim.labels.groupby("frame")["deflection_mm"].max().to_numpy()
    start = int(np.clip(np.argmax(deflection) - frames // 2, 0, max(0, len(deflection) - frames)))
    indices = np.arange(start, min(start + frames, len(deflection)))
    recorder = sample_recorder(
        config, sample, sim, dataclasses.replace(config.sampling, full_frame=True)
    )
    region, band = recorder.renderer.region, recorder.renderer.band
    noise_seed = sample.seeds(config.seed)["noise"]  # the recorder's own
    twins = {
        scale: TwinRecorder(
            recorder.profile.at_psf_scale(scale), region, band, recorder.exposure, noise_seed
        )
        for scale in psf_scales
    }
    images: dict[float, list[np.ndarray]] = {scale: [] for scale in psf_scales}
    for f in indices:
        radiance = recorder.radiance(int(f))
        for scale, twin in twins.items():
            images[scale].append(twin.record(radiance))
    labels = sim.labels[sim.labels["frame"].isin(indices)].copy()
    labels["frame"] -= start
    scales = ", ".join(f"{scale:g}" for scale in twins)
    scales = "" if tuple(psf_scales) == (1.0,) else f", PSF scales {scales}"
    print(
        f"sample {sample.sample_id}: {len(indices)} full frames ({indices[0]}-{indices[-1]}, "
        f"largest deflection {deflection.max():.1f} mm{scales})"
    )
    return images, labels


@contextmanager
def one_opencv_thread() -> Iterator[None]:
    """OpenCV on one thread inside the block (single-core speed), as it was after it."""
    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)
    try:
        yield
    finally:
        cv2.setNumThreads(threads)


def track_frames(
    images: list[np.ndarray], config: DatasetConfig, pipeline: PipelineConfig
) -> TrackResult:
    """The pipeline's tracking (detection and pose of every frame, in order) on ``images`` of
    ``config``'s array, through its lens."""
    markers = MarkerSet(config.array.marker_ids, config.array.marker_size_mm)
    detector, search, pose = pipeline.detector, pipeline.search, pipeline.pose_method
    return track(images, config.camera.lens, markers, detector, search, pose)


def time_pipeline(
    images: list[np.ndarray],
    config: DatasetConfig,
    pipeline: PipelineConfig,
    min_seconds: float,
) -> tuple[float, pd.DataFrame]:
    """(best frames/s over repeats, the detections of one run).

    A peer runs in its worker process, as everywhere (:mod:`pipeline.backends.isolated`): its
    frames/s include sending each searched crop there. The worker is started by an untimed
    frame first, so no repeat counts a process start. Callers hold OpenCV to one thread
    (:func:`one_opencv_thread`); the peers' adapters use one thread of their own.

    The isolation's cost, measured on 12 of these frames (the 2354 x 1944 px circle crop, 4.6 MB
    a call; track through the worker against the adapter in-process, alternating): locus about
    8 ms a frame (ratio 1.06), apriltag about 88 ms (ratio 1.24), of which all but about 5 ms is
    the worker's glibc returning the library's large buffers to the system after every call
    (with MALLOC_MMAP_THRESHOLD_ and MALLOC_TRIM_THRESHOLD_ raised the ratio was 1.015).
    """
    track_frames(images[:1], config, pipeline)  # starts a peer's worker outside the timing
    best, total, result = 0.0, 0.0, None
    while result is None or total < min_seconds:
        t0 = time.perf_counter()
        result = track_frames(images, config, pipeline)
        elapsed = time.perf_counter() - t0
        total += elapsed
        best = max(best, len(images) / elapsed)
    return best, result.detections
