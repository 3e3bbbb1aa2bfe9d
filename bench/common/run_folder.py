"""A run folder is one run's at a time, and a command writes only what is its own.

Every command that writes a folder opens it with :func:`open_folder` before its first write:

* **Claim** (:func:`claim`, reads only, so a refusal writes nothing): the folder is writable,
  not a file or a special file, not a dangling symbolic link, and holds no other command's
  output. Its ``manifest.json`` says whose it is; when that is missing or truncated the lock
  file, which every run rewrites, still says it. (A user's ``--out`` is also checked against
  the command's inputs and the run folders above it, :func:`check_not_input` and
  :func:`check_not_owned`, by the command line: a run's own units lie inside its folder.)
* **Lock**: ``.whiskerbench.lock`` in the folder, held with ``flock`` for the whole run (the
  kernel lets go when the process dies, so a dead run's lock is taken over, never waited on).
  A second command on a locked folder is refused in one line naming the holder: pid, host,
  command line and start time. The file also keeps the last run's kind and settings hash.
* **Clean**: the temporary files of dead runs (:func:`bench.common.atomic.clean_stale`) at the
  top level of the folders the command writes, never deeper; a symbolic link there that leads
  out of the run folder is refused, since a write through it would land elsewhere.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import shlex
import socket
import sys
import time
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

from bench.common.atomic import check_writable, clean_stale, new_run_id, run_id
from bench.common.manifest import MANIFEST, kind_of, read_manifest
from scenes.bounded_read import read_json, special_kind
from scenes.input_limits import RECORD_BYTES, RECORD_DEPTH
from scenes.validation import FieldError

#: The lock file of a run folder.
LOCK = ".whiskerbench.lock"
#: Folders in which a run keeps its units; never another command's to write into.
UNIT_FOLDERS = ("cells", "images", "study", "video", "grids")

_command_line: list[str] = []


class FolderBusyError(ValueError):
    """The folder is locked by another run (the message names it)."""


def set_command_line(argv: list[str]) -> None:
    """The command line a lock records: ``whiskerbench`` and ``argv`` (the CLI sets it)."""
    _command_line[:] = [shlex.join(["whiskerbench", *argv])]


def _this_command() -> str:
    return _command_line[0] if _command_line else shlex.join(sys.argv)


# -- checks that read only ------------------------------------------------------------------


def check_out_path(path: Path, folder: bool) -> None:
    """An output (a ``folder`` or a file) that may be written: ValueError in one line when it
    is a dangling symbolic link, a symbolic link out of its own folder (a file), a special file,
    or of the other type."""
    path = Path(path)
    if path.is_symlink():
        target = os.readlink(path)
        if not path.exists():
            raise ValueError(f"{path}: a dangling symbolic link (to {target}); remove it first")
        if not folder and path.resolve().parent != path.parent.resolve():
            raise ValueError(
                f"{path}: a symbolic link out of its folder (to {target}); writing it would "
                "replace the link: name the file itself"
            )
    special = special_kind(path)
    if special:
        raise ValueError(f"{path}: is {special}, not a {'folder' if folder else 'file'}")
    if path.exists() and folder and not path.is_dir():
        raise ValueError(f"{path}: is a file, not a folder")
    if path.exists() and not folder and path.is_dir():
        raise ValueError(f"{path}: is a folder, not a file")


def owned_names(record: dict) -> tuple[set[str], set[str]]:
    """What a run folder's manifest says is its own: (top-level names: its manifest and lock,
    outputs, unit folders and samples; every file it lists, relative to the folder)."""
    names = {MANIFEST, LOCK, "config.json", *UNIT_FOLDERS}
    files: set[str] = set()
    for key in ("outputs", "files"):
        if isinstance(record.get(key), dict):
            files |= {str(Path(str(k))) for k in record[key] if str(k).strip()}
    for key in ("samples", "units"):
        if isinstance(record.get(key), list):
            names |= {str(s) for s in record[key]}
    return names | {Path(f).parts[0] for f in files}, files


def check_not_owned(path: Path) -> None:
    """ValueError when ``path`` is a file or a top-level entry (a unit folder, a sample) of a
    run folder above it: a dataset's ``camera.json``, its sample's folder, a study's ``cells``,
    another run's ``manifest.json``. A new path deeper down (``detect``'s default output beside
    a sample's video) replaces nothing and is allowed."""
    path = Path(os.path.abspath(path))
    for above in path.parents:
        record = read_manifest(above)
        if record is None or kind_of(record) == "unknown":
            continue
        rel = path.relative_to(above)
        names, files = owned_names(record)
        if str(rel) in files or (len(rel.parts) == 1 and rel.parts[0] in names):
            raise ValueError(
                f"{path}: is part of the output of `{kind_of(record)}` in {above}; choose a "
                "path outside it"
            )


def check_not_input(path: Path, inputs: Iterable[Path], option: str = "--out") -> None:
    """ValueError when ``path`` is one of the command's ``inputs`` (the same file or folder)."""
    for given in inputs:
        with contextlib.suppress(OSError):
            if Path(given).exists() and Path(path).exists() and os.path.samefile(path, given):
                raise ValueError(f"{path}: is one of the command's inputs; {option} elsewhere")
        if os.path.abspath(path) == os.path.abspath(given):
            raise ValueError(f"{path}: is one of the command's inputs; {option} elsewhere")


def read_holder(folder: Path) -> dict | None:
    """The record in ``folder``'s lock file (its holder, or its last run); None if none."""
    try:
        record = read_json(Path(folder) / LOCK, RECORD_BYTES, RECORD_DEPTH)
    except (OSError, ValueError):
        return None
    return record if isinstance(record, dict) else None


def claim(folder: Path, kind: str) -> dict | None:
    """Check that ``kind`` may write into ``folder`` (see the module docstring); return the
    manifest already there, if any. ValueError in one line otherwise; writes nothing."""
    folder = Path(folder)
    check_out_path(folder, folder=True)
    check_writable(folder)
    existing = read_manifest(folder)
    found = kind_of(existing) if existing is not None else None
    where = MANIFEST
    if existing is None and (holder := read_holder(folder)) is not None:
        found, where = holder.get("kind"), f"{LOCK}; its {MANIFEST} is missing or unreadable"
    if found is not None and found != kind:
        raise ValueError(
            f"{folder} holds the output of `{found}` (its {where}); "
            f"`{kind}` does not write there: choose another folder"
        )
    return existing


def claim_out(folder: Path, kind: str) -> dict | None:
    """:func:`claim` for a command's ``--out``: a refusal is a FieldError on ``out``."""
    try:
        return claim(folder, kind)
    except ValueError as exc:
        raise FieldError("out", str(exc)) from None


# -- the lock -------------------------------------------------------------------------------


@dataclass
class FolderLock:
    """A run folder held by this process: released by :meth:`release` (or at exit)."""

    folder: Path
    fd: int | None
    previous: dict | None  # the lock file's record before this run: the last run's

    def record(self, kind: str, settings_sha256: str | None = None) -> None:
        """Write this run into the lock file (once its checks passed)."""
        record = {
            "pid": os.getpid(),
            "host": socket.gethostname(),
            "command": _this_command(),
            "started": datetime.now(UTC).isoformat(timespec="seconds"),
            "kind": kind,
            "run": run_id(),
            "settings_sha256": settings_sha256,
        }
        os.ftruncate(self.fd, 0)
        os.pwrite(self.fd, (json.dumps(record) + "\n").encode(), 0)

    def release(self) -> None:
        if self.fd is not None:
            os.close(self.fd)  # closing lets go of the flock
            self.fd = None

    __del__ = release  # a lock dropped unreleased (an exception's path) lets go with it

    def __enter__(self) -> FolderLock:
        return self

    def __exit__(self, *exc) -> None:
        self.release()


def describe_holder(holder: dict | None) -> str:
    """'pid 12 on host h (whiskerbench ...), started ...' of a lock file's record."""
    if not holder:
        return "another process (it has not yet recorded itself)"
    return (
        f"pid {holder.get('pid')} on host {holder.get('host')} "
        f"(`{holder.get('command')}`, started {holder.get('started')})"
    )


def lock_folder(folder: Path) -> FolderLock:
    """Take ``folder``'s lock (making the folder); FolderBusyError naming the holder when
    another process holds it. Nothing is recorded until :meth:`FolderLock.record`."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / LOCK
    flags = os.O_RDWR | os.O_CREAT | os.O_CLOEXEC | os.O_NOFOLLOW
    try:
        fd = os.open(path, flags, 0o666)
    except OSError as exc:
        raise ValueError(
            f"{path}: cannot be opened as the folder's lock ({exc.strerror})"
        ) from None
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        os.close(fd)
        holder = read_holder(folder)
        for _ in range(20):  # the holder writes its record just after taking the lock
            if holder:
                break
            time.sleep(0.05)
            holder = read_holder(folder)
        raise FolderBusyError(
            f"{folder}: in use by {describe_holder(holder)}; wait for it to end or choose "
            "another folder"
        ) from None
    previous = read_holder(folder)
    return FolderLock(folder, fd, previous)


def folders_written(folder: Path, written: Iterable[str]) -> list[Path]:
    """The folders (patterns relative to ``folder``; "" is the folder) that exist now."""
    found = []
    for pattern in written:
        found += [folder] if pattern in ("", ".") else sorted(folder.glob(pattern))
    return [p for p in dict.fromkeys(found) if p.is_dir() or p.is_symlink()]


def check_links(folder: Path, folders: Iterable[Path]) -> None:
    """ValueError naming the first symbolic link, among ``folders`` or at their top level,
    that leads out of ``folder``."""
    root = folder.resolve()
    for place in folders:
        entries = [place] if place.is_symlink() else []
        with contextlib.suppress(OSError):
            entries += [e for e in place.iterdir() if e.is_symlink()]
        for entry in entries:
            if not entry.resolve().is_relative_to(root):
                raise ValueError(
                    f"{entry}: a symbolic link out of the run folder (to {os.readlink(entry)}); "
                    "remove it or choose another folder"
                )


@contextlib.contextmanager
def _released_on_error(lock: FolderLock) -> Iterator[None]:
    try:
        yield
    except BaseException:
        lock.release()
        raise


def open_folder(
    folder: Path,
    kind: str,
    written: Iterable[str] = ("",),
    settings_sha256: str | None = None,
    record: bool = True,
) -> FolderLock:
    """Claim, lock and clean ``folder`` for a ``kind`` run (the module docstring); return the
    lock, to be released when the run ends. ``written``: the folders the run writes (patterns
    relative to ``folder``). ValueError in one line when refused. With ``record`` False the
    caller checks more before :meth:`FolderLock.record` (:mod:`bench.common.resumable`)."""
    folder = Path(folder)
    claim(folder, kind)  # nothing written when refused
    new_run_id()
    lock = lock_folder(folder)
    with _released_on_error(lock):
        claim(folder, kind)  # again: nobody can change it now
        places = folders_written(folder, written)
        check_links(folder, places)
        for place in places:
            clean_stale(place)
        if record:
            lock.record(kind, settings_sha256)
    return lock
