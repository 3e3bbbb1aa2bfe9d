"""A worker process that dies with its parent, SIGKILL included, and leaves Ctrl-C to it.

Used by the bench's process pools and by the detector backends' worker processes
(:mod:`pipeline.backends.isolated`): an orphaned worker would hold cores and memory forever.
"""

from __future__ import annotations

import ctypes
import os
import signal
import sys
import threading
import time

PR_SET_PDEATHSIG = 1  # from <linux/prctl.h>
#: How often a worker's watch thread checks that its parent is alive (s).
PARENT_POLL_S = 0.2


def exit_with_parent(parent_pid: int) -> None:
    """End this process as soon as ``parent_pid`` is no longer its parent (the parent died).

    The kernel's parent-death signal acts at once but exists on Linux only, and fires when the
    thread that started this process exits; the watch thread covers other systems, and a parent
    that died before the signal was armed is caught by the first check.
    """
    if sys.platform.startswith("linux"):
        try:
            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
        except (OSError, AttributeError):
            pass  # no prctl: the watch thread alone
    if os.getppid() != parent_pid:
        os._exit(1)

    def watch() -> None:
        while os.getppid() == parent_pid:
            time.sleep(PARENT_POLL_S)
        os._exit(1)

    threading.Thread(target=watch, name="parent-watch", daemon=True).start()


_ctrl_c_seen = False


def _note_ctrl_c(_signum: int, _frame: object) -> None:
    global _ctrl_c_seen
    _ctrl_c_seen = True


def leave_ctrl_c_to_parent() -> None:
    """Ctrl-C reaches every process of the terminal's group; let it interrupt the parent only.

    A worker it interrupted mid-task would take the KeyboardInterrupt as that task's error and go
    on to the next task in whatever state the interruption left, or finish a task whose library
    swallowed it (a study cell was written after Ctrl-C with other column types); a detector's
    worker would die and leave its failures in the results. Here the worker only notes it
    (:func:`ctrl_c_seen`): the task running finishes whole, no other starts. A handler, unlike
    SIG_IGN, is not inherited by the programs a worker starts (ffmpeg), which still stop.
    """
    signal.signal(signal.SIGINT, _note_ctrl_c)


def ctrl_c_seen() -> bool:
    """Whether this worker has had a Ctrl-C since :func:`leave_ctrl_c_to_parent`."""
    return _ctrl_c_seen
