"""Atomic file output: write to a temporary file beside the target, then rename over it.

A crash or Ctrl-C leaves either the old file or the new one, never half of one; the temporary
file is removed on failure. A SIGKILL cannot remove it, so its name says whose it is: the run's
id (:func:`run_id`, shared by the run's worker processes) and the writer's pid
(``.<name>.<run>-<pid>.tmp-<random><suffix>``). :func:`clean_stale` deletes, at the top level of
one folder only, those of other runs whose writer is dead: a user's file that merely looks like
one, or one in a folder the run does not write, is never touched.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import secrets
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any


@contextlib.contextmanager
def atomic_path(path: Path) -> Iterator[Path]:
    """Yield a temporary path (same folder and suffix) that replaces ``path`` on success."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    # the target's suffix kept last: writers (video, images) pick the format from it
    fd, tmp = tempfile.mkstemp(
        prefix=f".{path.name}.{run_id()}-{os.getpid()}.tmp-", suffix=path.suffix, dir=path.parent
    )
    os.close(fd)
    try:
        yield Path(tmp)
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes 0600; a finished file gets the usual
        os.replace(tmp, path)
    except OSError as exc:
        if exc.filename is None and exc.errno is not None:  # a write's error names no file
            raise OSError(exc.errno, exc.strerror, str(path)) from exc
        raise
    finally:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)


#: The environment variable that carries the run's id to the run's worker processes.
RUN_ID_ENV = "WHISKERBENCH_RUN_ID"
_RUN_ID = re.compile(r"[0-9a-f]{12}")
_TEMP_NAME = re.compile(
    r"^\..+\.(?P<run>[0-9a-f]{12})-(?P<pid>[0-9]+)\.tmp-[A-Za-z0-9_]+(\.[^.]+)?$"
)


def run_id() -> str:
    """This run's id: the one :func:`new_run_id` set (inherited by worker processes), else a
    new one for this process."""
    current = os.environ.get(RUN_ID_ENV, "")
    return current if _RUN_ID.fullmatch(current) else new_run_id()


def new_run_id() -> str:
    """Start a new run in this process: a fresh id, handed to the workers it starts after."""
    os.environ[RUN_ID_ENV] = secrets.token_hex(6)
    return os.environ[RUN_ID_ENV]


def clean_stale(folder: Path) -> list[Path]:
    """Delete the temporary files at the top level of ``folder`` (not below) left by dead
    writers of other runs; return what was deleted.

    A killed run leaves them behind; this run's, and a live process's (a killed run's worker
    that has not yet noticed), are kept.
    """
    removed = []
    ours = run_id()
    try:
        entries = sorted(Path(folder).iterdir())
    except (FileNotFoundError, NotADirectoryError):
        return removed
    for path in entries:
        match = _TEMP_NAME.match(path.name)
        if match is None or match["run"] == ours or _alive(int(match["pid"])):
            continue
        if path.is_file() and not path.is_symlink():
            with contextlib.suppress(FileNotFoundError):
                path.unlink()
                removed.append(path)
    return removed


def _alive(pid: int) -> bool:
    """Whether ``pid`` runs; a zombie (killed, not yet reaped: its parent was killed too, and
    a container's init may never reap it) writes nothing more, so it counts as dead."""
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's process
        return True
    try:  # Linux: the state letter follows the parenthesized command name
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (OSError, IndexError):
        return True
    return state not in ("Z", "X")


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def write_bytes(path: Path, data: bytes) -> None:
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)


def write_json(path: Path, obj: Any) -> None:
    write_bytes(path, (json.dumps(obj, indent=2, sort_keys=True, default=str) + "\n").encode())


def check_writable(folder: Path) -> None:
    """Raise ValueError unless ``folder`` exists or can be made, and files can be written in it.

    Creates nothing that is not already there when the answer is no.
    """
    folder = Path(folder)
    existing = folder
    while not existing.exists():
        existing = existing.parent
    if not existing.is_dir() or not os.access(existing, os.W_OK | os.X_OK):
        raise ValueError(f"{folder}: not writable (nearest existing folder: {existing})")
    try:  # access() says yes to root everywhere; a real (vanishing) file says the truth
        with tempfile.TemporaryFile(dir=existing):
            pass
    except OSError as exc:
        raise ValueError(f"{folder}: not writable ({exc.strerror} in {existing})") from None
