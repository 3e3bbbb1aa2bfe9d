"""A worker process that dies with its parent, SIGKILL included.

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
