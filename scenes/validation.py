"""One error type for a bad setting, shared by every config: it names the field it concerns.

The command line maps ``field`` to its option and prints ``detail`` in one line.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from scenes.bounded_read import BoundedReadError, read_json
from scenes.input_limits import SETTINGS_DEPTH

#: Largest seed of any config: seeds feed NumPy's SeedSequence and the manifests (32 bits).
MAX_SEED = 2**32 - 1


class FieldError(ValueError):
    """An invalid value of the config field ``field``; ``detail`` says why and what is allowed."""

    def __init__(self, field_name: str, message: str) -> None:
        super().__init__(f"{field_name}: {message}")
        self.field = field_name
        self.detail = message


def shown_value(value: object) -> str:
    """A value as a one-line refusal quotes it: as written, but an integer of over 20 digits by
    its length (a 400-digit number would fill the line)."""
    text = str(value)
    digits = len(text.lstrip("-"))
    return f"an integer of {digits} digits" if isinstance(value, int) and digits > 20 else text


#: Deepest nesting a small JSON settings file (profile, observations) may have.
MAX_JSON_DEPTH = SETTINGS_DEPTH


def read_small_json(
    path: Path,
    max_bytes: int,
    error: type[FieldError],
    field_name: str,
    max_depth: int = MAX_JSON_DEPTH,
) -> Any:
    """A small JSON file's content, bounded by size before it is read and by depth after
    (:func:`scenes.bounded_read.read_json`): ``error(field_name, ...)`` names the file and
    what is wrong otherwise."""
    try:
        return read_json(path, max_bytes, max_depth)
    except BoundedReadError as exc:
        raise error(field_name, f"{path}: {exc}") from None
