"""Run independent, idempotent tasks in-process, on a local process pool, or on Dask.

Each task is a pure function of its arguments that writes its own output atomically, so a
task can run anywhere, twice, or be skipped when its output exists: the outputs do not depend
on the executor (:data:`EXECUTORS`; Dask's in :mod:`bench.common.dask_backend`). A
:class:`TaskPool` keeps its worker processes across several batches (e.g. a study's refinement
rounds), and with them what each built once: a pool's ``setup`` runs once per worker (once in
this process without workers), and what it returns, the worker's *context* (a loaded renderer,
say), is handed to every task: ``fn(task, context)``.

A process pool's workers die with their parent, SIGKILL included: on Linux the kernel kills
them when it exits (``PR_SET_PDEATHSIG``), and everywhere a thread in each worker exits it once
its parent is gone. Ctrl-C is the parent's to answer: a worker finishes the task it is running
and starts no other (:func:`pipeline.lifetime.leave_ctrl_c_to_parent`); to stop at once, end
the parent (``kill``): its workers die with it and the next run cleans up.
"""

from __future__ import annotations

import multiprocessing
import os
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ProcessPoolExecutor, as_completed
from typing import Any, TypeVar

from tqdm import tqdm

from pipeline.lifetime import ctrl_c_seen, exit_with_parent, leave_ctrl_c_to_parent

T = TypeVar("T")

#: inline: this process; pool: local worker processes; dask: a LocalCluster or a scheduler's.
EXECUTORS = ("inline", "pool", "dask")
#: Seconds to wait for a Dask scheduler to answer before giving up.
CONNECT_TIMEOUT_S = 10


# A worker process runs one pool's tasks: its context is set once, by _start_worker.
_worker_context: Any = None


def _start_worker(parent_pid: int, setup: Callable[..., Any] | None, setup_args: tuple) -> None:
    global _worker_context
    exit_with_parent(parent_pid)
    leave_ctrl_c_to_parent()
    _worker_context = setup(*setup_args) if setup is not None else None


def _run_in_worker(fn: Callable[[T, Any], Any], task: T) -> Any:
    if ctrl_c_seen():  # a task already queued when Ctrl-C came: not started
        raise KeyboardInterrupt
    return fn(task, _worker_context)


def effective_executor(executor: str, workers: int, scheduler: str | None = None) -> str:
    """What runs the tasks: a scheduler means dask, a pool of one worker is this process."""
    if scheduler is not None:
        return "dask"
    if executor not in EXECUTORS:
        raise ValueError(f"executor: {executor!r}: choose one of {', '.join(EXECUTORS)}")
    return "inline" if executor == "pool" and workers <= 1 else executor


class TaskPool:
    """Tasks on ``executor`` (:data:`EXECUTORS`), its workers started once for every batch.

    ``pool``: ``workers`` processes (``spawn``), or this process when ``workers <= 1``;
    ``dask``: a LocalCluster of ``workers`` processes, or the cluster of ``scheduler``
    (``tcp://host:port``). ``setup(*setup_args)`` builds each worker's context (None without
    ``setup``).
    """

    def __init__(
        self,
        workers: int = 1,
        setup: Callable[..., Any] | None = None,
        setup_args: tuple = (),
        executor: str = "pool",
        scheduler: str | None = None,
    ) -> None:
        self.workers = workers
        self.executor = effective_executor(executor, workers, scheduler)
        self.scheduler = scheduler
        self._pool = None
        self._dask = None
        self._context = None
        if self.executor == "dask":
            from bench.common.dask_backend import DaskBackend

            self._dask = DaskBackend(workers, setup, setup_args, scheduler)
            return
        if self.executor == "inline":
            self._context = setup(*setup_args) if setup is not None else None
            return
        self._pool = ProcessPoolExecutor(
            workers,
            mp_context=multiprocessing.get_context("spawn"),
            initializer=_start_worker,
            initargs=(os.getpid(), setup, setup_args),
        )

    def __enter__(self) -> TaskPool:
        return self

    def __exit__(self, *exc: object) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
        if self._dask is not None:
            self._dask.close()

    def describe(self) -> dict:
        """The manifest's record of what ran the tasks (never part of a settings hash)."""
        return {"executor": self.executor, "workers": self.workers, "scheduler": self.scheduler}

    def map(
        self,
        fn: Callable[[T, Any], Any],
        tasks: Iterable[T],
        desc: str = "tasks",
        progress: bool = True,
        unit: str = "cell",
    ) -> Iterator[Any]:
        """Yield ``fn(task, context)`` for each task (in completion order), with a progress bar.

        In a pool or on Dask ``fn`` must be importable (a module-level function) and tasks
        picklable.
        """
        tasks = list(tasks)
        bar = tqdm(total=len(tasks), desc=desc, unit=unit, disable=not progress, smoothing=0.1)
        try:
            if self._dask is not None:
                for result in self._dask.run_all(fn, tasks):
                    yield result
                    bar.update()
                return
            if self._pool is None:
                for task in tasks:
                    yield fn(task, self._context)
                    bar.update()
                return
            futures = [self._pool.submit(_run_in_worker, fn, task) for task in tasks]
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
