"""The machine's cores shared between the samples a local pool is making at the same time.

Dr.Jit runs each frame's kernels on a pool of threads. Two worker processes that each run one
thread per core put twice as many threads as cores on the machine, and each kernel then waits at
its end for threads the other process has descheduled: on 2 cores, two samples rendered side by
side took 202-212 ms a frame with 2 threads each and 179-185 ms with 1 each. One thread per core
per process is therefore what a worker uses while the others are busy; the worker left making the
last sample of a run takes every core again (with 3 quick samples on 2 workers, a third of the
run). ``docs/video_speed.md`` has the measurements.
"""

from __future__ import annotations

import os
import time
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

#: Frames between two looks at how many samples are still being made.
CHECK_EVERY_FRAMES = 8


@dataclass(frozen=True)
class CoreShare:
    """The cores of this machine split between the samples of one run still in progress.

    ``folders``: every sample folder the run makes; a sample is finished once its
    ``sample.json`` (written last) is newer than ``started`` (the run's start, seconds since the
    epoch), so a damaged sample being made again is not counted as finished.
    """

    folders: tuple[Path, ...]
    workers: int
    cores: int
    started: float

    def threads(self) -> int:
        """Threads for one sample: the cores over the samples that can run at once now."""
        unfinished = sum(not _written_since(f / "sample.json", self.started) for f in self.folders)
        running = max(1, min(self.workers, unfinished))
        return max(1, self.cores // running)


def core_share(
    executor: str, scheduler: str | None, folders: Iterable[Path], workers: int
) -> CoreShare | None:
    """The share of this machine's cores for a run's sample ``folders`` made by ``workers`` on
    ``executor`` (as :func:`bench.common.executor.effective_executor` names it): None inline
    (this process keeps every core) and on a scheduler's cluster (machines this process cannot
    see: each worker uses all of its own)."""
    if executor == "inline" or scheduler is not None:
        return None
    return CoreShare(tuple(folders), workers, os.cpu_count() or 1, time.time())


def _written_since(path: Path, started: float) -> bool:
    try:
        return path.stat().st_mtime >= started
    except OSError:
        return False
