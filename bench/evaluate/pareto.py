"""The accuracy-against-speed chart of ``compare``: the Pareto front over every pipeline.

Peers (:func:`bench.evaluate.leaders.is_peer`) are hollow diamonds, the project's pipelines
filled circles; frames/s is the median over timing rounds with a bar from the slowest to the
fastest round (:mod:`bench.evaluate.timing`). A method with an accuracy but no speed (NaN: not
timed, such as a results file without times or a branch finder) is never on the front: it is a
dotted line at its accuracy, labelled "accuracy only".
"""

from __future__ import annotations

import textwrap
from collections.abc import Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
from matplotlib.ticker import NullFormatter  # noqa: E402

from bench.common.figures import BLUE, GREY, VERMILLION, label_points, save, titled  # noqa: E402
from bench.evaluate.leaders import is_peer  # noqa: E402

#: Accuracy measures on the dataset: column, label, whether higher is better.
ACCURACY = (
    ("correct_rate", "branch outcome correct (fraction of samples)", True),
    ("recall", "marker recall", True),
    ("deflection_err_mm", "deflection error (mm, median)", False),
)


def pareto_front(speed: np.ndarray, accuracy: np.ndarray, higher_better: bool) -> np.ndarray:
    """(N,) bool: points no other point beats in both speed and accuracy (ties do not beat).

    A point without an accuracy (NaN: its pipeline refused every sample) or without a speed
    (NaN: not timed, accuracy only) is not on the front and beats no other."""
    acc = np.asarray(accuracy, float) * (1 if higher_better else -1)
    speed = np.asarray(speed, float)
    front = np.isfinite(acc) & np.isfinite(speed)
    for i in range(len(speed)):
        better = (speed >= speed[i]) & (acc >= acc[i]) & ((speed > speed[i]) | (acc > acc[i]))
        front[i] &= not better.any()
    return front


#: A panel's title wraps here: a method named by a long path must not squeeze the panels away.
PANEL_TITLE_WIDTH = 60


def plot_pareto(
    summary: pd.DataFrame, path: Path, dataset: str = "", options: Sequence[str] = ()
) -> None:
    """Accuracy against speed, one panel per accuracy measure, the Pareto front drawn.

    The front is computed over every pipeline, peers included; peers are hollow diamonds, the
    project's pipelines filled circles (vermillion on the front, grey behind it: told apart by
    lightness too); a bar spans each pipeline's slowest to fastest round. A method without a
    speed is a dotted line at its accuracy, named "(accuracy only)"; one without a value for a
    measure (it refused every sample, or failed) cannot be placed: the panel's title names it,
    so no method drops out of the chart unsaid. The title names the ``dataset`` and the run's
    non-default ``options``; the legend stands below the panels."""
    fig, axes = plt.subplots(
        1, len(ACCURACY), figsize=(5 * len(ACCURACY), 4.2), layout="constrained", squeeze=False
    )
    axes = axes[0]
    named = []  # each panel's placed points, named once the layout is complete
    speed = summary["fps"].to_numpy()
    peer = summary["pipeline"].map(is_peer).to_numpy(bool)
    for ax, (column, label, higher) in zip(axes, ACCURACY, strict=True):
        acc = summary[column].to_numpy(float)
        placed = np.isfinite(acc) & np.isfinite(speed)
        untimed = np.isfinite(acc) & ~np.isfinite(speed)
        front = pareto_front(speed, acc, higher)
        for mine, where, colour in (
            (placed & ~front, "behind the front", GREY),
            (front, "Pareto front", VERMILLION),
        ):
            if "fps_min" in summary:  # the spread across rounds
                low, high = summary["fps_min"].to_numpy(float), summary["fps_max"].to_numpy(float)
                bars = [(speed - low)[mine], (high - speed)[mine]]
                ax.errorbar(speed[mine], acc[mine], xerr=bars, fmt="none", ecolor=colour, lw=1)
            ax.scatter(speed[mine & ~peer], acc[mine & ~peer], c=colour, s=45, label=where)
            ax.scatter(speed[mine & peer], acc[mine & peer], marker="D", s=55, facecolors="none",
                       edgecolors=colour, linewidths=1.6, label=f"peer, {where}")  # fmt: skip
        order = np.argsort(speed[front])
        ax.plot(speed[front][order], acc[front][order], "-", c=VERMILLION, lw=1)
        names = summary["pipeline"].to_numpy()
        named.append((ax, speed[placed], acc[placed], names[placed]))
        for y, name in zip(acc[untimed], names[untimed], strict=True):
            ax.axhline(y, ls=":", c=BLUE, lw=1.2)
            # a long name may spill past the panel: it must not shrink the panels (in_layout)
            ax.annotate(f"{name} (accuracy only)", (0.01, y), xycoords=("axes fraction", "data"),
                        fontsize=7, xytext=(0, 3), textcoords="offset points",
                        in_layout=False)  # fmt: skip
        if not np.isfinite(acc).all():
            missing = f"no value: {', '.join(names[~np.isfinite(acc)])}"
            ax.set_title(textwrap.fill(missing, PANEL_TITLE_WIDTH), fontsize=8)  # long names
        if placed.any():  # an empty panel has no range to log-scale
            ax.set_xscale("log")
            ax.xaxis.set_minor_formatter(NullFormatter())  # crowded labels between decades
        ax.set_xlabel("frames/s on the dataset's frames, one core (bar: rounds)")
        ax.set_ylabel(label + ("" if higher else ", lower is better"))
        ax.grid(alpha=0.3)
    handles, labels = axes[0].get_legend_handles_labels()
    shown = [(h, t) for h, t in zip(handles, labels, strict=True) if len(h.get_offsets())]
    if shown:  # none when every pipeline refused every sample
        fig.legend(*zip(*shown, strict=True), loc="outside lower center", ncol=len(shown),
                   fontsize=8, frameon=False)  # fmt: skip
    on = f" on {dataset}" if dataset else ""
    title = f"Accuracy against speed{on} (hollow diamonds: peer detectors)"
    fig.suptitle(titled(title, options), fontsize=10)
    for ax, xs, ys, names in named:
        label_points(ax, xs, ys, names)
    save(fig, path)
