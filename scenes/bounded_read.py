"""Reading a user's small text file bounded before it is parsed: by size (a regular file, read
no further than its limit), then JSON or YAML by nesting depth, node count and aliases.

``json.loads`` alone fails on hostile input with a RecursionError (deep nesting) or a plain
ValueError (an integer of over 4300 digits); PyYAML's SafeLoader expands aliases, so a few
hundred bytes walk as gigabytes. Every failure here is a :class:`BoundedReadError` (a
ValueError) whose message says what is wrong, without the path: the caller names the file.
"""

from __future__ import annotations

import errno
import json
import os
import stat
from pathlib import Path
from typing import Any

import yaml


class BoundedReadError(ValueError):
    """A file over a bound, not a regular file, or not parseable; the message says which."""


#: Why a path that is not UTF-8 text is refused before OpenCV sees it.
NOT_UTF8 = "the file name is not valid UTF-8 text; rename it (OpenCV crashes on such a path)"


def is_utf8(path: Path | str) -> bool:
    """Whether the path is UTF-8 text: a name in another encoding is decoded with surrogates
    (PEP 383), which OpenCV's path arguments cannot take (a segmentation fault, measured)."""
    try:
        str(path).encode("utf-8")
    except UnicodeEncodeError:
        return False
    return True


#: What a special file is, by the test of its mode.
SPECIAL_KINDS = (
    (stat.S_ISCHR, "a character device"),
    (stat.S_ISBLK, "a block device"),
    (stat.S_ISFIFO, "a named pipe"),
    (stat.S_ISSOCK, "a socket"),
)


def special_kind(path: Path | str) -> str | None:
    """'a character device', 'a named pipe', ... for a path that is neither a file nor a
    folder (None for those, and where nothing can be stat'ed)."""
    try:
        mode = os.stat(path).st_mode
    except OSError:
        return None
    return next((name for test, name in SPECIAL_KINDS if test(mode)), None)


def input_problem(path: Path | str) -> str | None:
    """Why an input that is no regular file or folder cannot be read although something is
    there (a named pipe, a symlink loop, a dangling link, a name too long), in the words after
    ``<path>: ``; None where nothing is there, so each caller says "no such file" its own way
    and a FIFO or a loop is never reported as missing."""
    try:
        os.stat(path)
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            return "a symlink loop"
        if exc.errno != errno.ENOENT:
            return f"cannot be read ({exc.strerror or type(exc).__name__})"
        if os.path.islink(path):
            return f"a dangling symbolic link (to {os.readlink(path)})"
        return None
    special = special_kind(path)
    return f"not a regular file ({special})" if special else None


def read_bounded_bytes(path: Path | str, max_bytes: int) -> bytes:
    """The bytes of a regular file of at most ``max_bytes``; BoundedReadError otherwise (a FIFO
    or device would block or never end; a file growing while read is cut at the bound)."""
    try:  # non-blocking: opening a FIFO for reading would wait for a writer
        with open(os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC), "rb") as f:
            mode = os.fstat(f.fileno()).st_mode
            if not stat.S_ISREG(mode):
                raise BoundedReadError(input_problem(path) or "not a regular file")
            data = f.read(max_bytes + 1)
    except OSError as exc:
        reason = f"cannot be read ({exc.strerror or type(exc).__name__})"
        raise BoundedReadError(input_problem(path) or reason) from None
    if len(data) > max_bytes:
        raise BoundedReadError(f"larger than {max_bytes} bytes")
    return data


def read_bounded_text(path: Path | str, max_bytes: int) -> str:
    """:func:`read_bounded_bytes` decoded as UTF-8."""
    try:
        return read_bounded_bytes(path, max_bytes).decode("utf-8")
    except UnicodeDecodeError as exc:
        raise BoundedReadError(f"not UTF-8 text ({exc.reason} at byte {exc.start})") from None


def deeper_than(value: Any, limit: int) -> bool:
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


def parse_json(text: str | bytes, max_depth: int) -> Any:
    """JSON ``text`` (bytes: UTF-8, 16 or 32) nested at most ``max_depth`` levels;
    BoundedReadError otherwise."""
    try:
        data = json.loads(text)
    except (ValueError, RecursionError) as exc:  # bad JSON or text, 4300+ digit integers, nesting
        reason = str(exc).splitlines()[0][:200] if str(exc) else type(exc).__name__
        raise BoundedReadError(f"not valid JSON ({reason})") from None
    if deeper_than(data, max_depth):
        raise BoundedReadError(f"nested deeper than {max_depth} levels")
    return data


def read_json(path: Path | str, max_bytes: int, max_depth: int) -> Any:
    """A JSON file bounded by size, then depth; BoundedReadError (no path) otherwise."""
    return parse_json(read_bounded_bytes(path, max_bytes), max_depth)


class BoundedYamlError(yaml.YAMLError):
    """A YAML document over a bound: an alias, too many nodes, too deep."""


class BoundedSafeLoader(yaml.SafeLoader):
    """SafeLoader refusing aliases and bounding the node count and depth while composing, so
    nothing is built beyond the bounds. Subclasses set :attr:`max_nodes`, :attr:`max_depth`."""

    max_nodes = 10_000
    max_depth = 8

    def __init__(self, stream) -> None:
        super().__init__(stream)
        self._nodes = 0
        self._depth = 0

    def compose_node(self, parent, index):
        if self.check_event(yaml.AliasEvent):
            event = self.peek_event()
            line = event.start_mark.line + 1 if event.start_mark else "?"
            raise BoundedYamlError(f"alias *{event.anchor} at line {line}: aliases are refused")
        self._nodes += 1
        if self._nodes > self.max_nodes:
            raise BoundedYamlError(f"more than {self.max_nodes} YAML nodes")
        self._depth += 1
        try:
            if self._depth > self.max_depth:
                raise BoundedYamlError(f"nested deeper than {self.max_depth} levels")
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1
