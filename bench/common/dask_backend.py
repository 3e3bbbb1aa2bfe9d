"""The Dask backend of :class:`bench.common.executor.TaskPool`: tasks on dask.distributed workers.

A ``LocalCluster`` on 127.0.0.1 (``workers`` processes, one thread each) or the cluster behind a
scheduler address. Tasks are idempotent and write their outputs atomically, so Dask may rerun
the tasks of a worker that died; nothing here retries by hand. The per-worker context is built
on the worker's first task of a pool (a slot keyed by the pool) and kept for the next ones, as
the process pool's initializer does; a worker keeps one pool's context at a time.

Imported only when the Dask backend is chosen: ``distributed`` is slow to import.
"""

from __future__ import annotations

import asyncio
import threading
import time
import uuid
from collections.abc import Callable, Iterable, Iterator
from typing import Any

from distributed import Client, LocalCluster, as_completed

from bench.common.executor import CONNECT_TIMEOUT_S

_slot: tuple[str, Any] | None = None  # (pool key, its context) in a worker process
_slot_lock = threading.Lock()
#: How often :func:`scheduler_workers` asks a scheduler whether a worker has joined (s).
WORKER_POLL_S = 0.2


def scheduler_workers(address: str, timeout_s: float) -> int:
    """How many workers the Dask scheduler at ``address`` has, waiting up to ``timeout_s``.

    Asked over Dask's own RPC (``identity``), not through a ``Client``: a client whose
    handshake failed stays half-made and, when collected, waits to close for longer than the
    deadline and prints a traceback. 0 when a scheduler answered but no worker joined it by the
    deadline; TimeoutError when nothing answered; ConnectionError naming the client's error when
    the peer answered but not as a Dask scheduler (junk bytes, another protocol).
    """
    from distributed.core import rpc

    deadline = time.monotonic() + timeout_s
    answered = False

    async def ask() -> int:
        nonlocal answered
        async with rpc(address, timeout=timeout_s) as scheduler:
            while True:
                info = await scheduler.identity()
                if not isinstance(info, dict) or info.get("type") != "Scheduler":
                    raise ConnectionError("the peer answered, but not as a Dask scheduler")
                answered = True
                if info.get("workers") or time.monotonic() >= deadline - WORKER_POLL_S:
                    return len(info.get("workers") or {})
                await asyncio.sleep(WORKER_POLL_S)

    try:
        return asyncio.run(asyncio.wait_for(ask(), timeout_s))
    except TimeoutError:  # asyncio.TimeoutError is TimeoutError
        if answered:  # a scheduler, no worker by the deadline
            return 0
        raise TimeoutError("no reply") from None
    except Exception as exc:  # words only: the traceback would keep the connection alive
        raise ConnectionError(f"{type(exc).__name__}: {exc}") from None


def _run_on_worker(
    key: str, setup: Callable[..., Any] | None, setup_args: tuple, fn: Callable, task: Any
) -> Any:
    global _slot
    with _slot_lock:
        if _slot is None or _slot[0] != key:
            _slot = (key, setup(*setup_args) if setup is not None else None)
        context = _slot[1]
    return fn(task, context)


class DaskBackend:
    """A client on a new LocalCluster of ``workers`` processes, or on ``scheduler``."""

    def __init__(
        self,
        workers: int,
        setup: Callable[..., Any] | None,
        setup_args: tuple,
        scheduler: str | None = None,
    ) -> None:
        self._cluster = None
        if scheduler is None:
            self._cluster = LocalCluster(
                n_workers=workers,
                threads_per_worker=1,
                processes=True,
                host="127.0.0.1",
                dashboard_address=None,
                memory_limit=0,  # the CLI's limits budget memory, as for the process pool
            )
            scheduler = self._cluster.scheduler_address
        self.client = Client(scheduler, timeout=CONNECT_TIMEOUT_S)
        self._key = uuid.uuid4().hex
        self._setup = setup
        self._setup_args = setup_args

    def run_all(self, fn: Callable[[Any, Any], Any], tasks: Iterable[Any]) -> Iterator[Any]:
        """Yield ``fn(task, context)`` for each task as it completes; cancel the rest on error."""
        futures = [
            self.client.submit(
                _run_on_worker, self._key, self._setup, self._setup_args, fn, task, pure=False
            )
            for task in tasks
        ]
        try:
            for future in as_completed(futures):
                yield future.result()
        except BaseException:
            self.client.cancel(futures)
            raise

    def close(self) -> None:
        self.client.close()
        if self._cluster is not None:
            self._cluster.close()
