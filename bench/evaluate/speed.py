"""The frames ``whiskerbench bench pipeline`` times: full frames of the busiest scene.

The frames are rendered whole (vegetation in every pixel), in time order around the largest
deflection of a busy sample, so ROI tracking sees real motion. They are timed as ``compare``
times a dataset's frames (:mod:`bench.evaluate.timing`: alternating, repeated, median and
spread); :func:`full_run` is them as one run.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pandas as pd

from bench.dataset.config import DatasetConfig, SampleSpec
from bench.dataset.sample import sample_recorder, simulate_sample
from bench.evaluate.timing import TimedRun
from pipeline.track import MarkerSet

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


def full_run(config: DatasetConfig, images: list[np.ndarray]) -> TimedRun:
    """``images`` (:func:`full_frames`, numbered from 0 like their labels) as one run of
    ``config``'s busiest sample, through its lens, for :mod:`bench.evaluate.timing`."""
    markers = MarkerSet(config.array.marker_ids, config.array.marker_size_mm)
    return TimedRun(
        pick_sample(config).sample_id,
        tuple(range(len(images))),
        tuple(images),
        config.camera.lens,
        markers,
    )
