"""The study figures' look: colours per marker size, number and tick labels, saving.

Used by :mod:`bench.study.plots`, on the project's one figure style (:mod:`bench.common.figures`:
the Okabe-Ito palette, options in titles, tight saving); the rates' colour map stays with the
heatmap that uses it.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pandas as pd

from bench.common.figures import colour, save  # noqa: F401  (save: the study's plots' too)
from bench.study.report import nominal_scale_of

#: Line style per corner refinement: ``subpix`` (OpenCV's) and ``own`` (a peer's) are the
#: detector's corners, ``lines`` the project's refined from them.
REFINEMENT_STYLES = {"lines": "-", "subpix": "--", "own": "--"}


def size_colors(sizes: Sequence[float]) -> dict[float, str]:
    """One colour per marker size that colour-blind readers tell apart (stable across plots)."""
    return {s: colour(i) for i, s in enumerate(sorted(sizes))}


def fmt_num(value: float) -> str:
    return f"{value:g}"


def at_nominal(table: pd.DataFrame, nominal_scale: float) -> tuple[pd.DataFrame, float, list]:
    """Rows at the nominal PSF scale, that scale, and all scales of the table (sorted)."""
    scales = np.sort(pd.unique(table["psf_scale"].astype(float)))
    nominal = nominal_scale_of(scales, nominal_scale)
    return table[np.isclose(table["psf_scale"].astype(float), nominal)], nominal, scales.tolist()


def scale_note(nominal: float, scales: Sequence[float]) -> str:
    if len(scales) == 1:
        return f"PSF scale {fmt_num(nominal)} (no band)"
    span = f"{fmt_num(scales[0])}\u2013{fmt_num(scales[-1])}"
    return f"nominal PSF scale {fmt_num(nominal)} of {span}"


def detector_note(detector: str | None) -> str:
    """``", detector locus (4x4_50)"`` for a figure's title; empty where none is named."""
    return f", detector {detector}" if detector else ""


def text_color(rgba: tuple[float, float, float, float]) -> str:
    r, g, b = rgba[:3]
    return "white" if 0.299 * r + 0.587 * g + 0.114 * b < 0.45 else "black"


def rate_label(rate: float) -> str:
    """Compact cell label: '1', '0', '.95'; never rounds a non-1 rate to '1.00'."""
    if rate >= 1.0:
        return "1"
    if rate <= 0.0:
        return "0"
    text = f"{rate:.2f}"
    if text == "1.00":
        return ">.99"
    if text == "0.00":
        return "<.01"
    return text.lstrip("0")


def minor_log_label(value: float, _pos: int) -> str:
    """Label the minor ticks 2 and 5 of each decade of a log axis, as plain numbers."""
    mantissa = value / 10.0 ** np.floor(np.log10(value))
    return f"{value:g}" if np.isclose(mantissa, [2.0, 5.0]).any() else ""
