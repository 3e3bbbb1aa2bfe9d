"""The Dask backend of :class:`bench.common.executor.TaskPool`: tasks on dask.distributed workers.

A ``LocalCluster`` on 127.0.0.1 (``workers`` processes, one thread each) or the cluster behind a
scheduler address. Tasks are idempotent and write their outputs atomically, so Dask may rerun
the tasks of a worker that died; nothing here retries by hand. The per-worker context is built
on the worker's first task of a pool (a slot keyed by the pool) and kept for the next ones, as
the process pool's initializer does; a worker keeps one pool's context at a time.

Imported only when the Dask backend is chosen: ``distributed`` is slow to import.
"""

from __future__ import annotations

import contextlib
import threading
import time
import uuid
from collections.abc import Callable, Iterable, Iterator
from typing import Any

from distributed import Client, LocalCluster, as_completed

from bench.common.executor import CONNECT_TIMEOUT_S

_slot: tuple[str, Any] | None = None  # (pool key, its context) in a worker process
_slot_lock = threading.Lock()


def scheduler_workers(address: str, timeout_s: float) -> int:
    """How many workers the Dask scheduler at ``address`` has, waiting up to ``timeout_s``.

    Bounded even when the peer accepts TCP and never answers: ``Client(timeout=...)`` then
    waits on the handshake for ever, so the client runs in a daemon thread that is abandoned at
    the deadline (it holds a socket until the process exits, nothing else). 0 when a scheduler
    answered but no worker joined it by the deadline; TimeoutError when nothing answered as a
    Dask scheduler; the client's own error when the peer answered but not as a scheduler.
    """
    deadline = time.monotonic() + timeout_s
    result: dict[str, Any] = {}
    done = threading.Event()

    def probe() -> None:
        try:
            with Client(address, timeout=timeout_s, set_as_default=False) as client:
                result["connected"] = True
                with contextlib.suppress(TimeoutError):  # none by the deadline: counted below
                    client.wait_for_workers(1, timeout=max(deadline - time.monotonic(), 0.01))
                result["workers"] = len(client.scheduler_info()["workers"])
        except Exception as exc:  # handed to the caller's thread
            result["error"] = exc
        finally:
            done.set()

    threading.Thread(target=probe, name=f"probe {address}", daemon=True).start()
    done.wait(timeout_s)
    if "workers" in result or "connected" in result:  # a scheduler, maybe closing at the deadline
        return result.get("workers", 0)
    if "error" in result:
        raise result["error"]
    raise TimeoutError("no reply")


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
