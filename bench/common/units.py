"""A resumable run's units (a study cell, a dataset sample, a ladder rung), each checked before
it is reused.

A unit's record is a JSON file written after (or atomically with) the unit's data files. It holds
the run's settings hash (``settings_sha256``), the SHA-256 of each data file (``files``, paths
relative to the record's folder), the machine of the process that made the unit (``machine``,
:func:`bench.common.manifest.machine`: a run resumed elsewhere, or a remote Dask worker, makes
its units on other CPUs, whose last bits differ) and its own hash (``record_sha256``: of the
record without it). So the settings stay with every unit even when the folder's
``manifest.json`` is lost, and a unit is reused only when its record is intact, made with this
run's settings, and every file it lists hashes as recorded: a swapped, emptied, truncated or
grown file is redone, not trusted.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Mapping
from pathlib import Path

from bench.common.atomic import write_json
from bench.common.manifest import json_sha256, machine, sha256
from scenes.bounded_read import read_json
from scenes.input_limits import RECORD_BYTES, RECORD_DEPTH

#: The key of a record's hash of itself.
RECORD_HASH = "record_sha256"
#: The keys that make a JSON file a unit record (beside the unit's own fields); ``unit``, where
#: a record has it, names the unit (so a record swapped in from another unit shows).
UNIT_KEYS = ("unit", "settings_sha256", "files", "machine", RECORD_HASH)

DONE, MISSING, DAMAGED = "done", "missing", "damaged"


class UnitSettingsError(ValueError):
    """A unit made with other settings: the folder holds another run's work (refused)."""


def seal(record: Mapping) -> dict:
    """``record`` as a reader gets it back, with its :data:`RECORD_HASH`."""
    plain = json.loads(json.dumps(record, default=str))
    plain.pop(RECORD_HASH, None)
    plain[RECORD_HASH] = json_sha256(plain)
    return plain


def write_unit(path: Path, record: Mapping) -> dict:
    """Write a unit's record (it has ``settings_sha256`` and ``files``) sealed, with this
    process's ``machine``; return it."""
    sealed = seal({**record, "machine": dict(machine())})
    write_json(path, sealed)
    return sealed


def payload(record: Mapping) -> dict:
    """A record's own fields, without :data:`UNIT_KEYS`."""
    return {k: v for k, v in record.items() if k not in UNIT_KEYS}


def _read(path: Path) -> dict | None:
    try:
        record = read_json(path, RECORD_BYTES, RECORD_DEPTH)  # bounded: a unit file is input
    except (OSError, ValueError):  # unreadable, truncated, emptied
        return None
    return record if isinstance(record, dict) else None


def _intact(record: dict) -> bool:
    """The record's own hash agrees (a record from before the hash is taken as it is)."""
    return RECORD_HASH not in record or seal(record)[RECORD_HASH] == record[RECORD_HASH]


def unit_state(path: Path, settings_sha256: str, expect: Mapping | None = None) -> str:
    """:data:`DONE` (reuse it), :data:`MISSING` or :data:`DAMAGED` (redo it) for the unit whose
    record is ``path``; ``expect``: fields the record must hold (its name: a record swapped in
    from another unit is damaged). UnitSettingsError when it was made with other settings."""
    return _checked(Path(path), settings_sha256, expect)[0]


def _checked(path: Path, settings_sha256: str, expect: Mapping | None) -> tuple[str, dict | None]:
    """:func:`unit_state` and the record it read (None unless :data:`DONE`)."""
    if not path.exists() and not path.is_symlink():
        return MISSING, None
    record = _read(path)
    if record is None or not _intact(record) or not isinstance(record.get("files"), dict):
        return DAMAGED, None
    if record.get("settings_sha256") != settings_sha256:
        raise UnitSettingsError(
            f"{path}: made with other settings (another run's); choose another --out or delete it"
        )
    if any(record.get(k) != v for k, v in (expect or {}).items()):
        return DAMAGED, None
    for name, digest in record["files"].items():
        file = path.parent / str(name)
        if not file.is_file() or sha256(file) != digest:
            return DAMAGED, None
    return DONE, record


def reusable(path: Path, settings_sha256: str, expect: Mapping | None = None) -> dict | None:
    """The record of a unit that may be reused (:func:`unit_state` says :data:`DONE`), read once
    with its checks, else None: missing, damaged or made with other settings, all to be redone.
    For units that any settings may overwrite (a score's samples: their folder is named by the
    pipeline)."""
    try:
        return _checked(Path(path), settings_sha256, expect)[1]
    except UnitSettingsError:
        return None


def other_settings(folder: Path, patterns: Iterable[str], settings_sha256: str) -> Path | None:
    """The first intact unit record under ``folder`` (``patterns``: globs of files, of which
    the unit records are read) made with other settings; None when there is none."""
    for pattern in patterns:
        for path in sorted(Path(folder).glob(pattern)):
            if path.suffix != ".json":
                continue
            record = _read(path)
            if record is None or "settings_sha256" not in record or not _intact(record):
                continue
            if record["settings_sha256"] != settings_sha256:
                return path
    return None
