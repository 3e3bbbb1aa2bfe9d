"""The results grid of a scored dataset: one cell per sample, its branch outcome as a colour
(``score``'s and ``score --branches``' ``grid-<protocol>-<lighting>.png``)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from bench.common.figures import BLUE, LIGHT_GREY, VERMILLION, save  # noqa: E402

#: Cell colours of the results grid: blue and vermillion (Okabe-Ito), which colour-blind
#: readers tell apart as red and green are not; grey for no answer.
OUTCOME_COLOURS = {"correct": BLUE, "wrong": VERMILLION, "refused": LIGHT_GREY}


def plot_grid(table: pd.DataFrame, path: Path, title: str) -> None:
    """A results table as an image: rows foliage x distance, columns branch configuration,
    blue = correct, vermillion = not (FP / FN written in the cell), grey = refused by the
    pipeline (colours colour-blind readers tell apart; the legend below says so)."""
    rows = sorted({(f, d) for f, d in zip(table["foliage"], table["distance"], strict=True)})
    cols = sorted(set(table["branches"]), key=lambda b: (b != "none", len(b), b))
    fig, ax = plt.subplots(
        figsize=(1.1 * len(cols) + 2, 0.45 * len(rows) + 1.2), layout="constrained"
    )
    for r, (foliage, distance) in enumerate(rows):
        for c, branches in enumerate(cols):
            hit = table[
                (table["foliage"] == foliage)
                & (table["distance"] == distance)
                & (table["branches"] == branches)
            ]
            if hit.empty:
                continue
            outcome = hit["outcome"].iloc[0]
            ok = outcome == "correct"
            colour = OUTCOME_COLOURS.get(outcome, OUTCOME_COLOURS["wrong"])
            ax.add_patch(plt.Rectangle((c, r), 1, 1, color=colour))
            text = (
                ""
                if ok
                else outcome.replace("false_positive", "FP")
                .replace("false_negative", "FN")
                .replace("+", " ")
            )
            ax.text(c + 0.5, r + 0.5, text, ha="center", va="center", fontsize=7)
    ax.set_xlim(0, len(cols))
    ax.set_ylim(len(rows), 0)
    ax.set_xticks(np.arange(len(cols)) + 0.5, cols, fontsize=8)
    ax.set_yticks(np.arange(len(rows)) + 0.5, [f"{f} {d}" for f, d in rows], fontsize=8)
    ax.set_xlabel("branches (mm)")
    ax.set_title(title, fontsize=9)
    ax.tick_params(length=0)
    key = [
        plt.Rectangle((0, 0), 1, 1, color=OUTCOME_COLOURS[k], label=label)
        for k, label in (
            ("correct", "correct"),
            ("wrong", "wrong (FN: a branch missed, FP: one reported where none is)"),
            ("refused", "refused (no no-contact pose)"),
        )
    ]
    fig.legend(handles=key, loc="outside lower center", ncol=3, fontsize=7, frameon=False)
    save(fig, path)
