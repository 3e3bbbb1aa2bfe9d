"""The part of a resumable run that the study, the dataset and the ladder share: open the folder,
finish it.

A resumable command writes its units (study cells, dataset samples, ladder rungs) one atomic
file at a time, each with its record (:mod:`bench.common.units`), so a rerun of the same command
skips what is done and verified. :func:`open_run` claims, locks and cleans the folder for the
whole run (:func:`bench.common.run_folder.open_folder`), then refuses a folder holding units made
with other settings: those its manifest records, else its lock file (the manifest may be lost),
and those every unit's record holds. It marks the folder as this command's with an unfinished
manifest. A folder that holds only that mark (no unit finished) takes any settings, so a
corrected command is never blocked by a failed one. :func:`finish_run` writes the complete
manifest last; leaving the ``with`` block releases the folder.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from bench.common.manifest import (
    RunClock,
    build_manifest,
    json_sha256,
    read_manifest,
    write_manifest,
)
from bench.common.run_folder import FolderLock, open_folder
from bench.common.units import other_settings


@dataclass
class ResumableRun:
    """An opened run: its folder, kind, settings hash, clock and lock (a context manager that
    releases the lock); ``redone``: damaged units found and made again, for the manifest."""

    folder: Path
    kind: str
    settings_sha256: str
    config: Any
    lock: FolderLock
    clock: RunClock = field(default_factory=RunClock)
    redone: list[str] = field(default_factory=list)

    def close(self) -> None:
        self.lock.release()

    def __enter__(self) -> ResumableRun:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def open_run(
    folder: Path,
    kind: str,
    config: Any,
    settings_sha256: str | None = None,
    units: str | Iterable[str] = "*",
    written: Iterable[str] = ("",),
    check: Callable[[Path], None] | None = None,
) -> ResumableRun:
    """Check, lock and mark ``folder`` for a ``kind`` run of ``config``; see the module docstring.

    ``units``: globs (relative to the folder) of the finished units' files, their records
    among them; ``written``: the folders the run writes (cleaned of dead runs' temporary
    files); ``settings_sha256`` defaults to the hash of ``config``'s JSON; ``check``: the
    command's own check of the locked folder, before anything is written. Raises ValueError
    (one line naming the folder) when the folder is refused.
    """
    folder = Path(folder)
    units = (units,) if isinstance(units, str) else tuple(units)
    settings = settings_sha256 or json_sha256(config)
    lock = open_folder(folder, kind, written, record=False)
    try:
        existing = read_manifest(folder)
        recorded = (
            _settings_of(existing) if existing else (lock.previous or {}).get("settings_sha256")
        )
        has_units = any(any(folder.glob(pattern)) for pattern in units)
        other = other_settings(folder, units, settings)
        if (recorded not in (None, settings) and has_units) or other is not None:
            where = f" ({other.relative_to(folder)})" if other is not None else ""
            raise ValueError(
                f"{folder} holds a {kind} run with another configuration{where}; "
                "choose another folder or delete that one"
            )
        if check is not None:
            check(folder)
        lock.record(kind, settings)
        run = ResumableRun(folder, kind, settings, config, lock)
        write_manifest(
            folder,
            build_manifest(kind, run.clock, config, finished=False, settings_sha256=settings),
        )
    except BaseException:
        lock.release()
        raise
    return run


def _settings_of(record: dict) -> str | None:
    """The settings hash a manifest records (an old study's: the hash of its config)."""
    if "settings_sha256" in record:
        return record["settings_sha256"]
    return json_sha256(record["config"]) if "config" in record else None


def finish_run(run: ResumableRun, **fields: Any) -> dict:
    """Write the run's complete manifest (``fields``: see :func:`build_manifest`); return it.
    The damaged units it made again are listed as ``units_redone``."""
    record = build_manifest(run.kind, run.clock, run.config, **fields)
    record["settings_sha256"] = run.settings_sha256
    record["units_redone"] = sorted(run.redone)
    return write_manifest(run.folder, record)
