"""One error type for a bad setting, shared by every config: it names the field it concerns.

The command line maps ``field`` to its option and prints ``detail`` in one line.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

#: Largest seed of any config: seeds feed NumPy's SeedSequence and the manifests (32 bits).
MAX_SEED = 2**32 - 1


class FieldError(ValueError):
    """An invalid value of the config field ``field``; ``detail`` says why and what is allowed."""

    def __init__(self, field_name: str, message: str) -> None:
        super().__init__(f"{field_name}: {message}")
        self.field = field_name
        self.detail = message


#: Deepest nesting a small JSON settings file (profile, observations) may have.
MAX_JSON_DEPTH = 8


def _deeper_than(value: Any, limit: int) -> bool:
    """Whether containers nest more than ``limit`` levels (iterative: no recursion limit)."""
    level = [value]
    for _ in range(limit):
        level = [
            child
            for item in level
            if isinstance(item, dict | list)
            for child in (item.values() if isinstance(item, dict) else item)
        ]
        if not level:
            return False
    return any(isinstance(item, dict | list) for item in level)


def read_small_json(path: Path, max_bytes: int, error: type[FieldError], field_name: str) -> Any:
    """A small JSON file's content, bounded by size before it is read and by depth after:
    ``error(field_name, ...)`` names the file and what is wrong otherwise."""
    if path.stat().st_size > max_bytes:
        raise error(field_name, f"{path}: larger than {max_bytes} bytes")
    try:
        data = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, RecursionError) as exc:
        raise error(field_name, f"{path}: not valid JSON ({exc})") from None
    if _deeper_than(data, MAX_JSON_DEPTH):
        raise error(field_name, f"{path}: nested deeper than {MAX_JSON_DEPTH} levels")
    return data
