"""Paths into a JSON or YAML document, and copies of it with one path replaced: what the
hostile-file suites (``test_hostile_files.py``, ``test_hostile_generated.py``) mutate, field by
field."""

from __future__ import annotations

import copy
from collections.abc import Iterator
from typing import Any


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
