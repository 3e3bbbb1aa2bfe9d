"""Atomic file output: write to a temporary file beside the target, then rename over it.

A crash or Ctrl-C leaves either the old file or the new one, never half of one; the temporary
file is removed on failure. A SIGKILL cannot remove it, so its name says whose it is
(``.<name>.<pid>.tmp-<random><suffix>``) and :func:`clean_stale` deletes those of dead processes.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
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
        prefix=f".{path.name}.{os.getpid()}.tmp-", suffix=path.suffix, dir=path.parent
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


_TEMP_NAME = re.compile(r"^\..+\.(?P<pid>[0-9]+)\.tmp-[A-Za-z0-9_]+(\.[^.]+)?$")


def clean_stale(folder: Path) -> list[Path]:
    """Delete the temporary files under ``folder`` (any depth) left by processes no longer alive.

    A killed run leaves them behind; a live process's files (another run writing there now)
    are kept. Returns what was deleted.
    """
    removed = []
    for path in sorted(Path(folder).rglob(".*.tmp-*")):
        match = _TEMP_NAME.match(path.name)
        if match and path.is_file() and not _alive(int(match["pid"])):
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
