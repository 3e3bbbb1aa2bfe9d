"""How a command ends when it does not end by itself: the short bug report of an internal
error (or one line for a detector backend's own failure, a plugin's: not the project's bug), one
line for a failure of the environment (a full disk, a permission, a name too long),
and a quiet end when the reader of stdout goes away early (``| head -1``)."""

from __future__ import annotations

import contextlib
import errno
import faulthandler
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


def prepare_streams() -> None:
    """stdout that prints any path (:func:`printable_stdout`), and a crash in native code (a
    segfault in Dr.Jit, OpenCV, a peer) that prints the Python stack, what a report needs
    (``faulthandler``; not where stderr is closed or a capture without a file)."""
    printable_stdout()
    with contextlib.suppress(RuntimeError, ValueError, OSError):  # RuntimeError: stderr None
        faulthandler.enable()


def printable_stdout() -> None:
    """Let stdout print any path: a character its encoding lacks (``PYTHONIOENCODING=ascii``,
    a Latin-1 terminal) is escaped, as stderr's are, instead of failing after all the work."""
    reconfigure = getattr(sys.stdout, "reconfigure", None)  # None: a test's capture, or closed
    if reconfigure is not None:
        reconfigure(errors="backslashreplace")


def end_quietly() -> int:
    """:data:`STDOUT_CLOSED`, once stdout points at /dev/null: the interpreter flushes stdout
    again at exit, which would otherwise print a second error."""
    os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
    return STDOUT_CLOSED


#: What to do about the commonest environment failures, after the system's own words.
_ADVICE = {
    errno.ENOSPC: "free some space there and rerun the same command",
    errno.EDQUOT: "the disk quota is used up; free some and rerun the same command",
    errno.EACCES: "this user may not write or read there",
    errno.EPERM: "not permitted: an immutable or append-only file (lsattr) or a protected folder",
    errno.EROFS: "a read-only file system",
    errno.ENAMETOOLONG: "each name may have at most 255 bytes, a path 4096",
    errno.ELOOP: "symbolic links that point at each other",
    errno.EMFILE: "too many open files (ulimit -n)",
}


def environment_failure(command: str, exc: BaseException, kept: str) -> str | None:
    """One line for a failure of the system, not of the tool: an ``OSError`` with an errno,
    naming the path and the cause (and what was kept), or a file name that is not UTF-8 text;
    None for anything else (a bug). A broken pipe other than stdout's stays a bug (a worker's
    pipe: :func:`stdout_closed`)."""
    if isinstance(exc, UnicodeEncodeError) and "surrogate" in exc.reason:
        name = exc.object[max(exc.start - 40, 0) : exc.end + 40]
        return (
            f"whiskerbench {command}: error: {name!r}: a file name that is not valid UTF-8 text "
            f"(paths are recorded as UTF-8); rename it; {kept}"
        )
    if not isinstance(exc, OSError) or exc.errno is None or isinstance(exc, BrokenPipeError):
        return None
    paths = [os.fsdecode(p) for p in (exc.filename, exc.filename2) if p is not None]
    where = " -> ".join(paths) if paths else "writing the outputs"
    cause = exc.strerror or os.strerror(exc.errno)
    name = errno.errorcode.get(exc.errno, str(exc.errno))
    advice = f"; {_ADVICE[exc.errno]}" if exc.errno in _ADVICE else ""
    return f"whiskerbench {command}: error: {where}: {cause} ({name}){advice}; {kept}"


def undecodable_argument(argv: list[str]) -> str | None:
    """One line's detail for the first command-line argument that is not valid UTF-8 text (a
    file name in another encoding arrives with surrogates), naming its option: OpenCV crashes
    on such a path and the manifests could not record it, so it is refused before any work.
    None when every argument is UTF-8."""
    for i, arg in enumerate(argv):
        try:
            arg.encode("utf-8")
        except UnicodeEncodeError:
            option, _, value = arg.partition("=") if arg.startswith("--") else ("", "", arg)
            if not option and i > 0 and argv[i - 1].startswith("-"):
                option = argv[i - 1]
            return (
                f"{option or 'argument'}: {value!r}: not valid UTF-8 text; rename it (OpenCV "
                "cannot open such a path, and the manifests record paths as UTF-8)"
            )
    return None
