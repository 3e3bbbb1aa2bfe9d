"""Argument types and output checks shared by the command-line modules.

A list option refuses an empty list and a value listed twice (a repeated size would count one
cell's images twice); an output is checked before any work, so a bad ``--out`` costs nothing.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from bench.common.atomic import check_writable
from scenes.validation import MAX_SEED, FieldError


def _distinct(option: str, text: str, values: tuple) -> tuple:
    if not values:
        raise argparse.ArgumentTypeError(f"{option}: needs at least one value")
    repeated = next((v for i, v in enumerate(values) if v in values[:i]), None)
    if repeated is not None:
        raise argparse.ArgumentTypeError(
            f"{option}: {text!r}: {repeated!r} is listed twice; list each value once"
        )
    return values


def float_list(option: str):
    """argparse type: comma-separated finite numbers, each once; a bad one is refused naming
    ``option``."""

    def parse(text: str) -> tuple[float, ...]:
        try:
            values = tuple(float(v) for v in text.split(",") if v.strip())
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"{option}: {text!r} is not a comma-separated list of numbers"
            ) from None
        if not all(math.isfinite(v) for v in values):
            raise argparse.ArgumentTypeError(f"{option}: {text!r}: every number must be finite")
        return _distinct(option, text, values)

    return parse


def name_list(option: str):
    """argparse type: comma-separated names, each once (at least one)."""

    def parse(text: str) -> tuple[str, ...]:
        return _distinct(option, text, tuple(v.strip() for v in text.split(",") if v.strip()))

    return parse


def distinct(option: str, values, text: str | None = None) -> tuple:
    """``values`` as a tuple, refused (argparse error quoting ``text``, the option's value)
    when empty or when one repeats."""
    return _distinct(option, ",".join(map(str, values)) if text is None else text, tuple(values))


def seed(text: str) -> int:
    """argparse type of ``--seed``: an integer in 0..2**32 - 1."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"--seed: {text!r} is not an integer") from None
    if not 0 <= value <= MAX_SEED:
        raise argparse.ArgumentTypeError(f"--seed: {value}: allowed range is 0..{MAX_SEED}")
    return value


def check_out_folder(path: Path | str, field: str = "out") -> Path:
    """An output folder: not an existing file, writable (made later, not now); FieldError
    naming ``field`` otherwise."""
    if not str(path).strip():
        raise FieldError(field, "must name a folder")
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise FieldError(field, f"{path}: is a file, not a folder")
    try:
        check_writable(path)
    except ValueError as exc:
        raise FieldError(field, str(exc)) from None
    return path


def check_out_file(path: Path | str, field: str = "out") -> Path:
    """An output file: not an existing folder, its folder writable; FieldError otherwise."""
    if not str(path).strip():
        raise FieldError(field, "must name a file")
    path = Path(path)
    if not path.name:
        raise FieldError(field, f"{str(path)!r}: must name a file")
    if path.is_dir():
        raise FieldError(field, f"{path}: is a folder, not a file")
    try:
        check_writable(path.parent)
    except ValueError as exc:
        raise FieldError(field, str(exc)) from None
    return path
