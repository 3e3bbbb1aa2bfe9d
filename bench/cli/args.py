"""Argument types shared by the command-line modules."""

from __future__ import annotations

import argparse
import math


def float_list(option: str):
    """argparse type: comma-separated finite numbers; a bad one is refused naming ``option``."""

    def parse(text: str) -> tuple[float, ...]:
        try:
            values = tuple(float(v) for v in text.split(",") if v.strip())
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"{option}: {text!r} is not a comma-separated list of numbers"
            ) from None
        if not values:
            raise argparse.ArgumentTypeError(f"{option}: needs at least one number")
        if not all(math.isfinite(v) for v in values):
            raise argparse.ArgumentTypeError(f"{option}: {text!r}: every number must be finite")
        return values

    return parse
