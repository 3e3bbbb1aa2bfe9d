"""The ladder's tables and chart: rungs.csv, defaults.csv, table.md, ladder.png.

Input: one row per (part, axis, rung, cell) with the outcomes (:mod:`bench.ladder.match`) and
seconds; a rung's cost is its wall seconds per image (study: render, optics, sensor, detection
and scoring over its images; video: render and camera over its frames).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
from matplotlib.ticker import FormatStrFormatter, NullFormatter  # noqa: E402

from bench.common.figures import (  # noqa: E402
    BLACK,
    BLUE,
    VERMILLION,
    label_points,
    legend_outside,
    save,
    titled,
)
from bench.ladder.match import knee, rung_matches  # noqa: E402
from bench.ladder.rungs import CHECKS, current_default  # noqa: E402


def per_rung(cells: pd.DataFrame) -> pd.DataFrame:
    """One row per (part, axis, rung): seconds per image, worst rate error, match, knee."""
    rows = []
    for part, group in cells.groupby("part", sort=False):
        group = group.dropna(axis=1, how="all")  # the other part's columns
        ref = group[group["axis"] == "reference"]
        control = group[group["axis"] == "control"]
        ref_rate = ref.set_index("cell")["rate"]
        for (axis, rung), rows_of in group.groupby(["axis", "rung"], sort=False):
            rate_err = (rows_of.set_index("cell")["rate"] - ref_rate).abs().max()
            rows.append(
                {
                    "part": part,
                    "axis": axis,
                    "rung": rung,
                    "s_per_image": rows_of["wall_s"].sum() / max(1, rows_of["n_images"].sum()),
                    "rate_err_max": float(rate_err),
                    "corner_err_px": float(rows_of["corner_err_px"].median()),
                    "matches_reference": rung_matches(rows_of, ref, control),
                }
            )
    return pd.DataFrame(rows)


def _choices(rungs: pd.DataFrame) -> pd.DataFrame:
    """The rungs that vary one rendering choice: neither the reference nor its checks."""
    return rungs[~rungs["axis"].isin(("reference", *CHECKS))]


def defaults_table(rungs: pd.DataFrame) -> pd.DataFrame:
    """Per (part, axis): the cheapest matching rung (the knee) beside the current default."""
    out = []
    for (part, axis), group in _choices(rungs).groupby(["part", "axis"], sort=False):
        ref = rungs[(rungs["part"] == part) & (rungs["axis"] == "reference")]
        candidates = pd.concat([group, ref.assign(rung="reference")])
        if axis == "stage":  # a stage off is a simplification, not a cost level: list them all
            off = group[group["matches_reference"]]["rung"].tolist()
            cheapest = "off ok: " + (", ".join(off) or "none")
        else:
            cheapest = knee(candidates) or "none"
        out.append(
            {
                "part": part,
                "axis": axis,
                "cheapest_matching": cheapest,
                "current_default": current_default(part, axis),
            }
        )
    return pd.DataFrame(out)


def _md(table: pd.DataFrame) -> str:
    """A GitHub markdown table (pandas' to_markdown needs tabulate, not a dependency)."""
    lines = ["| " + " | ".join(table.columns) + " |", "|" + "---|" * len(table.columns)]
    lines += ["| " + " | ".join(str(v) for v in row) + " |" for row in table.itertuples(False)]
    return "\n".join(lines)


def markdown(rungs: pd.DataFrame, defaults: pd.DataFrame) -> str:
    """table.md: the rung table, then the defaults table."""
    shown = rungs.assign(
        s_per_image=rungs["s_per_image"].map(lambda v: f"{v:.3g}"),
        rate_err_max=rungs["rate_err_max"].map(lambda v: f"{v:.3f}"),
        corner_err_px=rungs["corner_err_px"].map(lambda v: f"{v:.3f}"),
    )
    return "## Rungs\n\n" + _md(shown) + "\n\n## Defaults\n\n" + _md(defaults) + "\n"


def plot(
    rungs: pd.DataFrame, defaults: pd.DataFrame, path: Path, options: Sequence[str] = ()
) -> None:
    """Outcome error (worst |rate - reference rate| over cells) against seconds per image, one
    panel per (part, axis), log time; the reference a star, the knee circled; a rung that
    matches the reference a blue dot, one that does not a vermillion cross (told apart by
    shape and by colour-blind readers too); rungs are named where no name covers another, the
    star or the ring (:func:`bench.common.figures.label_points`). The title names the run's
    non-default ``options``; the legend stands right of the panels."""
    panels = list(_choices(rungs).groupby(["part", "axis"], sort=False).groups)
    n = max(1, len(panels))
    cols = min(3, n)
    fig, axes = plt.subplots(
        (n + cols - 1) // cols,
        cols,
        figsize=(4.2 * cols, 3.2 * ((n + cols - 1) // cols)),
        layout="constrained",
    )
    axes = np.atleast_1d(axes).ravel()
    named = []  # each panel's rungs, named once the layout is complete
    for ax, (part, axis) in zip(axes, panels, strict=False):
        group = rungs[(rungs["part"] == part) & (rungs["axis"] == axis)]
        ref = rungs[(rungs["part"] == part) & (rungs["axis"] == "reference")]
        for matches, shape, colour, label in (
            (True, "o", BLUE, "matches the reference"),
            (False, "X", VERMILLION, "does not match"),
        ):
            mine = group[group["matches_reference"] == matches]
            ax.scatter(mine["s_per_image"], mine["rate_err_max"], marker=shape, c=colour,
                       zorder=3, label=label)  # fmt: skip
        ax.scatter(ref["s_per_image"], ref["rate_err_max"], marker="*", s=160, c="k",
                   label="reference", zorder=4)  # fmt: skip
        chosen = defaults[(defaults["part"] == part) & (defaults["axis"] == axis)]
        name = chosen["cheapest_matching"].iloc[0] if len(chosen) else None
        hit = group[group["rung"] == name]
        if len(hit):
            ax.scatter(hit["s_per_image"], hit["rate_err_max"], s=260, facecolors="none",
                       edgecolors=BLACK, linewidths=2, label="knee", zorder=5)  # fmt: skip
        large = pd.concat([ref, hit])[["s_per_image", "rate_err_max"]].to_numpy()
        named.append((ax, group["s_per_image"], group["rate_err_max"], group["rung"], large))
        ax.set_xscale("log")
        # narrow ranges have no decade tick: label every tick, small; wide ones their decades
        seconds = pd.concat([group["s_per_image"], ref["s_per_image"]])
        narrow = seconds.max() < 10 * seconds.min()
        ax.xaxis.set_major_formatter(FormatStrFormatter("%.3g"))
        ax.xaxis.set_minor_formatter(FormatStrFormatter("%.3g") if narrow else NullFormatter())
        ax.tick_params(axis="x", which="both", labelsize=6, labelrotation=45)
        ax.set_title(f"{part}: {axis}", fontsize=9)
        ax.set_xlabel("wall s per image")
        ax.set_ylabel("max |rate - ref|")
        ax.grid(alpha=0.3)
    for ax in axes[len(panels) :]:
        ax.axis("off")
    labelled = {}
    for ax in axes[: len(panels)]:
        for handle, label in zip(*ax.get_legend_handles_labels(), strict=True):
            labelled.setdefault(label, handle)
    legend_outside(fig, list(labelled.values()), list(labelled), fontsize=8)
    title = "Fidelity ladder: outcome error against cost (each rung against the reference)"
    fig.suptitle(titled(title, options))
    fig.canvas.draw()  # once: the names stay out of the layout (label_points)
    for ax, xs, ys, names, large in named:
        label_points(ax, xs, ys, names, avoid=large, draw=False)
    save(fig, path)
