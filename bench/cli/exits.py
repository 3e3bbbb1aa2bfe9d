"""How a command ends when it does not end by itself: the short bug report of an internal
error (or one line for a detector backend's own failure, a plugin's: not the project's bug),
and a quiet end when the reader of stdout goes away early (``| head -1``)."""

from __future__ import annotations

import os
import select
import signal
import sys
import traceback

#: Frames of the traceback an internal error's bug report shows.
BUG_REPORT_FRAMES = 4
#: The exit code of a command whose stdout was closed early: a shell's for SIGPIPE.
STDOUT_CLOSED = 128 + signal.SIGPIPE


def bug_report(command: str, exc: BaseException) -> str:
    """An internal error in a few lines: what, a request, and the innermost frames; a
    backend's failure (:class:`pipeline.backends.BackendError`, a plugin that raised or
    answered outside its contract) in one line naming it, with no request to report it."""
    from pipeline.backends import BackendError

    if isinstance(exc, BackendError):
        return f"whiskerbench {command}: error: {' '.join(str(exc).split())}"
    frames = traceback.extract_tb(exc.__traceback__)[-BUG_REPORT_FRAMES:]
    detail = str(exc).splitlines()[0] if str(exc) else ""
    return "\n".join(
        [
            f"whiskerbench {command}: internal error: {type(exc).__name__}: {detail}",
            "please report this with the command line; traceback:",
            *(f'  File "{f.filename}", line {f.lineno}, in {f.name}: {f.line}' for f in frames),
        ]
    )


def stdout_closed() -> bool:
    """Whether stdout is a pipe whose reader has gone (it polls as an error), so that a
    BrokenPipeError from anywhere else (a worker's pipe) is still reported as a bug."""
    try:
        poll = select.poll()
        poll.register(sys.stdout.fileno(), select.POLLOUT)
    except (OSError, ValueError):  # no file descriptor (a test's capture): not a pipe
        return False
    return any(events & select.POLLERR for _, events in poll.poll(0))


def end_quietly() -> int:
    """:data:`STDOUT_CLOSED`, once stdout points at /dev/null: the interpreter flushes stdout
    again at exit, which would otherwise print a second error."""
    os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
    return STDOUT_CLOSED
