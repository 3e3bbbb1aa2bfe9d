"""Paths into a JSON or YAML document, copies of it with one path replaced, the hostile values
put there and the verdict on a command's answer: what the hostile-file suites
(``test_hostile_files.py``, ``test_hostile_generated.py``) share, field by field."""

from __future__ import annotations

import copy
import math
from collections.abc import Iterator
from typing import Any

#: What a leaf is set to in turn: not a number, infinities, negative, zero, huge (a float and an
#: integer past 64 bits), the wrong types, nothing. The suites grow by a value here.
HOSTILE_VALUES = (math.nan, math.inf, -math.inf, -1, 0, 1e300, 10**30, "x", "", None, [], {}, True)


def paths(document: Any, limit: int | None = None, path: tuple = ()) -> Iterator[tuple]:
    """Every path into ``document``: each object member and list item, at every depth, then
    its own; with ``limit``, only the first ``limit`` members of each object and list."""
    if isinstance(document, dict | list):
        members = document.items() if isinstance(document, dict) else enumerate(document)
        for key, item in list(members)[:limit]:
            yield (*path, key)
            yield from paths(item, limit, (*path, key))


def replaced(document: Any, path: tuple, value: Any) -> Any:
    """A deep copy of ``document`` with the member at ``path`` set to ``value``."""
    document = copy.deepcopy(document)
    parent = document
    for key in path[:-1]:
        parent = parent[key]
    parent[path[-1]] = value
    return document


def wrong_answer(
    code: int, err: str, nonfinite: bool, written: bool = False, prefix: str = ""
) -> str | None:
    """What is wrong with a command's answer to a hostile input, or None: it must accept (exit 0,
    never a value that is not a finite number) or refuse in one line starting with ``prefix``
    (exit 2) having written nothing; never an internal error."""
    lines = err.strip().splitlines()
    if "Traceback" in err or "internal error" in err:
        return "an internal error"
    if code == 2:
        if len(lines) != 1 or not lines[0].startswith(prefix):
            return f"a refusal in {len(lines)} lines"
        return "refused, but wrote" if written else None
    if code == 0:
        return "accepted a value that is not a finite number" if nonfinite else None
    return f"exit code {code}"
