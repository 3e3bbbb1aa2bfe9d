"""Run independent, idempotent tasks in-process or on a local process pool.

Each task is a pure function of its arguments that writes its own output atomically, so a
task can run anywhere, twice, or be skipped when its output exists; a Dask client's ``map``
would slot in here the same way.
"""

from __future__ import annotations

import multiprocessing
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ProcessPoolExecutor, as_completed
from typing import Any, TypeVar

from tqdm import tqdm

T = TypeVar("T")


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
    """Yield ``fn(task)`` for each task (in completion order), with a progress bar."""
    tasks = list(tasks)
    bar = tqdm(total=len(tasks), desc=desc, unit=unit, disable=not progress, smoothing=0.1)
    try:
        if workers <= 1:
            if initializer is not None:
                initializer(*initargs)
            for task in tasks:
                yield fn(task)
                bar.update()
            return
        ctx = multiprocessing.get_context("spawn")
        with ProcessPoolExecutor(
            workers, mp_context=ctx, initializer=initializer, initargs=initargs
        ) as pool:
            futures = [pool.submit(fn, task) for task in tasks]
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
