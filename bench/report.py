"""Aggregate per-image detection results into per-cell statistics and plots.

The input is the per-image table written by the benchmark runner (one row per rendered
image). A *cell* is one combination of :data:`CELL_KEYS`; every statistic here is computed
per cell, and the study's figure of merit (:func:`max_phi`) is derived from the per-cell
summary.
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
from matplotlib.patches import Rectangle  # noqa: E402

__all__ = [
    "CELL_KEYS",
    "GROUP_KEYS",
    "SUMMARY_COLUMNS",
    "MAX_PHI_COLUMNS",
    "wilson_interval",
    "summarize",
    "summary_to_csv_bytes",
    "max_phi",
    "plot_max_phi",
    "plot_heatmap",
    "plot_pose_error",
]

#: Two-sided 95 % standard normal quantile.
Z_95 = 1.959963984540054

#: Columns that identify one cell of the study grid.
CELL_KEYS: list[str] = ["lighting", "size_mm", "alpha_deg", "phi_deg"]

#: Columns that identify one curve point of the figure of merit (a cell without phi).
GROUP_KEYS: list[str] = ["lighting", "size_mm", "alpha_deg"]

#: Per-image error columns summarised per cell (only over images with ``id_ok``).
_METRICS: list[str] = ["corner_err_px", "rot_err_deg", "trans_err_mm"]

#: Columns of :func:`summarize`'s output, in order.
SUMMARY_COLUMNS: list[str] = [
    *CELL_KEYS,
    "n_images",
    "n_detected",
    "n_id_ok",
    "detection_rate",
    "rate_lo",
    "rate_hi",
    "corner_err_px_median",
    "corner_err_px_max",
    "rot_err_deg_median",
    "rot_err_deg_max",
    "trans_err_mm_median",
    "trans_err_mm_max",
    "ambiguity_ratio_median",
]

#: Columns of :func:`max_phi`'s output, in order.
MAX_PHI_COLUMNS: list[str] = [
    *GROUP_KEYS,
    "max_phi_deg",
    "max_phi_lower_deg",
    "n_images_per_cell",
    "phi_max_tested_deg",
]

_REQUIRED_IMAGE_COLUMNS: list[str] = [
    *CELL_KEYS,
    "detected",
    "id_ok",
    *_METRICS,
    "ambiguity_ratio",
]

# Rates are ratios of small integers; allow for the last-bit rounding of e.g. 57/60 vs 0.95.
_RATE_TOL = 1e-12

_DPI = 120
_NAN_Y = -5.0  # where "threshold never reached" is drawn in plot_max_phi
_LINESTYLES = ["-", "--", ":", "-."]
# Red (0) to green (1), with most of the colour change spent near the 95 % threshold where
# the study's decisions are made: 0.90 is pale yellow-green, 0.95 mid green, 1.0 dark green.
_RATE_CMAP = LinearSegmentedColormap.from_list(
    "red_yellow_green",
    [
        (0.0, "#b71c1c"),
        (0.5, "#f57c00"),
        (0.8, "#fdd835"),
        (0.9, "#dce775"),
        (0.95, "#66bb6a"),
        (1.0, "#1b5e20"),
    ],
)


# --------------------------------------------------------------------------------------
# statistics
# --------------------------------------------------------------------------------------


def wilson_interval(
    successes: np.ndarray | Sequence[float] | float,
    trials: np.ndarray | Sequence[float] | float,
    z: float = Z_95,
) -> tuple[np.ndarray, np.ndarray]:
    """Wilson score interval for a binomial proportion, vectorised over arrays.

    Why Wilson and not the normal (Wald) interval ``p +- z*sqrt(p(1-p)/n)``: the study's
    threshold is a 95 % detection rate estimated from ~60 images per cell, i.e. right next
    to the p = 1 boundary. There the Wald interval collapses to zero width at k = n
    (claiming certainty from 60 images), spills above 1, and has coverage far below its
    nominal level. The Wilson interval stays inside [0, 1], is never degenerate for n > 0,
    and keeps near-nominal coverage for p close to 0 or 1 (Brown, Cai & DasGupta 2001,
    "Interval Estimation for a Binomial Proportion", Statistical Science 16(2)).

    Args:
        successes: number of successes k (broadcastable with ``trials``).
        trials: number of trials n >= k >= 0.
        z: standard normal quantile; the default gives a two-sided 95 % interval.

    Returns:
        ``(lo, hi)`` arrays of the broadcast shape. Cells with ``trials == 0`` carry no
        information and get ``(0, 1)``; ``k == 0`` gives ``lo == 0`` and ``k == n`` gives
        ``hi == 1`` exactly.
    """
    k = np.asarray(successes, dtype=float)
    n = np.asarray(trials, dtype=float)
    k, n = np.broadcast_arrays(k, n)
    if np.any(n < 0) or np.any(k < 0) or np.any(k > n):
        raise ValueError("wilson_interval needs 0 <= successes <= trials")
    if not z > 0:
        raise ValueError(f"z must be positive, got {z}")

    empty = n == 0
    n_safe = np.where(empty, 1.0, n)
    p = k / n_safe
    z2 = z * z
    denom = 1.0 + z2 / n_safe
    center = (p + z2 / (2.0 * n_safe)) / denom
    half = z * np.sqrt(p * (1.0 - p) / n_safe + z2 / (4.0 * n_safe * n_safe)) / denom
    lo = np.clip(center - half, 0.0, 1.0)
    hi = np.clip(center + half, 0.0, 1.0)
    lo = np.where(k == 0, 0.0, lo)
    hi = np.where(k == n, 1.0, hi)
    lo = np.where(empty, 0.0, lo)
    hi = np.where(empty, 1.0, hi)
    return lo, hi


def summarize(images: pd.DataFrame) -> pd.DataFrame:
    """Collapse the per-image table into one row per cell (:data:`CELL_KEYS`).

    Counts: ``n_images``, ``n_detected`` (any marker found), ``n_id_ok`` (right id found:
    this is what counts as a detection). ``detection_rate = n_id_ok / n_images`` with its
    Wilson 95 % interval ``rate_lo``/``rate_hi``. Error statistics (median and max of
    corner, rotation and translation error, median ambiguity ratio) use only images with
    ``id_ok`` and are NaN in cells without a detection. Extra input columns are ignored and
    the input is not modified. Rows are sorted by :data:`CELL_KEYS`, so the result does not
    depend on the input row order.
    """
    missing = [c for c in _REQUIRED_IMAGE_COLUMNS if c not in images.columns]
    if missing:
        raise ValueError(f"per-image table lacks columns: {missing}")

    id_ok = images["id_ok"].astype(bool)
    work = pd.DataFrame(
        {
            **{key: images[key] for key in CELL_KEYS},
            "detected": images["detected"].astype(bool).astype(np.int64),
            "id_ok": id_ok.astype(np.int64),
            # error values of images without the right id are meaningless: mask them
            **{m: images[m].astype(float).where(id_ok) for m in _METRICS},
            "ambiguity_ratio": images["ambiguity_ratio"].astype(float).where(id_ok),
        }
    )
    grouped = work.groupby(CELL_KEYS, sort=True, dropna=False)
    out = grouped.agg(
        n_images=("id_ok", "size"),
        n_detected=("detected", "sum"),
        n_id_ok=("id_ok", "sum"),
        corner_err_px_median=("corner_err_px", "median"),
        corner_err_px_max=("corner_err_px", "max"),
        rot_err_deg_median=("rot_err_deg", "median"),
        rot_err_deg_max=("rot_err_deg", "max"),
        trans_err_mm_median=("trans_err_mm", "median"),
        trans_err_mm_max=("trans_err_mm", "max"),
        ambiguity_ratio_median=("ambiguity_ratio", "median"),
    ).reset_index()
    for col in ("n_images", "n_detected", "n_id_ok"):
        out[col] = out[col].astype(np.int64)
    n = out["n_images"].to_numpy(dtype=float)
    k = out["n_id_ok"].to_numpy(dtype=float)
    out["detection_rate"] = k / n  # groups are never empty, n >= 1
    out["rate_lo"], out["rate_hi"] = wilson_interval(k, n)
    out = out.sort_values(CELL_KEYS, kind="mergesort").reset_index(drop=True)
    return out[SUMMARY_COLUMNS]


def summary_to_csv_bytes(summary: pd.DataFrame) -> bytes:
    """Serialise a summary (or max-phi) table to deterministic CSV bytes.

    Rows are (stably) sorted by whichever of :data:`CELL_KEYS` are present, floats are
    written with ``%.6g``, line endings are ``\\n`` and the encoding is UTF-8, so the same
    table gives byte-identical output regardless of row order or platform.
    """
    keys = [k for k in CELL_KEYS if k in summary.columns]
    table = summary
    if keys:
        table = summary.sort_values(keys, kind="mergesort")
    text = table.to_csv(index=False, float_format="%.6g", lineterminator="\n")
    return text.encode("utf-8")


def max_phi(summary: pd.DataFrame, threshold: float = 0.95) -> pd.DataFrame:
    """Largest tilt phi that is still reliably detected, per (lighting, size, alpha).

    This is the original study's figure of merit: for each marker size and angular
    position alpha in the fisheye field of view, the largest tilt phi at which the marker
    is still detected with rate >= ``threshold``.

    Columns:
        ``max_phi_deg``: largest ``phi_deg`` with ``detection_rate >= threshold`` (NaN if
            no phi passes). It is the largest passing phi, not the end of the first passing
            run, so an isolated pass after a failing phi counts.
        ``max_phi_lower_deg``: the same using the Wilson lower bound ``rate_lo`` (a
            conservative version; always <= ``max_phi_deg`` where both exist). Note that
            at ``threshold=0.95`` even n/n detections give ``rate_lo = n / (n + z^2) < 0.95``
            for n <= 72, so with ~60 images per cell this column is NaN everywhere.
        ``n_images_per_cell``: the smallest ``n_images`` over the group's cells.
        ``phi_max_tested_deg``: the largest phi in the grid for this group; a
            ``max_phi_deg`` equal to it is censored (the true limit may be higher).
    """
    if not 0.0 <= threshold <= 1.0:
        raise ValueError(f"threshold must lie in [0, 1], got {threshold}")
    missing = [
        c for c in [*CELL_KEYS, "n_images", "detection_rate", "rate_lo"] if c not in summary.columns
    ]
    if missing:
        raise ValueError(f"summary table lacks columns: {missing}")

    phi = summary["phi_deg"].astype(float)
    work = pd.DataFrame(
        {
            **{key: summary[key] for key in GROUP_KEYS},
            "pass_point": phi.where(summary["detection_rate"] >= threshold - _RATE_TOL),
            "pass_lower": phi.where(summary["rate_lo"] >= threshold - _RATE_TOL),
            "n_images": summary["n_images"],
            "phi": phi,
        }
    )
    out = (
        work.groupby(GROUP_KEYS, sort=True, dropna=False)
        .agg(
            max_phi_deg=("pass_point", "max"),
            max_phi_lower_deg=("pass_lower", "max"),
            n_images_per_cell=("n_images", "min"),
            phi_max_tested_deg=("phi", "max"),
        )
        .reset_index()
    )
    out["n_images_per_cell"] = out["n_images_per_cell"].astype(np.int64)
    out = out.sort_values(GROUP_KEYS, kind="mergesort").reset_index(drop=True)
    return out[MAX_PHI_COLUMNS]


# --------------------------------------------------------------------------------------
# plots
# --------------------------------------------------------------------------------------


def _size_colors(sizes: Sequence[float]) -> dict[float, tuple[float, float, float, float]]:
    """One distinguishable colour per marker size (stable across plots)."""
    cmap = plt.get_cmap("tab10")
    return {s: cmap(i % 10) for i, s in enumerate(sorted(sizes))}


def _fmt_num(value: float) -> str:
    return f"{value:g}"


def _save(fig: plt.Figure, path: pathlib.Path) -> None:
    path = pathlib.Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=_DPI)
    plt.close(fig)


def _require(table: pd.DataFrame, columns: Sequence[str], what: str) -> None:
    missing = [c for c in columns if c not in table.columns]
    if missing:
        raise ValueError(f"{what} lacks columns: {missing}")
    if table.empty:
        raise ValueError(f"{what} is empty: nothing to plot")


def plot_max_phi(max_phi_table: pd.DataFrame, path: pathlib.Path, threshold: float = 0.95) -> None:
    """Plot the figure of merit: max detectable tilt phi vs field angle alpha.

    One solid line per marker size (point estimate) and a dashed line of the same colour
    for the Wilson-lower-bound version; one panel per lighting. Groups where no phi
    reaches the threshold are drawn as an 'x' at phi = -5 deg (slightly spread along alpha
    so that sizes do not hide each other). ``threshold`` is only used for labels.
    """
    _require(max_phi_table, [*GROUP_KEYS, "max_phi_deg", "max_phi_lower_deg"], "max-phi table")
    table = max_phi_table.sort_values(GROUP_KEYS, kind="mergesort")
    lightings = list(pd.unique(table["lighting"]))
    sizes = sorted(pd.unique(table["size_mm"]))
    colors = _size_colors(sizes)
    alphas = np.sort(pd.unique(table["alpha_deg"]).astype(float))
    if "phi_max_tested_deg" in table.columns:
        phi_top = float(np.nanmax(table["phi_max_tested_deg"].to_numpy(dtype=float)))
    else:
        values = table[["max_phi_deg", "max_phi_lower_deg"]].to_numpy(dtype=float)
        phi_top = float(np.nanmax(values)) if np.isfinite(values).any() else 10.0
    phi_top = max(phi_top, 10.0)
    alpha_span = float(alphas.max() - alphas.min()) if alphas.size > 1 else 10.0
    # spread of the 'x' markers of different sizes along alpha
    jitter = 0.006 * alpha_span
    offsets = {s: (i - (len(sizes) - 1) / 2.0) * jitter for i, s in enumerate(sizes)}

    n_panels = len(lightings)
    fig_w = 2.0 + 4.8 * n_panels
    fig, axes = plt.subplots(
        1, n_panels, figsize=(fig_w, 5.6), sharey=True, squeeze=False, layout="constrained"
    )
    pct = f"{threshold * 100:g}%"
    for ax, lighting in zip(axes[0], lightings, strict=True):
        sub = table[table["lighting"] == lighting]
        for size, grp in sub.groupby("size_mm", sort=True):
            x = grp["alpha_deg"].to_numpy(dtype=float)
            y = grp["max_phi_deg"].to_numpy(dtype=float)
            y_lo = grp["max_phi_lower_deg"].to_numpy(dtype=float)
            c = colors[size]
            ax.plot(x, y, "-o", color=c, lw=1.8, ms=5)
            ax.plot(x, y_lo, "--", color=c, lw=1.3, marker="o", ms=3, mfc="white")
            nan_x = x[np.isnan(y)] + offsets[size]
            ax.plot(nan_x, np.full(nan_x.shape, _NAN_Y), "x", color=c, ms=7, mew=2, ls="none")
        ax.axhline(0.0, color="0.6", lw=0.6, zorder=0)
        ax.set_title(f"lighting: {lighting}" if n_panels > 1 or lighting else "max phi")
        ax.set_xlabel("field angle alpha (deg)")
        ax.set_xticks(alphas)
        ax.set_xticklabels([_fmt_num(a) for a in alphas], fontsize=8)
        pad = 0.04 * alpha_span
        ax.set_xlim(alphas.min() - pad, alphas.max() + pad)
        ax.grid(True, alpha=0.3)
    axes[0, 0].set_ylabel(f"max tilt phi with detection rate \u2265 {pct} (deg)")
    axes[0, 0].set_ylim(_NAN_Y - 3.0, phi_top + 3.0)
    step = 10.0 if phi_top > 30 else 5.0
    axes[0, 0].set_yticks(np.arange(0.0, phi_top + 0.5 * step, step))

    size_handles = [
        Line2D([], [], color=colors[s], marker="o", lw=1.8, label=f"{_fmt_num(s)} mm")
        for s in sizes
    ]
    fig.legend(
        handles=size_handles,
        loc="outside right upper",
        title="marker size",
        fontsize=8,
        title_fontsize=8,
        frameon=False,
    )
    lower_note = "" if table["max_phi_lower_deg"].notna().any() else " (reached nowhere)"
    style_handles = [
        Line2D(
            [],
            [],
            color="0.2",
            ls="-",
            marker="o",
            ms=5,
            label=f"solid: detection rate \u2265 {pct}",
        ),
        Line2D(
            [],
            [],
            color="0.2",
            ls="--",
            marker="o",
            ms=3,
            mfc="white",
            label=f"dashed: Wilson 95% lower bound \u2265 {pct}{lower_note}",
        ),
        Line2D(
            [],
            [],
            color="0.2",
            ls="none",
            marker="x",
            ms=7,
            mew=2,
            label=f"x at {_fmt_num(_NAN_Y)} deg: no phi reaches {pct} (point estimate)",
        ),
    ]
    fig.legend(
        handles=style_handles,
        loc="outside lower center",
        ncol=len(style_handles) if fig_w >= 10 else 1,
        fontsize=8,
        frameon=False,
    )
    fig.suptitle("Largest detectable marker tilt vs position in the field of view")
    _save(fig, path)


def _text_color(rgba: tuple[float, float, float, float]) -> str:
    r, g, b = rgba[:3]
    return "white" if 0.299 * r + 0.587 * g + 0.114 * b < 0.45 else "black"


def _rate_label(rate: float) -> str:
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


def plot_heatmap(summary: pd.DataFrame, path: pathlib.Path, threshold: float = 0.95) -> None:
    """Detection rate heatmaps: alpha (columns) x phi (rows), one panel per size/lighting.

    Grid rows are lightings, grid columns are marker sizes. Colour runs from red (rate 0)
    to green (rate 1); each cell shows its rate, and cells below ``threshold`` have bold
    text and a black outline. Cells missing from the summary are grey.
    """
    _require(summary, [*CELL_KEYS, "detection_rate"], "summary table")
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
        figsize=(1.4 + panel_w * n_cols, 0.8 + panel_h * n_rows),
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
            grid = (
                sub.pivot_table(
                    index="phi_deg", columns="alpha_deg", values="detection_rate", aggfunc="mean"
                )
                .reindex(index=phis, columns=alphas)
                .to_numpy(dtype=float)
            )
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
                low = rate < threshold - _RATE_TOL
                label = _rate_label(rate)
                ax.text(
                    c,
                    r,
                    label,
                    ha="center",
                    va="center",
                    fontsize=fontsize,
                    fontweight="bold" if low else "normal",
                    color=_text_color(cmap(rate)),
                )
                if low:
                    ax.add_patch(
                        Rectangle((c - 0.5, r - 0.5), 1.0, 1.0, fill=False, ec="black", lw=0.8)
                    )
            title = f"{_fmt_num(size)} mm"
            if n_rows > 1 or lighting:
                title += f", {lighting}"
            ax.set_title(title, fontsize=9)
            ax.set_xticks(np.arange(alphas.size))
            ax.set_xticklabels([_fmt_num(a) for a in alphas], fontsize=7)
            ax.set_yticks(np.arange(phis.size))
            ax.set_yticklabels([_fmt_num(p) for p in phis], fontsize=7)
            if i == n_rows - 1:
                ax.set_xlabel("alpha (deg)", fontsize=8)
            if j == 0:
                ax.set_ylabel("tilt phi (deg)", fontsize=8)
    cbar = fig.colorbar(image, ax=axes, shrink=0.9, aspect=30)
    cbar.set_label("detection rate (right id)")
    cbar.ax.axhline(threshold, color="black", lw=1.0)
    fig.suptitle(
        f"Detection rate per cell (bold, outlined: below {threshold * 100:g}%)", fontsize=11
    )
    _save(fig, path)


def plot_pose_error(
    summary: pd.DataFrame, path: pathlib.Path, phi_deg: float | None = None
) -> None:
    """Median pose error vs alpha: rotation (deg) and translation (mm) panels.

    One colour per marker size and one line style per lighting. Each point collapses
    phi: with ``phi_deg=None`` it is the median over phi of the per-cell median errors
    (cells without a detection are skipped); with a value only that phi is used. The
    y axis is logarithmic when the positive values span more than a factor 30.
    """
    _require(summary, [*CELL_KEYS, "rot_err_deg_median", "trans_err_mm_median"], "summary table")
    table = summary
    if phi_deg is not None:
        table = summary[np.isclose(summary["phi_deg"].astype(float), phi_deg)]
        if table.empty:
            raise ValueError(f"no cells with phi_deg == {phi_deg}")
    collapsed = (
        table.groupby(GROUP_KEYS, sort=True, dropna=False)[
            ["rot_err_deg_median", "trans_err_mm_median"]
        ]
        .median()
        .reset_index()
    )
    lightings = list(pd.unique(collapsed["lighting"]))
    sizes = sorted(pd.unique(collapsed["size_mm"]))
    colors = _size_colors(sizes)
    styles = {lt: _LINESTYLES[i % len(_LINESTYLES)] for i, lt in enumerate(lightings)}
    alphas = np.sort(pd.unique(collapsed["alpha_deg"]).astype(float))

    fig, axes = plt.subplots(1, 2, figsize=(11.0, 4.6), layout="constrained")
    panels = [
        ("rot_err_deg_median", "median rotation error (deg)", "Rotation error"),
        ("trans_err_mm_median", "median translation error (mm)", "Translation error"),
    ]
    for ax, (col, ylabel, title) in zip(axes, panels, strict=True):
        for (lighting, size), grp in collapsed.groupby(["lighting", "size_mm"], sort=True):
            ax.plot(
                grp["alpha_deg"],
                grp[col],
                ls=styles[lighting],
                color=colors[size],
                marker="o",
                ms=4,
                lw=1.5,
            )
        values = collapsed[col].to_numpy(dtype=float)
        positive = values[np.isfinite(values) & (values > 0)]
        if (
            positive.size
            and positive.max() / positive.min() > 30
            and (positive.size == np.isfinite(values).sum())
        ):
            ax.set_yscale("log")
        ax.set_xlabel("field angle alpha (deg)")
        ax.set_ylabel(ylabel)
        ax.set_title(title)
        ax.set_xticks(alphas)
        ax.set_xticklabels([_fmt_num(a) for a in alphas], fontsize=8)
        ax.grid(True, alpha=0.3, which="both")

    handles = [
        Line2D([], [], color=colors[s], marker="o", ms=4, label=f"{_fmt_num(s)} mm") for s in sizes
    ]
    if len(lightings) > 1:
        handles += [
            Line2D([], [], color="0.2", ls=styles[lt], label=f"lighting: {lt}") for lt in lightings
        ]
    fig.legend(
        handles=handles,
        loc="outside lower center",
        ncol=min(len(handles), 8),
        fontsize=8,
        frameon=False,
    )
    how = (
        f"at phi = {_fmt_num(phi_deg)} deg"
        if phi_deg is not None
        else "median over phi of per-cell medians"
    )
    fig.suptitle(f"Pose error of detected markers vs field angle ({how})")
    _save(fig, path)
