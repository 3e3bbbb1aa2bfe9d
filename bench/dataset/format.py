"""The dataset format's version: what ``manifest.json`` says it is, and what a reader accepts.

``docs/dataset_format.md`` is the format, written down; :data:`FORMAT_VERSION` is its version,
``major.minor``. A minor step adds (a file, a ``sample.json`` or manifest key, a labels column
at the end) and a reader of the same major version reads the dataset as before, ignoring what it
does not know. A major step changes or removes something a reader relies on (a column's unit or
frame, a file's encoding, a key's meaning), so a reader refuses a dataset of a newer major
version rather than misread it. A manifest without ``format_version`` is a dataset made before
the field: version 1.0, which it is.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from pathlib import Path

#: The version of the format :func:`bench.dataset.generate.run_dataset` writes.
FORMAT_VERSION = "1.2"
#: The version of a dataset whose manifest has no ``format_version`` (made before the field).
UNVERSIONED = "1.0"
_VERSION = re.compile(r"(\d{1,6})\.(\d{1,6})")


class DatasetFormatError(ValueError):
    """A folder that is not a dataset this whiskerbench reads; the message, one line, names the
    file at fault (:class:`bench.dataset.verify.DatasetIntegrityError` is one)."""


def parse_version(version: object, where: object) -> tuple[int, int]:
    """(major, minor) of a ``"major.minor"`` string; DatasetFormatError naming ``where``."""
    match = _VERSION.fullmatch(version) if isinstance(version, str) else None
    if match is None or int(match[1]) < 1:
        raise DatasetFormatError(
            f"{where}: format_version {version!r} is not a version 'major.minor' (e.g. "
            f"{FORMAT_VERSION!r})"
        )
    return int(match[1]), int(match[2])


def check_format_version(manifest: Mapping, where: Path | str) -> str:
    """The dataset's format version (``manifest`` read from ``where``), if this reader reads it:
    any of its major version or an older one. A newer major version: DatasetFormatError."""
    version = manifest.get("format_version", UNVERSIONED)
    major, _ = parse_version(version, where)
    ours, _ = parse_version(FORMAT_VERSION, "FORMAT_VERSION")
    if major > ours:
        raise DatasetFormatError(
            f"{where}: dataset format {version} is newer than this whiskerbench reads "
            f"({FORMAT_VERSION}, major {ours}); upgrade whiskerbench"
        )
    return version
