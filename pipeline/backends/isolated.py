"""Peer backends in a worker process: a crash in native code costs one image, not the run.

Some detector bindings corrupt the heap on some families (pupil-apriltags on tag16h5,
CAMERA_NOTES.md) and take the whole process down; a hung one never returns. A backend marked
``isolated`` therefore runs in a child process of its own (one per backend and parent process,
started on first use and kept): the image goes over a socket, the :class:`Found` comes back. If
the child dies or does not answer within :data:`TIMEOUT_S`, :func:`run_backend` raises
:class:`BackendCrashError` naming the backend and the image's fate, and the next image starts a
fresh child. A plugin (:mod:`pipeline.backends.plugin`) has its own limit
(:func:`pipeline.backends.plugin.timeout_s`) and a run of :data:`MAX_STRAIGHT_CRASHES` crashes
or hangs in a row stops it (:class:`BackendError`): a plugin that hangs on every image would
otherwise cost its limit on every frame. The child is a plain ``python -m`` process (not
``multiprocessing``, which refuses children of daemonic processes such as Dask's workers) and
dies with its parent.

The cost, measured by ``whiskerbench bench pipeline`` (peers' frames/s include it): one copy
of the image through the socket per call.
"""

from __future__ import annotations

import atexit
import os
import socket
import subprocess
import sys
from multiprocessing.connection import Connection
from pathlib import Path

import numpy as np

from pipeline.backends import (
    PLUGIN_PREFIX,
    Backend,
    BackendCrashError,
    BackendError,
    Found,
    PoseRequest,
    get_backend,
    require,
)

#: Longest a backend may take on one image before it counts as hung (s).
TIMEOUT_S = 120.0
#: glibc keeps large buffers instead of returning them to the system after every call: the
#: AprilTag library allocates ~100 MB per frame, and giving it back and taking it again made the
#: worker 1.23x slower than the same adapter in-process; with these, 1.015x (measured on one
#: full frame, alternating 8 rounds). Other C libraries ignore them.
ALLOCATOR_ENV = {"MALLOC_MMAP_THRESHOLD_": str(1 << 30), "MALLOC_TRIM_THRESHOLD_": str(1 << 30)}
_ROOT = Path(__file__).resolve().parents[2]  # the project, for the child's imports
#: Crashes or hangs in a row after which a plugin is stopped.
MAX_STRAIGHT_CRASHES = 3
#: How long a plugin's fresh worker may take to start and import the plugin (a model's
#: weights, say) before its first image: that is not the plugin hanging on an image.
STARTUP_S = 120.0


def _timeout_s(backend: Backend) -> float:
    if backend.name.startswith(PLUGIN_PREFIX):
        from pipeline.backends.plugin import timeout_s

        return timeout_s()
    return TIMEOUT_S


class _Worker:
    """One child process serving one backend for this process."""

    def __init__(self, backend: Backend) -> None:
        self.backend = backend
        self.owner = os.getpid()  # a forked copy of this object must not use the socket
        self.started = not backend.name.startswith(PLUGIN_PREFIX)  # a plugin: after a check
        parent, child = socket.socketpair()
        path = os.pathsep.join(filter(None, [str(_ROOT), os.environ.get("PYTHONPATH")]))
        env = dict(os.environ, PYTHONPATH=path, **ALLOCATOR_ENV)
        if not self.started:  # a plugin: on one core, as the pipelines are timed
            from pipeline.backends.plugin import ONE_THREAD_ENV

            env.update(ONE_THREAD_ENV)
        self.process = subprocess.Popen(
            [sys.executable, "-m", "pipeline.backends.isolated", str(child.fileno()),
             str(os.getpid())],
            pass_fds=(child.fileno(),), env=env, stdin=subprocess.DEVNULL,
        )  # fmt: skip
        child.close()
        self.conn = Connection(parent.detach())

    def call(self, image: np.ndarray, config, side: int, pose: PoseRequest | None) -> Found:
        limit = _timeout_s(self.backend)
        try:
            if not self.started:  # imports the plugin, within STARTUP_S, not the image's limit
                self.conn.send(self.backend.name)
                if not self.conn.poll(STARTUP_S):
                    self.close()
                    raise BackendCrashError(
                        f"detector {self.backend.name} did not start within {STARTUP_S:g} s; "
                        "its worker was stopped"
                    )
                status, value = self.conn.recv()
                if status != "ok":  # the plugin does not resolve in the worker
                    raise BackendError(f"detector {self.backend.name}: in its worker: {value}")
                self.started = True
            self.conn.send((self.backend, config, side, pose, image.shape))
            self.conn.send_bytes(memoryview(image).cast("B"))
            if not self.conn.poll(limit):
                self.close()
                raise BackendCrashError(
                    f"detector {self.backend.name} did not answer within {limit:g} s on a "
                    f"{image.shape[1]}x{image.shape[0]} image; its worker was stopped"
                )
            status, value = self.conn.recv()
        except (EOFError, OSError):
            code = self.process.wait()
            self.close()
            how = f"signal {-code}" if code < 0 else f"exit status {code}"
            raise BackendCrashError(
                f"detector {self.backend.name} crashed ({how}) on a "
                f"{image.shape[1]}x{image.shape[0]} image; a fresh worker takes the next"
            ) from None
        if status == "error":
            raise BackendError(f"detector {self.backend.name}: {value}")
        if status == "failed":  # its own words name it
            raise BackendError(value)
        return value

    def close(self) -> None:
        if self.owner != os.getpid():
            return
        try:
            self.conn.close()
        finally:
            if self.process.poll() is None:
                self.process.kill()
                self.process.wait()


_workers: dict[str, _Worker] = {}
_straight_crashes: dict[str, int] = {}  # backend -> crashes and hangs in a row


def run_backend(
    image: np.ndarray, config, frame_side_px: int, pose: PoseRequest | None = None
) -> Found:
    """The backend's :class:`Found` for ``image``: in this process for ``opencv``, in the
    backend's worker process for the peers."""
    backend = get_backend(config.backend)
    if not backend.isolated:
        return backend.detect(image, config, frame_side_px, pose)
    require(backend.name)  # not installed: say so here, before starting a process
    worker = _workers.get(backend.name)
    if worker is None or worker.owner != os.getpid() or worker.process.poll() is not None:
        worker = _workers[backend.name] = _Worker(backend)
    try:
        found = worker.call(image, config, frame_side_px, pose)
    except BackendCrashError as exc:
        del _workers[backend.name]
        crashes = _straight_crashes[backend.name] = _straight_crashes.get(backend.name, 0) + 1
        if backend.name.startswith(PLUGIN_PREFIX) and crashes >= MAX_STRAIGHT_CRASHES:
            _straight_crashes[backend.name] = 0
            raise BackendError(
                f"detector {backend.name} crashed or hung on {crashes} images in a row, "
                f"stopped; the last: {exc}"
            ) from None
        raise
    _straight_crashes[backend.name] = 0
    return found


@atexit.register
def stop_workers() -> None:
    """Stop this process's backend workers (they would also die with it)."""
    for worker in _workers.values():
        worker.close()
    _workers.clear()


def _serve(conn: Connection) -> None:
    """The child's loop: an image in, its Found (or the Python error) out, until EOF; a
    backend's name alone: load it (a plugin's import) and say whether it loaded."""
    while True:
        try:
            message = conn.recv()
            if isinstance(message, str):  # a plugin's start
                try:
                    from pipeline.backends.plugin import one_thread

                    one_thread()
                    get_backend(message)
                    conn.send(("ok", None))
                except ValueError as exc:
                    conn.send(("failed", " ".join(str(exc).split())))
                continue
            backend, config, side, pose, shape = message
            buffer = conn.recv_bytes()
        except EOFError:
            return
        image = np.frombuffer(buffer, np.uint8).reshape(shape)
        try:
            result = ("ok", backend.detect(image, config, side, pose))
        except BackendError as exc:  # a plugin's failure, in its own words
            result = ("failed", " ".join(str(exc).split()))
        except Exception as exc:  # noqa: BLE001 - reported to the parent, which raises it
            result = ("error", " ".join(f"{type(exc).__name__}: {exc}".split()))
        conn.send(result)


if __name__ == "__main__":
    from pipeline.lifetime import exit_with_parent, leave_ctrl_c_to_parent

    exit_with_parent(int(sys.argv[2]))
    leave_ctrl_c_to_parent()
    _serve(Connection(int(sys.argv[1])))
