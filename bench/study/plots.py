"""The detectability study's figures: max phi with its PSF band, the rate heatmap, pose errors.

They draw the tables of :mod:`bench.study.report` (per-cell summary, per-scale max phi), in the
look of :mod:`bench.study.plot_style`.
"""

from __future__ import annotations

import pathlib
from collections.abc import Sequence

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
from matplotlib.colors import LinearSegmentedColormap  # noqa: E402
from matplotlib.lines import Line2D  # noqa: E402
from matplotlib.patches import Patch, Rectangle  # noqa: E402
from matplotlib.ticker import FormatStrFormatter, FuncFormatter  # noqa: E402

from bench.common.figures import BLUE, SKY_BLUE, VERMILLION, YELLOW, titled  # noqa: E402
from bench.study.plot_style import (  # noqa: E402
    REFINEMENT_STYLES,
    at_nominal,
    detector_note,
    fmt_num,
    minor_log_label,
    rate_label,
    save,
    scale_note,
    size_colors,
    text_color,
)
from bench.study.report import (  # noqa: E402
    BAND_KEYS,
    CELL_KEYS,
    PERCENTILE,
    REFINEMENTS,
    THRESHOLD,
    band,
    passes,
    require_columns,
)

_NAN_Y = -5.0  # where "threshold never reached" is drawn in plot_max_phi
# Vermillion (0) through yellow to blue (1): the blue-orange axis that colour-blind readers see
# (a red-green map is the one they cannot), with most of the change spent near the 95 %
# threshold where the study's decisions are made: 0.90 is sky blue, 0.95 blue, 1.0 dark blue.
_RATE_CMAP = LinearSegmentedColormap.from_list(
    "vermillion_yellow_blue",
    [
        (0.0, VERMILLION),
        (0.5, "#eec06b"),
        (0.8, YELLOW),
        (0.9, SKY_BLUE),
        (0.95, BLUE),
        (1.0, "#08306b"),
    ],
)


def plot_max_phi(
    max_phi_table: pd.DataFrame,
    path: pathlib.Path,
    threshold: float = THRESHOLD,
    nominal_scale: float = 1.0,
    detector: str | None = None,
    options: Sequence[str] = (),
) -> None:
    """Plot the figure of merit with its PSF band: max detectable tilt phi vs field angle alpha.

    Takes :func:`max_phi`'s per-scale table. Per marker size: a line at the nominal scale and,
    with more than one scale, at each alpha a shaded bar from the smallest to the largest max
    phi over the scales (:func:`band`); the sizes stand side by side around each alpha, as
    overlapping filled bands of four sizes could not be told apart. One panel per lighting.
    "No phi reaches the threshold" is drawn at phi = -5 deg: an 'x' for the nominal scale, and
    a bar reaching down to it fails at some scale. ``threshold`` is only used for labels;
    ``detector`` (what found the markers) and ``options`` (the run's non-default options, as
    :func:`bench.study.config.nondefault_options` spells them) go into the title.
    """
    table = band(max_phi_table, nominal_scale)
    scales = np.sort(pd.unique(max_phi_table["psf_scale"].astype(float))).tolist()
    nominal = float(table["psf_scale_nominal"].iloc[0])
    lightings = list(pd.unique(table["lighting"]))
    sizes = sorted(pd.unique(table["size_mm"]))
    colors = size_colors(sizes)
    alphas = np.sort(pd.unique(table["alpha_deg"]).astype(float))
    phi_top = max(float(np.nanmax(table["phi_max_tested_deg"].to_numpy(dtype=float))), 10.0)
    alpha_span = float(alphas.max() - alphas.min()) if alphas.size > 1 else 10.0
    # sizes are dodged along alpha so that their bars stand side by side: together they fill
    # 80 % of the narrowest gap between tested alphas, and at most 10 % of the alpha range
    gap = float(np.diff(alphas).min()) if alphas.size > 1 else alpha_span
    width = min(0.8 * gap, 0.1 * alpha_span) / len(sizes)
    offsets = {s: (i - (len(sizes) - 1) / 2.0) * width for i, s in enumerate(sizes)}

    n_panels = len(lightings)
    fig_w = 2.6 + 4.8 * n_panels
    fig, axes = plt.subplots(
        1, n_panels, figsize=(fig_w, 5.8), sharey=True, squeeze=False, layout="constrained"
    )
    pct = f"{threshold * 100:g}%"
    for ax, lighting in zip(axes[0], lightings, strict=True):
        sub = table[table["lighting"] == lighting]
        for size, grp in sub.groupby("size_mm", sort=True):
            x = grp["alpha_deg"].to_numpy(dtype=float) + offsets[size]
            y = grp["max_phi_deg"].to_numpy(dtype=float)
            c = colors[size]
            if len(scales) > 1:
                # "fails at some scale" (NaN band_lo) reaches down to the "none" level
                lo = grp["band_lo_deg"].fillna(_NAN_Y).to_numpy(dtype=float)
                hi = grp["band_hi_deg"].fillna(_NAN_Y).to_numpy(dtype=float)
                ax.bar(x, hi - lo, width, bottom=lo, color=c, alpha=0.3, ec=c, lw=0.6)
            ax.plot(x, y, "-o", color=c, lw=1.6, ms=4.5)
            nan_x = x[np.isnan(y)]
            ax.plot(nan_x, np.full(nan_x.shape, _NAN_Y), "x", color=c, ms=7, mew=2, ls="none")
        ax.axhline(0.0, color="0.6", lw=0.6, zorder=0)
        ax.set_title(f"lighting: {lighting}" if n_panels > 1 or lighting else "max phi")
        ax.set_xlabel("field angle alpha (deg)")
        ax.set_xticks(alphas)
        ax.set_xticklabels([fmt_num(a) for a in alphas], fontsize=8)
        pad = 0.04 * alpha_span + 0.5 * width * len(sizes)
        ax.set_xlim(alphas.min() - pad, alphas.max() + pad)
        ax.grid(True, alpha=0.3)
    axes[0, 0].set_ylabel(f"max tilt phi with detection rate \u2265 {pct} (deg)")
    axes[0, 0].set_ylim(_NAN_Y - 3.0, phi_top + 3.0)
    step = 10.0 if phi_top > 30 else 5.0
    ticks = np.arange(0.0, phi_top + 0.5 * step, step)
    axes[0, 0].set_yticks([_NAN_Y, *ticks])
    axes[0, 0].set_yticklabels(["none", *(fmt_num(t) for t in ticks)])

    size_handles = [
        Line2D([], [], color=colors[s], marker="o", lw=1.8, label=f"{fmt_num(s)} mm") for s in sizes
    ]
    fig.legend(
        handles=size_handles,
        loc="outside right center",
        title="marker size",
        fontsize=8,
        title_fontsize=8,
        frameon=False,
    )
    style_handles = [
        Line2D([], [], color="0.2", marker="o", ms=5, label=f"line: PSF scale {fmt_num(nominal)}"),
        Line2D(
            [],
            [],
            color="0.2",
            ls="none",
            marker="x",
            ms=7,
            mew=2,
            label=f"none: no tested phi reaches {pct}",
        ),
    ]
    if len(scales) > 1:
        listed = ", ".join(fmt_num(s) for s in scales)
        style_handles.insert(
            1,
            Patch(
                color="0.2",
                alpha=0.2,
                label=f"band: min\u2013max over PSF scales {listed}"
                f" (down to none: some scale never reaches {pct})",
            ),
        )
    fig.legend(
        handles=style_handles,
        loc="outside lower center",
        ncol=len(style_handles) if fig_w >= 10 else 1,
        fontsize=8,
        frameon=False,
    )
    title = "Largest detectable marker tilt vs position in the field of view"
    title += f"{detector_note(detector)}\n" + (
        f"line: PSF scale {fmt_num(nominal)}; band: PSF scale "
        f"{fmt_num(scales[0])}\u2013{fmt_num(scales[-1])}"
        if len(scales) > 1
        else f"PSF scale {fmt_num(nominal)} (no band)"
    )
    fig.suptitle(titled(title, options), fontsize=11)
    save(fig, path)


def plot_heatmap(
    summary: pd.DataFrame,
    path: pathlib.Path,
    threshold: float = THRESHOLD,
    nominal_scale: float = 1.0,
    detector: str | None = None,
    options: Sequence[str] = (),
) -> None:
    """Detection rate heatmaps at the nominal PSF scale: alpha (columns) x phi (rows).

    Grid rows are lightings, grid columns are marker sizes. Only the nominal scale is drawn:
    five scales would multiply the panels by five, and what the scales change (the max phi)
    is the band of :func:`plot_max_phi`; the other scales' rates are in the summary table.
    Colour runs from red (rate 0) to green (rate 1); each cell shows its rate, cells below
    ``threshold`` have bold text and a black outline, and a '?' marks a cell whose Wilson
    interval still holds the threshold (undecided at the image cap). Untested cells are grey.
    ``detector`` (what found the markers) and ``options`` go into the title.
    """
    needed = [*CELL_KEYS, "detection_rate", "decided"]
    require_columns(summary, needed, "summary table", nonempty=True)
    summary, nominal, scales = at_nominal(summary, nominal_scale)
    lightings = list(pd.unique(summary.sort_values("lighting")["lighting"]))
    sizes = sorted(pd.unique(summary["size_mm"]))
    alphas = np.sort(pd.unique(summary["alpha_deg"]).astype(float))
    phis = np.sort(pd.unique(summary["phi_deg"]).astype(float))
    n_rows, n_cols = len(lightings), len(sizes)
    cell_w = 0.42 if alphas.size > 4 else 0.6
    cell_h = 0.32 if phis.size > 4 else 0.5
    panel_w = max(3.4, 0.9 + cell_w * alphas.size)
    panel_h = max(2.2, 0.9 + cell_h * phis.size)
    fig, axes = plt.subplots(
        n_rows,
        n_cols,
        figsize=(1.4 + panel_w * n_cols, 1.0 + panel_h * n_rows),
        squeeze=False,
        sharex=True,
        sharey=True,
        layout="constrained",
    )
    fontsize = 6.5 if alphas.size > 6 else 8
    cmap = _RATE_CMAP.with_extremes(bad="0.8")
    image = None
    for i, lighting in enumerate(lightings):
        for j, size in enumerate(sizes):
            ax = axes[i, j]
            sub = summary[(summary["lighting"] == lighting) & (summary["size_mm"] == size)]
            grids = [
                sub.pivot_table(index="phi_deg", columns="alpha_deg", values=v, aggfunc="mean")
                .reindex(index=phis, columns=alphas)
                .to_numpy(dtype=float)
                for v in ("detection_rate", "decided")
            ]
            grid, decided = grids
            image = ax.imshow(
                np.ma.masked_invalid(grid),
                cmap=cmap,
                vmin=0.0,
                vmax=1.0,
                origin="lower",
                aspect="auto",
                interpolation="nearest",
            )
            for (r, c), rate in np.ndenumerate(grid):
                if np.isnan(rate):
                    ax.text(c, r, "-", ha="center", va="center", fontsize=fontsize)
                    continue
                low = not passes(rate, threshold)
                label = rate_label(rate) + ("" if decided[r, c] else "?")
                ax.text(
                    c,
                    r,
                    label,
                    ha="center",
                    va="center",
                    fontsize=fontsize,
                    fontweight="bold" if low else "normal",
                    color=text_color(cmap(rate)),
                )
                if low:
                    ax.add_patch(
                        Rectangle((c - 0.5, r - 0.5), 1.0, 1.0, fill=False, ec="black", lw=0.8)
                    )
            title = f"{fmt_num(size)} mm"
            if n_rows > 1 or lighting:
                title += f", {lighting}"
            ax.set_title(title, fontsize=9)
            ax.set_xticks(np.arange(alphas.size))
            ax.set_xticklabels([fmt_num(a) for a in alphas], fontsize=7)
            ax.set_yticks(np.arange(phis.size))
            ax.set_yticklabels([fmt_num(p) for p in phis], fontsize=7)
            if i == n_rows - 1:
                ax.set_xlabel("alpha (deg)", fontsize=8)
            if j == 0:
                ax.set_ylabel("tilt phi (deg)", fontsize=8)
    cbar = fig.colorbar(image, ax=axes, shrink=0.9, aspect=30)
    cbar.set_label("detection rate (right id)")
    cbar.ax.axhline(threshold, color="black", lw=1.0)
    title = (
        f"Detection rate per cell, {scale_note(nominal, scales)}{detector_note(detector)}\n"
        f"bold, outlined: below {threshold * 100:g}%; ?: Wilson interval still holds "
        f"{threshold * 100:g}%; -: not tested"
    )
    fig.suptitle(titled(title, options), fontsize=10)
    save(fig, path)


def plot_pose_error(
    summary: pd.DataFrame,
    path: pathlib.Path,
    phi_deg: float | None = None,
    nominal_scale: float = 1.0,
    detector: str | None = None,
    refinements: tuple[str, ...] = REFINEMENTS,
    options: Sequence[str] = (),
) -> None:
    """Pose error vs alpha at the nominal PSF scale: median and p95, lines vs the detector's
    corners (``subpix`` for OpenCV, ``own`` for a peer: ``refinements``).

    Per lighting a 2 x 2 block: rows rotation (deg) and translation (mm), columns the per-cell
    median and :data:`PERCENTILE` th percentile over detected images. One colour per marker
    size; solid for the ``lines`` refinement, dashed for the detector's. Each point collapses phi:
    with ``phi_deg=None`` it is the median over the tested phis of the per-cell statistic
    (cells without a detection are skipped); with a value only that phi is used. A row's y
    axis is logarithmic when its positive values span more than a factor 30. ``detector``
    (what found the markers) and ``options`` go into the title.
    """
    p_stat = f"p{PERCENTILE}"
    columns = [
        f"{m}_{r}_{s}"
        for m in ("rot_err_deg", "trans_err_mm")
        for r in refinements
        for s in ("median", p_stat)
    ]
    require_columns(summary, [*CELL_KEYS, *columns], "summary table", nonempty=True)
    table, nominal, scales = at_nominal(summary, nominal_scale)
    if phi_deg is not None:
        table = table[np.isclose(table["phi_deg"].astype(float), phi_deg)]
        if table.empty:
            raise ValueError(f"phi_deg: no cells with phi_deg == {phi_deg}")
    collapsed = table.groupby(BAND_KEYS, sort=True, dropna=False)[columns].median().reset_index()
    lightings = list(pd.unique(collapsed["lighting"]))
    sizes = sorted(pd.unique(collapsed["size_mm"]))
    colors = size_colors(sizes)
    alphas = np.sort(pd.unique(collapsed["alpha_deg"]).astype(float))
    quantities = [
        ("rot_err_deg", "rotation error (deg)"),
        ("trans_err_mm", "translation error (mm)"),
    ]
    stats = [("median", "median"), (p_stat, f"{PERCENTILE}th percentile")]

    n_rows = 2 * len(lightings)
    fig, axes = plt.subplots(
        n_rows,
        2,
        figsize=(11.0, 0.9 + 3.4 * n_rows),
        squeeze=False,
        sharey="row",
        layout="constrained",
    )
    for li, lighting in enumerate(lightings):
        sub = collapsed[collapsed["lighting"] == lighting]
        for qi, (metric, label) in enumerate(quantities):
            row = axes[2 * li + qi]
            values = sub[[f"{metric}_{r}_{s}" for r in refinements for s, _ in stats]]
            values = values.to_numpy(dtype=float).ravel()
            positive = values[np.isfinite(values) & (values > 0)]
            log = (
                positive.size > 0
                and positive.max() / positive.min() > 30
                and positive.size == np.isfinite(values).sum()
            )
            for ax, (stat, stat_label) in zip(row, stats, strict=True):
                for size, grp in sub.groupby("size_mm", sort=True):
                    for refinement in refinements:
                        ax.plot(
                            grp["alpha_deg"],
                            grp[f"{metric}_{refinement}_{stat}"],
                            ls=REFINEMENT_STYLES[refinement],
                            color=colors[size],
                            marker="o",
                            ms=3.5,
                            lw=1.4,
                        )
                if log:
                    ax.set_yscale("log")
                    # plain numbers (0.2, 0.5, 1) instead of the default 2x10^-1 labels
                    ax.yaxis.set_major_formatter(FormatStrFormatter("%g"))
                    ax.yaxis.set_minor_formatter(FuncFormatter(minor_log_label))
                title = f"{stat_label} {label}"
                ax.set_title(f"{title}, {lighting}" if len(lightings) > 1 else title, fontsize=10)
                ax.set_ylabel(label)
                ax.set_xticks(alphas)
                ax.set_xticklabels([fmt_num(a) for a in alphas], fontsize=8)
                ax.grid(True, alpha=0.3, which="both")
    for ax in axes[-1]:
        ax.set_xlabel("field angle alpha (deg)")

    handles = [
        Line2D([], [], color=colors[s], marker="o", ms=4, label=f"{fmt_num(s)} mm") for s in sizes
    ]
    handles += [
        Line2D([], [], color="0.2", ls=REFINEMENT_STYLES[r], label=f"corners: {r}")
        for r in refinements
    ]
    fig.legend(
        handles=handles,
        loc="outside lower center",
        ncol=min(len(handles), 8),
        fontsize=8,
        frameon=False,
    )
    how = (
        f"at phi = {fmt_num(phi_deg)} deg"
        if phi_deg is not None
        else "median over the tested phis of the per-cell statistics"
    )
    title = (
        f"Pose error of detected markers vs field angle ({how}), {scale_note(nominal, scales)}"
        f"{detector_note(detector)}"
    )
    fig.suptitle(titled(title, options), fontsize=11)
    save(fig, path)
