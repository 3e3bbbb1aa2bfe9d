"""Benchmark datasets: labeled videos of the whisker array sampling vegetation (SPEC 2, 5).

A dataset is a grid of samples; each sample is a pure function of the dataset config and its
own seed and writes ``<out>/<sample_id>/`` atomically, file by file, with ``sample.json`` last:
it lists the SHA-256 of the other files, so a rerun skips a sample whose files verify and
redoes one that a crash cut short.

Per sample: vegetation (:mod:`scenes.vegetation`) and a protocol (:mod:`scenes.motion`) give the
array's path; the mechanics (:mod:`scenes.dynamics`: dynamic by default, quasi-static as the
config's choice) give every whisker's deflection at every time sample; the frame recorder
(:class:`renderers.frames.FrameRecorder`) renders each frame's radiance and records it through
the camera twin (one :class:`~scenes.profile.CameraProfile`): optics once per frame, then the
sensor and stream stages; :mod:`bench.dataset.labels` makes the
exact labels with the profile's lens; :mod:`bench.common.video` writes the videos.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

from bench.common.atomic import atomic_path, write_json
from bench.common.manifest import sha256
from bench.common.units import unit_state, write_unit
from bench.dataset.config import SAMPLE_FILES, DatasetConfig, SampleSpec
from bench.dataset.core_share import CHECK_EVERY_FRAMES, CoreShare
from bench.dataset.labels import corners_of_frame, label_table
from renderers.variant import set_threads
from scenes.branch_reach import gap_of_branch
from scenes.lighting import get_lighting
from scenes.marker import check_dictionary
from scenes.motion import MotionSpec
from scenes.vegetation import (
    SAMPLING_PENETRATION_MM,
    Vegetation,
    VegetationSpec,
)

if TYPE_CHECKING:
    from collections.abc import Iterable

    from renderers.frame_sampling import FrameSampling
    from renderers.frames import FrameRecorder

# -- one sample ------------------------------------------------------------------------------


@dataclass(frozen=True)
class SampleTiming:
    frames: int
    frames_reused: int  # still frames recorded from the previous frame's optical image
    simulate_s: float
    render_s: float
    optics_s: float  # the twin's optical stages, in their own thread beside the render
    sensor_s: float  # the twin's sensor, processing and stream stages, likewise
    encode_s: float  # the frame loop's time not rendering: waiting on the twin and the writers
    total_s: float


def sample_times(motion: MotionSpec, exposure_s: float, subframes: int, step: int):
    """(frame times (F,), source frame indices (F,), time samples (F, subframes) s).

    A frame's timestamp is the middle of its exposure; its time samples are stratified over it.
    """
    source = np.arange(0, len(motion.frame_times()), step)
    times = motion.frame_times()[source]
    offsets = ((np.arange(subframes) + 0.5) / subframes - 0.5) * exposure_s
    return times, source, times[:, None] + offsets[None, :]


@dataclass
class SimulatedSample:
    """A sample's path and mechanics: everything but the pixels."""

    vegetation: Vegetation
    motion: MotionSpec
    times_s: np.ndarray  # (F,) frame timestamps (middle of the exposure)
    source_frames: np.ndarray  # (F,) indices at the protocol's full frame rate
    sub_times_s: np.ndarray  # (F, K) time samples within each exposure
    angles_rad: np.ndarray  # (F, K + 1, n, 2): at the K time samples, then at the timestamp
    labels: pd.DataFrame  # bench.labels.label_table


def simulate_sample(config: DatasetConfig, sample: SampleSpec) -> SimulatedSample:
    """Vegetation, path and every whisker's deflection at every time sample, in time order."""
    from scenes.dynamics import simulate_at
    from scenes.vegetation import build_vegetation

    motion = config.motion(sample.protocol, sample.distance)
    k = config.sampling.subframes
    vegetation = build_vegetation(
        VegetationSpec(
            sample.foliage,
            sample.distance,
            sample.branches_mm,
            sample.layout_seed(config.seed),
        ),
        config.array,
        detail=config.foliage_detail,
    )
    times, source, sub_times = sample_times(
        motion, config.exposure_ms / 1000, k, config.frames_step
    )
    all_times = np.concatenate([sub_times, times[:, None]], axis=1).ravel()
    # The path's corners join the time samples: between two samples the mechanics move the
    # array in a straight line, which would cut a reversal that falls between frames.
    with_corners = np.concatenate([all_times, motion.waypoints()[0]])
    order = np.argsort(with_corners, kind="stable")
    sorted_times = with_corners[order]
    result = simulate_at(
        config.array,
        sorted_times,
        motion.offsets_at(sorted_times),
        vegetation.branches,
        vegetation.contacts,
        mechanics=config.mechanics,
    )
    rows = np.empty_like(order)
    rows[order] = np.arange(len(order))
    rows = rows[: all_times.size]  # each time sample's row, the corners dropped
    angles = result.angles_rad[rows].reshape(len(times), k + 1, -1, 2)
    contact = result.contact[rows].reshape(len(times), k + 1, -1)[:, k]
    branch_contact = result.branch_contact[rows].reshape(len(times), k + 1, -1)[:, k]
    labels = label_table(
        config.camera.lens, config.array, angles[:, k], contact, branch_contact, times, source
    )
    return SimulatedSample(vegetation, motion, times, source, sub_times, angles, labels)


def sample_recorder(
    config: DatasetConfig,
    sample: SampleSpec,
    sim: SimulatedSample,
    sampling: FrameSampling | None = None,
    draw_seed: int | None = None,
) -> FrameRecorder:
    """The frame recorder of a simulated sample (:class:`renderers.frames.FrameRecorder`): its
    vegetation, lighting, seeds, deflections and path; ``sampling`` defaults to the config's.
    ``draw_seed``: another dataset seed for the render's and the sensor's random draws only (the
    same scene drawn again: the fidelity ladder's control); None: the config's."""
    from renderers.frames import FrameRecorder

    seeds = sample.seeds(config.seed if draw_seed is None else draw_seed)
    return FrameRecorder(
        config.twin,
        config.array,
        [(p.name, p.mesh, p.albedo_rgb) for p in sim.vegetation.parts],
        get_lighting(sample.lighting),
        sampling or config.sampling,
        seeds["render"],
        seeds["noise"],
        config.exposure,
        sim.angles_rad,
        sim.motion.offsets_at(sim.sub_times_s),
    )


def run_sample(
    config: DatasetConfig, sample: SampleSpec, out_dir: Path, share: CoreShare | None = None
) -> dict:
    """Simulate, render and label one sample into ``out_dir / sample_id``; return its record.

    ``share``: the cores split with the run's other samples in progress (a local pool), looked
    at every :data:`~bench.dataset.core_share.CHECK_EVERY_FRAMES` frames; None keeps Dr.Jit's
    thread count as it is."""
    from bench.common.video import BackgroundWriter, write_preview, write_video

    t_start = time.perf_counter()
    folder = Path(out_dir) / sample.sample_id
    sim = simulate_sample(config, sample)
    t_sim = time.perf_counter()

    # --- Frames: render here; the twin records frame f in a thread while f + 1 renders, and
    # the video and its preview encode in threads of their own
    frames = sample_recorder(config, sample, sim)
    n_frames = len(sim.times_s)
    truth = [corners_of_frame(sim.labels, f) for f in range(n_frames)]
    captions = [f"frame {f}  t = {sim.times_s[f]:.3f} s" for f in range(n_frames)]
    video = BackgroundWriter(lambda it: write_video(folder / "video.mp4", it, sim.motion.fps))
    preview = BackgroundWriter(  # drawn on the frames as recorded, before the video's codec
        lambda it: write_preview(
            folder / "preview.mp4", it, *zip(*truth, strict=True), captions, sim.motion.fps
        )
    )

    def record(radiances: Iterable[np.ndarray | None]) -> int:
        count = 0
        for radiance in radiances:
            frame = frames.record(radiance)
            video.put(frame)
            preview.put(frame)
            count += 1
        return count

    t_frames = time.perf_counter()
    with video, preview, BackgroundWriter(record) as twin:
        for f in range(n_frames):
            if share is not None and f % CHECK_EVERY_FRAMES == 0:
                set_threads(share.threads())
            twin.put(frames.render_once(f))
    n_written = video.count
    encode_s = time.perf_counter() - t_frames - frames.render_s

    # --- Labels, camera
    with atomic_path(folder / "labels.parquet") as tmp:
        sim.labels.to_parquet(tmp, index=False)
    write_json(folder / "camera.json", config.twin.to_json())

    timing = SampleTiming(
        frames=n_written,
        frames_reused=frames.frames_reused,
        simulate_s=t_sim - t_start,
        render_s=frames.render_s,
        optics_s=frames.optics_s,
        sensor_s=frames.sensor_s,
        encode_s=encode_s,
        total_s=time.perf_counter() - t_start,
    )
    record = {
        "sample_id": sample.sample_id,
        "foliage": sample.foliage,
        "distance": sample.distance,
        "penetration_mm": SAMPLING_PENETRATION_MM[sample.distance],
        "branches_mm": list(sample.branches_mm),
        "branch_gaps": [
            list(gap_of_branch(b, sample.distance, config.array)) for b in sample.branches_mm
        ],
        "branches_veg_mm": [dataclasses.asdict(b) for b in sim.vegetation.branches],
        "protocol": dataclasses.asdict(sim.motion),
        "lighting": sample.lighting,
        "seed": config.seed,
        "sample_seeds": sample.seeds(config.seed),
        "layout_seed": sample.layout_seed(config.seed),  # shared by the foliage_group's samples
        "foliage_group": sample.foliage_group(config.seed),
        "frames": n_written,
        "frames_step": config.frames_step,
        "mechanics": config.mechanics,
        "foliage_detail": config.foliage_detail,
        "exposure_ms": config.exposure_ms,
        "exposure_applied": frames.exposure,  # config.exposure x the lighting preset's
        "camera_profile": config.camera.name,
        "sampling": config.to_json()["sampling"],
        "region_px": dataclasses.asdict(frames.renderer.region),
        "rays_per_frame": frames.renderer.rays_per_frame,
        "array": config.array.to_json(),
        "family": check_dictionary(config.array.dictionary),  # the markers' (array.dictionary)
        "timing_s": dataclasses.asdict(timing),
        "settings_sha256": config.settings_hash(),
        "files": {name: sha256(folder / name) for name in SAMPLE_FILES},
    }
    return write_unit(folder / "sample.json", record)


def sample_state(folder: Path, settings_sha256: str) -> str:
    """Whether the sample in ``folder`` is done and intact: its ``sample.json`` (a unit record,
    :func:`bench.common.units.unit_state`) is whole, names this folder, and every file it lists
    verifies. UnitSettingsError (a ValueError) when the sample was made with other settings
    (the folder holds another dataset: refuse rather than mix)."""
    return unit_state(folder / "sample.json", settings_sha256, {"sample_id": folder.name})
