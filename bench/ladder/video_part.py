"""The video ladder: a branch sample and its no-branch twin rendered once per render setting.

A task is one render setting (spp, integrator, region, foliage detail) and the rungs sharing it
(the reference and its camera-stage rungs). For each of the two samples it simulates the
mechanics once per worker (rendering does not change them), renders every ``frames_step``-th
frame once (:meth:`FrameRecorder.radiance`) and records that radiance through each rung's
profile (:class:`Replay`) into ``video/<rung>/<sample>.mp4``. Each rung's pipeline then runs on
the twin (its fixed threshold, as ``score`` sets it) and on the branch sample, scored by
:mod:`bench.evaluate.score`; ``result.json`` is written last (a unit record of the ladder's
settings, :mod:`bench.common.units`), so a rerun skips the rung if it verifies.
"""

from __future__ import annotations

import dataclasses
import queue
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from bench.common.units import DONE, unit_state, write_unit
from bench.dataset.config import DatasetConfig, SampleSpec
from bench.dataset.sample import SimulatedSample, sample_recorder, simulate_sample
from bench.ladder.config import LadderConfig
from bench.ladder.rungs import Rung, render_groups, stage_off
from bench.study.report import wilson_interval
from renderers.camera_twin import pixel_gain
from renderers.frame_sampling import FrameSampling
from renderers.frames import FrameRecorder
from renderers.twin_recorder import TwinRecorder
from scenes.branch_reach import gap_of_branch
from scenes.profile import CameraProfile, load_profile
from scenes.vegetation import build_vegetation


def dataset_config(config: LadderConfig) -> DatasetConfig:
    """The twin and the branch sample: outdoor, one pass, the ladder's step and profile."""
    return DatasetConfig(
        foliage=(config.foliage,),
        distances=(config.distance,),
        branches=((), (config.branch_mm,)),
        protocols=("outdoor",),
        passes=1,
        frames_step=config.frames_step,
        seed=config.seed,
        camera=load_profile(config.profile),
    )


def sampling_of(options: dict) -> FrameSampling:
    return FrameSampling(
        marker_spp=options["marker_spp"],
        background_spp=options["background_spp"],
        full_frame=options["full_frame"],
        integrator=options["integrator"],
        path_depth=max(1, options["path_depth"]),
    )


class Replay:
    """Records radiance that ``source`` rendered through another profile (a camera-stage rung):
    the per-pixel optics the renderer applied are swapped for ``profile``'s, then a
    :class:`~renderers.twin_recorder.TwinRecorder` records it, with the sample's own noise seed."""

    def __init__(self, source: FrameRecorder, profile: CameraProfile, noise_seed: int) -> None:
        region = source.renderer.region
        origin = (region.x0, region.y0)
        ours = pixel_gain(profile, origin, region.shape)
        theirs = pixel_gain(source.profile, origin, region.shape)
        ratio = np.divide(ours, theirs, out=np.zeros_like(ours), where=theirs > 0)
        self.gain = None if np.array_equal(ours, theirs) else ratio[..., None]
        band = source.renderer.band
        self.twin = TwinRecorder(profile, region, band, source.exposure, noise_seed)

    def record(self, radiance: np.ndarray) -> np.ndarray:
        return self.twin.record(radiance if self.gain is None else radiance * self.gain)


class _Writers:
    """One encoder thread per video, fed frame by frame (a clip never sits in memory)."""

    def __init__(self, paths: list[Path], fps: float) -> None:
        from bench.common.video import write_video

        self.queues = [queue.Queue(maxsize=2) for _ in paths]
        self.errors: list[BaseException] = []

        def frames(q: queue.Queue):
            while (frame := q.get()) is not None:
                yield frame

        def encode(path: Path, q: queue.Queue) -> None:
            try:
                write_video(path, frames(q), fps)
            except BaseException as exc:  # re-raised by close()
                self.errors.append(exc)
                for _ in frames(q):  # keep draining so the producer never blocks
                    pass

        pairs = zip(paths, self.queues, strict=True)
        self.threads = [threading.Thread(target=encode, args=pair) for pair in pairs]
        for t in self.threads:
            t.start()

    def put(self, frames: list[np.ndarray]) -> None:
        for q, frame in zip(self.queues, frames, strict=True):
            q.put(frame)

    def close(self) -> None:
        for q in self.queues:
            q.put(None)
        for t in self.threads:
            t.join()
        if self.errors:
            raise self.errors[0]


@dataclass(frozen=True)
class VideoTask:
    """One render setting and the rungs recorded from it (picklable)."""

    config: LadderConfig
    rungs: tuple[Rung, ...]
    out_dir: Path
    settings: str  # the ladder's settings hash, in each rung's record


def result_path(out_dir: Path, rung: Rung) -> Path:
    return out_dir / "video" / rung.key / "result.json"


def video_tasks(config: LadderConfig, rungs: list[Rung], out_dir: Path) -> list[VideoTask]:
    """One task per render setting with an unfinished rung."""
    tasks, settings = [], config.settings_hash()
    for group in render_groups(rungs):
        todo = tuple(
            r
            for r in group
            if unit_state(result_path(out_dir, r), settings, {"unit": r.key}) != DONE
        )
        if todo:
            tasks.append(VideoTask(config, todo, out_dir, settings))
    return tasks


def _simulated(dataset: DatasetConfig, sample: SampleSpec, detail: str, cache: dict):
    """The sample's mechanics (once per worker), its vegetation at ``detail``."""
    key = ("sim", sample.sample_id, dataset.frames_step, dataset.seed)
    if key not in cache:
        cache[key] = simulate_sample(dataset, sample)
    sim: SimulatedSample = cache[key]
    return dataclasses.replace(
        sim, vegetation=build_vegetation(sim.vegetation.spec, dataset.array, detail)
    )


def _render(task: VideoTask, dataset: DatasetConfig, sample: SampleSpec, cache: dict) -> dict:
    """Render ``sample`` once and record it per rung: {rung key: seconds}, and its labels."""
    options = task.rungs[0].options
    sim = _simulated(dataset, sample, options["foliage_detail"], cache)
    draw_seed = dataset.seed + options["seed_offset"]
    recorder = sample_recorder(dataset, sample, sim, sampling_of(options), draw_seed)
    noise = sample.seeds(draw_seed)["noise"]
    replays = []
    for rung in task.rungs:
        stage = rung.options["stage_off"]
        profile = stage_off(dataset.twin, stage) if stage else dataset.twin
        replays.append(Replay(recorder, profile, noise))
    folder = task.out_dir / "video"
    paths = [folder / r.key / f"{sample.sample_id}.mp4" for r in task.rungs]
    writers = _Writers(paths, sim.motion.fps)
    try:
        for f in range(len(sim.times_s)):
            radiance = recorder.radiance(f)
            writers.put([r.record(radiance) for r in replays])
    finally:
        writers.close()
    seconds = {
        r.key: recorder.render_s + p.twin.optics_s + p.twin.sensor_s
        for r, p in zip(task.rungs, replays, strict=True)
    }
    return {"seconds": seconds, "labels": sim.labels, "frames": len(sim.times_s)}


def _score(task: VideoTask, rung: Rung, dataset: DatasetConfig, rendered: dict) -> dict:
    """The rung's pipeline on the twin (its threshold), then the branch sample; the markers of
    both scored together. A pipeline that refuses a sample (no free air at its start) gives the
    outcome ``refused``."""
    from bench.evaluate.detect import run_detect
    from bench.evaluate.score import SAME_LAYOUT_TWIN, branch_outcome, score_markers
    from pipeline.branches import foliage_threshold
    from pipeline.deflection import NoBaselineError
    from pipeline.presets import get_pipeline

    pipeline = get_pipeline(task.config.pipeline)
    # the same free-air time as at the full frame rate: every frames_step-th frame is rendered
    step = dataset.frames_step
    pipeline = dataclasses.replace(
        pipeline, baseline_frames=max(1, round(pipeline.baseline_frames / step))
    )
    folder = task.out_dir / "video" / rung.key
    twin, branch = dataset.samples()
    threshold, results, detections, labels = None, {}, [], []
    t0 = time.perf_counter()
    for sample in (twin, branch):
        video = folder / f"{sample.sample_id}.mp4"
        try:
            results[sample] = run_detect(
                video, dataset.camera.lens, pipeline, folder / sample.sample_id, threshold,
                array=dataset.array,
            )  # fmt: skip
        except NoBaselineError as exc:
            return {"branch_outcome": "refused", "refused_reason": str(exc)}
        found = pd.read_parquet(folder / sample.sample_id / "detections.parquet")
        if sample is twin and pipeline.threshold == "fixed":
            threshold = foliage_threshold(found["deflection_mm"].to_numpy())
        offset = len(labels) and rendered[twin]["frames"]  # the branch clip after the twin's
        detections.append(found.assign(frame=found["frame"] + offset))
        truth = rendered[sample]["labels"]
        labels.append(truth.assign(frame=truth["frame"] + offset))
    foreign = sum(r["foreign_ids"] for r in results.values())
    scores = score_markers(pd.concat(detections), pd.concat(labels), foreign)
    estimated = [b["gap"] for b in results[branch]["branches"]]
    true_gaps = [gap_of_branch(b, branch.distance, dataset.array) for b in branch.branches_mm]
    outcome = branch_outcome(estimated, true_gaps)
    lo, hi = wilson_interval(scores["markers_found"], scores["markers_visible"])
    return {
        "n": scores["markers_visible"],
        "rate": scores["recall"],
        "rate_lo": float(lo),
        "rate_hi": float(hi),
        "corner_err_px": scores["corner_err_px"],
        "rot_err_deg": scores["rot_err_deg"],
        "trans_err_mm": scores["trans_err_mm"],
        "branch_outcome": outcome["outcome"],
        "estimated_gaps": estimated,
        "threshold_mm": results[branch]["threshold_mm"],
        "threshold_source": SAME_LAYOUT_TWIN if threshold is not None else "online",
        "pipeline_s": time.perf_counter() - t0,
    }


def run_video_task(task: VideoTask, cache: dict) -> VideoTask:
    """Render both samples once, record and score every rung of the task: ``result.json``."""
    dataset = dataset_config(task.config)
    rendered = {s: _render(task, dataset, s, cache) for s in dataset.samples()}
    for rung in task.rungs:
        record = _score(task, rung, dataset, rendered)
        write_unit(
            result_path(task.out_dir, rung),
            {
                "unit": rung.key,
                "settings_sha256": task.settings,
                "files": {},  # the record is the result: its own hash pins it
                **record,
                "samples": [s.sample_id for s in rendered],
                "frames": sum(r["frames"] for r in rendered.values()),
                "wall_s": sum(r["seconds"][rung.key] for r in rendered.values()),
            },
        )
    return task
