"""The part of a resumable run that the study and the dataset share: open the folder, finish it.

A resumable command writes its units (study cells, dataset samples) one atomic file at a time,
so a rerun of the same command skips what is done. :func:`open_run` checks the folder before any
work: writable, not another command's (:func:`bench.common.manifest.claim`), and not holding
units made with other settings; it deletes the temporary files of a killed run and marks the
folder as this command's with an unfinished manifest. A folder that holds only that mark (no
unit finished) takes any settings, so a corrected command is never blocked by a failed one.
:func:`finish_run` writes the complete manifest last.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from bench.common.manifest import (
    RunClock,
    build_manifest,
    claim,
    json_sha256,
    write_manifest,
)


@dataclass
class ResumableRun:
    """An opened run: its folder, kind, settings hash and clock."""

    folder: Path
    kind: str
    settings_sha256: str
    config: Any
    clock: RunClock = field(default_factory=RunClock)


def open_run(
    folder: Path, kind: str, config: Any, settings_sha256: str | None = None, units: str = "*"
) -> ResumableRun:
    """Check ``folder`` for a ``kind`` run of ``config`` and mark it; see the module docstring.

    ``units`` is the glob (relative to the folder) of the finished units; ``settings_sha256``
    defaults to the hash of ``config``'s JSON. Raises ValueError (one line naming the folder)
    with nothing written when the folder is refused.
    """
    folder = Path(folder)
    settings = settings_sha256 or json_sha256(config)
    existing = claim(folder, kind)
    if existing is not None and _settings_of(existing) != settings and any(folder.glob(units)):
        raise ValueError(
            f"{folder} holds a {kind} run with another configuration; "
            "choose another folder or delete that one"
        )
    run = ResumableRun(folder, kind, settings, config)
    folder.mkdir(parents=True, exist_ok=True)
    write_manifest(
        folder,
        build_manifest(kind, run.clock, config, finished=False, settings_sha256=settings),
    )
    return run


def _settings_of(record: dict) -> str | None:
    """The settings hash a manifest records (an old study's: the hash of its config)."""
    if "settings_sha256" in record:
        return record["settings_sha256"]
    return json_sha256(record["config"]) if "config" in record else None


def finish_run(run: ResumableRun, **fields: Any) -> dict:
    """Write the run's complete manifest (``fields``: see :func:`build_manifest`); return it."""
    record = build_manifest(run.kind, run.clock, run.config, **fields)
    record["settings_sha256"] = run.settings_sha256
    return write_manifest(run.folder, record)
