"""Run independent, idempotent tasks in-process or on a local process pool.

Each task is a pure function of its arguments that writes its own output atomically, so a
task can run anywhere, twice, or be skipped when its output exists; a Dask client's ``map``
would slot in here the same way. A :class:`TaskPool` keeps its worker processes (and what they
loaded: Mitsuba, compiled kernels) across several batches, e.g. a study's refinement rounds.
"""

from __future__ import annotations

import multiprocessing
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ProcessPoolExecutor, as_completed
from typing import Any, TypeVar

from tqdm import tqdm

T = TypeVar("T")


class TaskPool:
    """``workers`` processes (``spawn``) started once, or this process when ``workers <= 1``."""

    def __init__(
        self,
        workers: int = 1,
        initializer: Callable[..., None] | None = None,
        initargs: tuple = (),
    ) -> None:
        self.workers = workers
        self._pool = None
        if workers <= 1:
            if initializer is not None:
                initializer(*initargs)
            return
        ctx = multiprocessing.get_context("spawn")
        self._pool = ProcessPoolExecutor(
            workers, mp_context=ctx, initializer=initializer, initargs=initargs
        )

    def __enter__(self) -> TaskPool:
        return self

    def __exit__(self, *exc: object) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)

    def map(
        self,
        fn: Callable[[T], Any],
        tasks: Iterable[T],
        desc: str = "tasks",
        progress: bool = True,
        unit: str = "cell",
    ) -> Iterator[Any]:
        """Yield ``fn(task)`` for each task (in completion order), with a progress bar."""
        tasks = list(tasks)
        bar = tqdm(total=len(tasks), desc=desc, unit=unit, disable=not progress, smoothing=0.1)
        try:
            if self._pool is None:
                for task in tasks:
                    yield fn(task)
                    bar.update()
                return
            futures = [self._pool.submit(fn, task) for task in tasks]
            try:
                for future in as_completed(futures):
                    yield future.result()
                    bar.update()
            except BaseException:
                for future in futures:
                    future.cancel()
                raise
        finally:
            bar.close()


def run_tasks(
    fn: Callable[[T], Any],
    tasks: Iterable[T],
    workers: int = 1,
    initializer: Callable[..., None] | None = None,
    initargs: tuple = (),
    desc: str = "tasks",
    progress: bool = True,
    unit: str = "cell",
) -> Iterator[Any]:
    """Yield ``fn(task)`` for each task (in completion order) on a pool of its own."""
    with TaskPool(workers, initializer, initargs) as pool:
        yield from pool.map(fn, tasks, desc, progress, unit)
