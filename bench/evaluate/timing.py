"""Timing pipelines: alternating, repeated, frames/s as a median with its spread across rounds.

Shared by ``compare`` (on frames of the dataset it compares: :func:`dataset_runs`) and
``whiskerbench bench pipeline`` (on full frames of the busiest scene). The method
(``docs/speed.md``):

* the frames are *runs*: consecutive frames of one sample, tracked in order (ROI tracking sees
  real motion); the first frame of a run is its lead-in, tracked but not timed, so the tracker
  is locked on as it is for all but the first frame of a sample, and a peer's worker process
  starts outside the timing;
* the pipelines **alternate**: within a round each run is tracked by every pipeline in turn,
  and each round starts the turn one pipeline later. On a shared machine the load drifts; run
  one after another, a pipeline timed during a busy minute would look slow for reasons not its
  own, while alternating spreads the drift over all pipelines alike;
* the rounds **repeat**: a pipeline's frames/s of a round is its timed frames over its time on
  every run of that round; reported are the median over rounds (``fps``) and the slowest and
  fastest round (``fps_min``, ``fps_max``): a lead smaller than that spread could turn in another
  round (:func:`bench.evaluate.leaders.leaders`: ``lead_within_spread``).

Timing is keyed by pipeline name: a pipeline not timed here (another tool's results) has no
row, and its readers give it NaN (accuracy only). A pipeline whose backend fails
(:class:`pipeline.backends.BackendError`: a plugin that raises, answers outside its contract,
or crashes or hangs image after image) drops out of the rounds: its rows are left out (no
speed) and :attr:`Timing.failed` says why, while the others go on.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from time import perf_counter

import cv2
import numpy as np
import pandas as pd

from pipeline.backends import BackendError
from pipeline.presets import PipelineConfig
from pipeline.track import MarkerSet, TrackResult, track
from scenes.camera import FisheyeCamera

#: Timed frames of a run (after its lead-in frame): long enough that ROI tracking is timed as
#: it runs on a sample, short enough to spread ``compare``'s sample over several samples.
RUN_FRAMES = 10
#: ``compare``'s defaults: timed frames in all, and rounds.
SPEED_FRAMES = 40
SPEED_ROUNDS = 5
#: The per-round table's columns (``compare``'s ``speed_rounds.csv``).
ROUND_COLUMNS = ("round", "position", "pipeline", "frames", "seconds", "fps")
#: The per-pipeline figures' columns (:func:`speed_figures`).
SPEED_COLUMNS = ("fps", "fps_min", "fps_max", "speed_rounds")


@dataclass(frozen=True, eq=False)
class TimedRun:
    """Consecutive frames of one sample: ``images[0]`` is the lead-in (tracked, untimed).

    ``source``: the sample id; ``frame_ids``: each image's index in the sample's video;
    ``images``: (H, W) uint8 grey frames; ``camera`` and ``markers``: the sample's lens and
    array, as the pipeline is given them when it scores the sample."""

    source: str
    frame_ids: tuple[int, ...]
    images: tuple[np.ndarray, ...]
    camera: FisheyeCamera
    markers: MarkerSet

    @property
    def timed_frames(self) -> int:
        return len(self.images) - 1


@dataclass(frozen=True, eq=False)
class Timing:
    """What :func:`time_pipelines` measured: ``rounds``, one row per round and pipeline in
    the order they ran (:data:`ROUND_COLUMNS`; ``position``: the pipeline's turn in the
    round), each pipeline's detections on each run in the first round, and why each pipeline
    that failed did (``{name: reason}``, one line each; it has no rows)."""

    rounds: pd.DataFrame
    detections: dict[str, list[pd.DataFrame]]
    failed: dict[str, str] = field(default_factory=dict)


def plan_runs(
    lengths: Sequence[tuple[str, int]], frames: int, run_frames: int = RUN_FRAMES
) -> list[tuple[str, range]]:
    """Where to take up to ``frames`` timed frames from samples of ``lengths`` ((id, frame
    count), in the dataset's order): ``(sample id, frame indices)`` per run, a lead-in frame
    and up to ``run_frames`` timed frames each.

    The runs are spread evenly over the samples (run j goes to sample floor((j + 1/2) n / runs)
    of n) and, where a sample holds several, over its time: each the middle of an equal
    part of the sample. A sample too short for a run gives what it has; a sample of under 2
    frames (no timed frame after a lead-in) is passed over, so the total may fall short."""
    if frames < 1 or run_frames < 1:
        raise ValueError(f"need frames >= 1 and run_frames >= 1, got {frames}, {run_frames}")
    usable = [(sample_id, n) for sample_id, n in lengths if n >= 2]
    if not usable:
        return []
    runs = math.ceil(frames / run_frames)
    sizes = [run_frames] * (runs - 1) + [frames - (runs - 1) * run_frames]
    owner = [math.floor((j + 0.5) * len(usable) / runs) for j in range(runs)]
    plan = []
    for s, (sample_id, n) in enumerate(usable):
        mine = [sizes[j] for j in range(runs) if owner[j] == s]
        part = n // max(len(mine), 1)
        for i, size in enumerate(mine):
            length = min(size + 1, part)
            if length < 2:
                continue
            start = i * part + (part - length) // 2
            plan.append((sample_id, range(start, start + length)))
    return plan


def dataset_runs(
    dataset: Path, frames: int = SPEED_FRAMES, run_frames: int = RUN_FRAMES
) -> list[TimedRun]:
    """The runs of :func:`plan_runs` decoded from ``dataset``'s videos, each with its
    sample's lens (``camera.json``) and array (``sample.json``), as scoring reads them."""
    from bench.dataset.loader import open_dataset
    from bench.evaluate.score import _array
    from scenes.array import ArraySpec

    ds = open_dataset(dataset)
    samples = {sample_id: ds[sample_id] for sample_id in ds.sample_ids}
    lengths = [(sample_id, len(sample)) for sample_id, sample in samples.items()]
    runs = []
    for sample_id, indices in plan_runs(lengths, frames, run_frames):
        with samples[sample_id] as sample:
            images = tuple(sample.frame(i).image for i in indices)
            array = _array(sample.meta) or ArraySpec()
            markers = MarkerSet(array.marker_ids, array.marker_size_mm)
            runs.append(TimedRun(sample_id, tuple(indices), images, sample.camera, markers))
    return runs


def runs_table(runs: Sequence[TimedRun]) -> pd.DataFrame:
    """The frames timed, one row per frame: ``run``, ``sample_id``, ``frame`` (its index in
    the sample's video) and ``timed`` (False: the run's lead-in)."""
    rows = [
        {"run": k, "sample_id": run.source, "frame": f, "timed": i > 0}
        for k, run in enumerate(runs)
        for i, f in enumerate(run.frame_ids)
    ]
    return pd.DataFrame(rows, columns=["run", "sample_id", "frame", "timed"])


@contextmanager
def one_opencv_thread() -> Iterator[None]:
    """OpenCV on one thread inside the block (single-core speed), as it was after it."""
    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)
    try:
        yield
    finally:
        cv2.setNumThreads(threads)


def track_run(run: TimedRun, pipeline: PipelineConfig) -> TrackResult:
    """The pipeline's tracking (detection and pose of every frame, in order) on ``run``."""
    return track(
        run.images, run.camera, run.markers, pipeline.detector, pipeline.search,
        pipeline.pose_method,
    )  # fmt: skip


def timed_track(run: TimedRun, pipeline: PipelineConfig) -> tuple[float, TrackResult]:
    """(seconds from the end of the lead-in to the end of the run, the tracking result).

    The clock starts when tracking asks for the run's second frame: the lead-in frame (a
    full-frame search, a peer's worker start) is done, its result kept for the next frame."""
    if run.timed_frames < 1:
        raise ValueError(f"{run.source}: a run needs a frame after its lead-in")
    started: list[float] = []

    def frames() -> Iterator[np.ndarray]:
        yield run.images[0]
        started.append(perf_counter())
        yield from run.images[1:]

    result = track(
        frames(), run.camera, run.markers, pipeline.detector, pipeline.search,
        pipeline.pose_method,
    )  # fmt: skip
    return perf_counter() - started[0], result


def round_order(names: Sequence[str], round_index: int) -> list[str]:
    """The pipelines' turns in round ``round_index``: the list rotated by the round, so each
    pipeline goes first in turn."""
    k = round_index % len(names)
    return [*names[k:], *names[:k]]


def time_pipelines(
    runs: Sequence[TimedRun], pipelines: dict[str, PipelineConfig], rounds: int
) -> Timing:
    """Time every pipeline (``{name: config}``) on ``runs``, alternating, ``rounds`` times.

    In each round every run is tracked by every pipeline in :func:`round_order`; OpenCV runs
    on one thread (:func:`one_opencv_thread`; the peers' adapters use one of their own). A
    pipeline that fails (BackendError) drops out of the rounds: :attr:`Timing.failed`."""
    if rounds < 1 or not pipelines:
        raise ValueError(f"need rounds >= 1 and a pipeline, got {rounds} and {len(pipelines)}")
    if not any(run.timed_frames for run in runs):
        raise ValueError("no frames to time: no sample has 2 frames or more")
    names = list(pipelines)
    frames = sum(run.timed_frames for run in runs)
    rows, detections, failed = [], {name: [] for name in names}, {}
    with one_opencv_thread():
        for r in range(rounds):
            live = [n for n in names if n not in failed]
            if not live:  # every pipeline failed
                break
            order = round_order(live, r)
            seconds = dict.fromkeys(order, 0.0)
            for run in runs:
                for name in (n for n in order if n not in failed):
                    try:
                        elapsed, result = timed_track(run, pipelines[name])
                    except BackendError as exc:  # that pipeline's failure: the others go on
                        failed[name] = " ".join(str(exc).split())
                        continue
                    seconds[name] += elapsed
                    if r == 0:
                        detections[name].append(result.detections)
            rows += [
                dict(zip(ROUND_COLUMNS, (r, p, name, frames, seconds[name],
                                         frames / seconds[name]), strict=True))
                for p, name in enumerate(order)
                if name not in failed  # its earlier rounds too: left out below
            ]  # fmt: skip
    table = pd.DataFrame(rows, columns=list(ROUND_COLUMNS))
    table = table[~table["pipeline"].isin(failed)].reset_index(drop=True)
    kept = {name: found for name, found in detections.items() if name not in failed}
    return Timing(table, kept, failed)


def speed_figures(rounds: pd.DataFrame) -> pd.DataFrame:
    """Per pipeline (the index, in first-timed order): the median frames/s over rounds
    (``fps``), the slowest and fastest round (``fps_min``, ``fps_max``) and the rounds."""
    grouped = rounds.groupby("pipeline", sort=False)["fps"]
    figures = pd.DataFrame(
        {
            "fps": grouped.median(),
            "fps_min": grouped.min(),
            "fps_max": grouped.max(),
            "speed_rounds": grouped.size(),
        }
    )
    return figures.reindex(columns=list(SPEED_COLUMNS))


def speed_of(figures: pd.DataFrame, name: str) -> dict:
    """A pipeline's speed columns from :func:`speed_figures` as plain numbers, NaN where it was
    not timed (accuracy only)."""
    if name not in figures.index:
        return dict.fromkeys(SPEED_COLUMNS, float("nan"))
    row = figures.loc[name]
    return {
        **{c: float(row[c]) for c in SPEED_COLUMNS[:3]},
        "speed_rounds": int(row["speed_rounds"]),
    }
