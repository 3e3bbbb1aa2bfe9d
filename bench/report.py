"""Aggregate per-image detection results into per-cell statistics, the max-phi band and plots.

The input is the per-image table written by the study (one row per rendered image). A *cell*
is one combination of :data:`CELL_KEYS`; every statistic here is computed per cell. The study's
figure of merit (:func:`max_phi`) is derived per PSF scale from the per-cell summary, and
:func:`band` collapses the scales into the nominal value and its sensitivity band.
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

__all__ = [
    "BAND_COLUMNS",
    "BAND_KEYS",
    "CELL_KEYS",
    "GROUP_KEYS",
    "IMAGE_METRIC_COLUMNS",
    "MAX_PHI_COLUMNS",
    "METRICS",
    "PERCENTILE",
    "REFINEMENTS",
    "STATISTICS",
    "SUMMARY_COLUMNS",
    "THRESHOLD",
    "band",
    "excludes_threshold",
    "max_phi",
    "plot_heatmap",
    "plot_max_phi",
    "plot_pose_error",
    "summarize",
    "summary_to_csv_bytes",
    "wilson_interval",
]

#: Two-sided 95 % standard normal quantile.
Z_95 = 1.959963984540054

#: Detection rate a cell must reach: the original study's criterion (SPEC section 4).
THRESHOLD = 0.95

#: Corner refinements scored per image: OpenCV's ``subpix`` (what the original system used)
#: and this project's ``lines``.
REFINEMENTS: tuple[str, ...] = ("lines", "subpix")

#: Upper percentile reported beside median and max (NumPy's default linear interpolation
#: between order statistics, i.e. Hyndman & Fan type 7).
PERCENTILE = 95

#: Per-image error quantities; each comes once per refinement, as ``<metric>_<refinement>``.
METRICS: tuple[str, ...] = ("corner_err_px", "rot_err_deg", "trans_err_mm", "ambiguity_ratio")

#: Per-cell statistics of every metric column, as suffixes ``_<statistic>``.
STATISTICS: tuple[str, ...] = ("median", f"p{PERCENTILE}", "max")

#: Per-image metric columns, in order.
IMAGE_METRIC_COLUMNS: list[str] = [f"{m}_{r}" for m in METRICS for r in REFINEMENTS]

#: Columns that identify one cell of the study grid.
CELL_KEYS: list[str] = ["lighting", "psf_scale", "size_mm", "alpha_deg", "phi_deg"]

#: Columns that identify one max-phi value (a cell without phi).
GROUP_KEYS: list[str] = ["lighting", "psf_scale", "size_mm", "alpha_deg"]

#: Columns that identify one row of the band (a max-phi group without the PSF scale).
BAND_KEYS: list[str] = ["lighting", "size_mm", "alpha_deg"]

#: Columns of :func:`summarize`'s output, in order.
SUMMARY_COLUMNS: list[str] = [
    *CELL_KEYS,
    "n_images",
    "n_detected",
    "n_id_ok",
    "detection_rate",
    "rate_lo",
    "rate_hi",
    "decided",
    *[f"{c}_{s}" for c in IMAGE_METRIC_COLUMNS for s in STATISTICS],
]

#: Columns of :func:`max_phi`'s output, in order.
MAX_PHI_COLUMNS: list[str] = [
    *GROUP_KEYS,
    "max_phi_deg",
    "first_fail_phi_deg",
    "resolution_deg",
    "max_phi_lower_deg",
    "phi_max_tested_deg",
    "n_images_min",
    "n_images_max",
    "undecided_cells",
]

#: Columns of :func:`band`'s output, in order.
BAND_COLUMNS: list[str] = [
    *BAND_KEYS,
    "max_phi_deg",
    "band_lo_deg",
    "band_hi_deg",
    "robust",
    "max_phi_lower_deg",
    "resolution_deg",
    "phi_max_tested_deg",
    "psf_scale_nominal",
    "psf_scale_min",
    "psf_scale_max",
]

_REQUIRED_IMAGE_COLUMNS: list[str] = [*CELL_KEYS, "detected", "id_ok", *IMAGE_METRIC_COLUMNS]

# Rates are ratios of small integers; allow for the last-bit rounding of e.g. 57/60 vs 0.95.
_RATE_TOL = 1e-12

_DPI = 120
_NAN_Y = -5.0  # where "threshold never reached" is drawn in plot_max_phi
_REFINEMENT_STYLES = {"lines": "-", "subpix": "--"}
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
    threshold is a 95 % detection rate estimated from tens of images per cell, i.e. right
    next to the p = 1 boundary. There the Wald interval collapses to zero width at k = n
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


def excludes_threshold(
    rate_lo: np.ndarray | Sequence[float] | float,
    rate_hi: np.ndarray | Sequence[float] | float,
    threshold: float = THRESHOLD,
) -> np.ndarray:
    """Whether a cell is *decided*: its rate interval lies wholly above or below ``threshold``.

    Strict on both sides (``lo > threshold or hi < threshold``), so an interval that touches
    the threshold is still undecided. This is the stopping rule of the adaptive sampling and
    the ``decided`` column of :func:`summarize`: one definition for both.
    """
    _check_threshold(threshold)
    lo = np.asarray(rate_lo, dtype=float)
    hi = np.asarray(rate_hi, dtype=float)
    return (lo > threshold) | (hi < threshold)


def summarize(images: pd.DataFrame, threshold: float = THRESHOLD) -> pd.DataFrame:
    """Collapse the per-image table into one row per cell (:data:`CELL_KEYS`).

    Counts: ``n_images`` (may differ per cell: sampling is adaptive), ``n_detected`` (any
    marker found), ``n_id_ok`` (right id found: this is what counts as a detection).
    ``detection_rate = n_id_ok / n_images`` with its Wilson 95 % interval
    ``rate_lo``/``rate_hi``, and ``decided`` (:func:`excludes_threshold`). For every metric
    column ``<metric>_<refinement>`` the median, the :data:`PERCENTILE` th percentile (linear
    interpolation) and the max, as ``<column>_<statistic>``, over the images with ``id_ok``
    (errors of a wrong id are meaningless) whose value is finite; NaN where there is none.
    Extra input columns are ignored and the input is not modified. Rows are sorted by
    :data:`CELL_KEYS`, so the result does not depend on the input row order.
    """
    _check_threshold(threshold)
    _require(images, _REQUIRED_IMAGE_COLUMNS, "per-image table")
    scales = images["psf_scale"].to_numpy(dtype=float)
    bad = scales[~(np.isfinite(scales) & (scales >= 0))]
    if bad.size:
        raise ValueError(f"psf_scale must be a finite factor >= 0 (0: no blur), got {bad[0]}")

    id_ok = images["id_ok"].astype(bool)
    work = pd.DataFrame(
        {
            **{key: images[key] for key in CELL_KEYS},
            "detected": images["detected"].astype(bool).astype(np.int64),
            "id_ok": id_ok.astype(np.int64),
            **{c: images[c].astype(float).where(id_ok) for c in IMAGE_METRIC_COLUMNS},
        }
    )
    grouped = work.groupby(CELL_KEYS, sort=True, dropna=False)
    counts = grouped.agg(
        n_images=("id_ok", "size"),
        n_detected=("detected", "sum"),
        n_id_ok=("id_ok", "sum"),
    ).astype(np.int64)
    errors = grouped[IMAGE_METRIC_COLUMNS]
    stats = {  # pandas skips NaN in all three, as np.nanmedian / np.nanpercentile / np.nanmax
        "median": errors.median(),
        f"p{PERCENTILE}": errors.quantile(PERCENTILE / 100.0, interpolation="linear"),
        "max": errors.max(),
    }
    out = pd.concat(
        [counts, *(frame.add_suffix(f"_{name}") for name, frame in stats.items())], axis=1
    ).reset_index()
    n = out["n_images"].to_numpy(dtype=float)
    k = out["n_id_ok"].to_numpy(dtype=float)
    out["detection_rate"] = k / n  # groups are never empty, n >= 1
    out["rate_lo"], out["rate_hi"] = wilson_interval(k, n)
    out["decided"] = excludes_threshold(out["rate_lo"], out["rate_hi"], threshold)
    out = out.sort_values(CELL_KEYS, kind="mergesort").reset_index(drop=True)
    return out[SUMMARY_COLUMNS]


def summary_to_csv_bytes(summary: pd.DataFrame) -> bytes:
    """Serialise a summary, max-phi or band table to deterministic CSV bytes.

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


def max_phi(summary: pd.DataFrame, threshold: float = THRESHOLD) -> pd.DataFrame:
    """Largest tilt phi that is still reliably detected, per (lighting, PSF scale, size, alpha).

    This is the original study's figure of merit: for each marker size and angular
    position alpha in the fisheye field of view, the largest tilt phi at which the marker
    is still detected with rate >= ``threshold``. The tested phis may differ per group (the
    study adds tilts between the last passing and the first failing grid tilt).

    Columns:
        ``max_phi_deg``: largest ``phi_deg`` with ``detection_rate >= threshold`` (NaN if
            no phi passes). It is the largest passing phi, not the end of the first passing
            run, so an isolated pass after a failing phi counts.
        ``first_fail_phi_deg``: the smallest tested phi above ``max_phi_deg`` (it fails, as
            every phi above the largest passing one does); the smallest tested phi where none
            passes; NaN where the largest tested phi passes (censored: the limit may be higher).
        ``resolution_deg``: ``first_fail_phi_deg - max_phi_deg``, the width of the bracket
            that holds the true limit; NaN where either end is NaN.
        ``max_phi_lower_deg``: as ``max_phi_deg`` with the Wilson lower bound ``rate_lo``
            (conservative; always <= ``max_phi_deg`` where both exist). n/n detections give
            ``rate_lo = n / (n + z^2)``, above 0.95 only from n = 73 images on.
        ``phi_max_tested_deg``: the largest phi tested in the group.
        ``n_images_min``/``n_images_max``: fewest and most images of the group's cells.
        ``undecided_cells``: cells whose Wilson interval still holds ``threshold``.
    """
    _check_threshold(threshold)
    _require(
        summary,
        [*CELL_KEYS, "n_images", "detection_rate", "rate_lo", "rate_hi"],
        "summary table",
    )
    phi = summary["phi_deg"].astype(float)
    work = pd.DataFrame(
        {
            **{key: summary[key] for key in GROUP_KEYS},
            "pass_point": phi.where(summary["detection_rate"] >= threshold - _RATE_TOL),
            "pass_lower": phi.where(summary["rate_lo"] >= threshold - _RATE_TOL),
            "n_images": summary["n_images"],
            "phi": phi,
            "undecided": ~excludes_threshold(summary["rate_lo"], summary["rate_hi"], threshold),
        }
    )
    best = work.groupby(GROUP_KEYS, sort=True, dropna=False)["pass_point"].transform("max")
    # every phi above the largest passing one fails; where nothing passes, every phi fails
    work["fail_above"] = phi.where(best.isna() | (phi > best))
    out = (
        work.groupby(GROUP_KEYS, sort=True, dropna=False)
        .agg(
            max_phi_deg=("pass_point", "max"),
            first_fail_phi_deg=("fail_above", "min"),
            max_phi_lower_deg=("pass_lower", "max"),
            phi_max_tested_deg=("phi", "max"),
            n_images_min=("n_images", "min"),
            n_images_max=("n_images", "max"),
            undecided_cells=("undecided", "sum"),
        )
        .reset_index()
    )
    out["resolution_deg"] = out["first_fail_phi_deg"] - out["max_phi_deg"]
    for col in ("n_images_min", "n_images_max", "undecided_cells"):
        out[col] = out[col].astype(np.int64)
    out = out.sort_values(GROUP_KEYS, kind="mergesort").reset_index(drop=True)
    return out[MAX_PHI_COLUMNS]


def band(max_phi_table: pd.DataFrame, nominal_scale: float = 1.0) -> pd.DataFrame:
    """The nominal max phi and its band over the PSF scales, per (lighting, size, alpha).

    Rule for "no phi passes" (``max_phi_deg`` NaN at some scale): it counts as the lowest
    possible value, -inf, so ``band_lo_deg`` is NaN (written so in the CSV) exactly where
    the size fails at some scale, and ``band_hi_deg`` is NaN only where it fails at every
    scale. ``robust`` is True where the size passes at this alpha at every scale
    (``max_phi_deg >= 0`` at all of them), i.e. where ``band_lo_deg`` is not NaN.

    ``max_phi_deg``, ``max_phi_lower_deg`` and ``resolution_deg`` are those of the nominal
    scale: ``nominal_scale``, or the only scale if the table has one. ``phi_max_tested_deg``
    is the largest over the scales; ``psf_scale_nominal/_min/_max`` say which scales made
    the row. Every group must have been run at every scale, else ValueError.
    """
    _require(
        max_phi_table,
        [*GROUP_KEYS, "max_phi_deg", "max_phi_lower_deg", "resolution_deg", "phi_max_tested_deg"],
        "max-phi table",
        nonempty=True,
    )
    table = max_phi_table
    scales = np.sort(pd.unique(table["psf_scale"].astype(float)))
    nominal = _nominal_scale(scales, nominal_scale)
    per_group = table.groupby(BAND_KEYS, sort=True, dropna=False)["psf_scale"].agg(
        ["size", "nunique"]
    )
    bad = per_group[(per_group["size"] != scales.size) | (per_group["nunique"] != scales.size)]
    if not bad.empty:
        raise ValueError(
            f"max-phi table: psf_scale must appear once per group for every scale "
            f"{scales.tolist()}; group {bad.index[0]} has {int(bad['nunique'].iloc[0])} distinct "
            f"scales in {int(bad['size'].iloc[0])} rows"
        )

    reach = table["max_phi_deg"].astype(float).fillna(-np.inf)  # "never passes" = lowest
    work = pd.DataFrame({**{k: table[k] for k in BAND_KEYS}, "reach": reach})
    work["phi_max_tested_deg"] = table["phi_max_tested_deg"]
    out = (
        work.groupby(BAND_KEYS, sort=True, dropna=False)
        .agg(
            band_lo_deg=("reach", "min"),
            band_hi_deg=("reach", "max"),
            phi_max_tested_deg=("phi_max_tested_deg", "max"),
        )
        .reset_index()
    )
    out["robust"] = np.isfinite(out["band_lo_deg"])
    out[["band_lo_deg", "band_hi_deg"]] = out[["band_lo_deg", "band_hi_deg"]].replace(
        -np.inf, np.nan
    )
    at_nominal = table[np.isclose(table["psf_scale"].astype(float), nominal)]
    nominal_cols = ["max_phi_deg", "max_phi_lower_deg", "resolution_deg"]
    out = out.merge(at_nominal[[*BAND_KEYS, *nominal_cols]], on=BAND_KEYS, how="left")
    out["psf_scale_nominal"] = nominal
    out["psf_scale_min"] = float(scales[0])
    out["psf_scale_max"] = float(scales[-1])
    out = out.sort_values(BAND_KEYS, kind="mergesort").reset_index(drop=True)
    return out[BAND_COLUMNS]


def _check_threshold(threshold: float) -> None:
    if not 0.0 <= threshold <= 1.0:
        raise ValueError(f"threshold must lie in [0, 1], got {threshold}")


def _nominal_scale(scales: np.ndarray, requested: float) -> float:
    """``requested`` if among ``scales`` (to float tolerance), the only scale if there is one."""
    match = scales[np.isclose(scales, requested)]
    if match.size:
        return float(match[0])
    if scales.size == 1:
        return float(scales[0])
    raise ValueError(
        f"psf_scale: the nominal scale {requested:g} is not among the table's scales "
        f"{scales.tolist()}; pass one of them as nominal_scale"
    )


def _require(
    table: pd.DataFrame, columns: Sequence[str], what: str, nonempty: bool = False
) -> None:
    missing = [c for c in columns if c not in table.columns]
    if missing:
        raise ValueError(f"{what} lacks columns: {missing}")
    if nonempty and table.empty:
        raise ValueError(f"{what} is empty")


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


def _at_nominal(table: pd.DataFrame, nominal_scale: float) -> tuple[pd.DataFrame, float, list]:
    """Rows at the nominal PSF scale, that scale, and all scales of the table (sorted)."""
    scales = np.sort(pd.unique(table["psf_scale"].astype(float)))
    nominal = _nominal_scale(scales, nominal_scale)
    return table[np.isclose(table["psf_scale"].astype(float), nominal)], nominal, scales.tolist()


def _scale_note(nominal: float, scales: Sequence[float]) -> str:
    if len(scales) == 1:
        return f"PSF scale {_fmt_num(nominal)} (no band)"
    span = f"{_fmt_num(scales[0])}\u2013{_fmt_num(scales[-1])}"
    return f"nominal PSF scale {_fmt_num(nominal)} of {span}"


def plot_max_phi(
    max_phi_table: pd.DataFrame,
    path: pathlib.Path,
    threshold: float = THRESHOLD,
    nominal_scale: float = 1.0,
) -> None:
    """Plot the figure of merit with its PSF band: max detectable tilt phi vs field angle alpha.

    Takes :func:`max_phi`'s per-scale table. Per marker size: a line at the nominal scale and,
    with more than one scale, at each alpha a shaded bar from the smallest to the largest max
    phi over the scales (:func:`band`); the sizes stand side by side around each alpha, as
    overlapping filled bands of four sizes could not be told apart. One panel per lighting.
    "No phi reaches the threshold" is drawn at phi = -5 deg: an 'x' for the nominal scale, and
    a bar reaching down to it fails at some scale. ``threshold`` is only used for labels.
    """
    table = band(max_phi_table, nominal_scale)
    scales = np.sort(pd.unique(max_phi_table["psf_scale"].astype(float))).tolist()
    nominal = float(table["psf_scale_nominal"].iloc[0])
    lightings = list(pd.unique(table["lighting"]))
    sizes = sorted(pd.unique(table["size_mm"]))
    colors = _size_colors(sizes)
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
        ax.set_xticklabels([_fmt_num(a) for a in alphas], fontsize=8)
        pad = 0.04 * alpha_span + 0.5 * width * len(sizes)
        ax.set_xlim(alphas.min() - pad, alphas.max() + pad)
        ax.grid(True, alpha=0.3)
    axes[0, 0].set_ylabel(f"max tilt phi with detection rate \u2265 {pct} (deg)")
    axes[0, 0].set_ylim(_NAN_Y - 3.0, phi_top + 3.0)
    step = 10.0 if phi_top > 30 else 5.0
    ticks = np.arange(0.0, phi_top + 0.5 * step, step)
    axes[0, 0].set_yticks([_NAN_Y, *ticks])
    axes[0, 0].set_yticklabels(["none", *(_fmt_num(t) for t in ticks)])

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
    style_handles = [
        Line2D([], [], color="0.2", marker="o", ms=5, label=f"line: PSF scale {_fmt_num(nominal)}"),
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
        listed = ", ".join(_fmt_num(s) for s in scales)
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
    fig.suptitle(
        "Largest detectable marker tilt vs position in the field of view\n"
        + (
            f"line: PSF scale {_fmt_num(nominal)}; band: PSF scale "
            f"{_fmt_num(scales[0])}\u2013{_fmt_num(scales[-1])}"
            if len(scales) > 1
            else f"PSF scale {_fmt_num(nominal)} (no band)"
        ),
        fontsize=11,
    )
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


def plot_heatmap(
    summary: pd.DataFrame,
    path: pathlib.Path,
    threshold: float = THRESHOLD,
    nominal_scale: float = 1.0,
) -> None:
    """Detection rate heatmaps at the nominal PSF scale: alpha (columns) x phi (rows).

    Grid rows are lightings, grid columns are marker sizes. Only the nominal scale is drawn:
    five scales would multiply the panels by five, and what the scales change (the max phi)
    is the band of :func:`plot_max_phi`; the other scales' rates are in the summary table.
    Colour runs from red (rate 0) to green (rate 1); each cell shows its rate, cells below
    ``threshold`` have bold text and a black outline, and a '?' marks a cell whose Wilson
    interval still holds the threshold (undecided at the image cap). Untested cells are grey.
    """
    _require(summary, [*CELL_KEYS, "detection_rate", "decided"], "summary table", nonempty=True)
    summary, nominal, scales = _at_nominal(summary, nominal_scale)
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
                low = rate < threshold - _RATE_TOL
                label = _rate_label(rate) + ("" if decided[r, c] else "?")
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
        f"Detection rate per cell, {_scale_note(nominal, scales)}\n"
        f"bold, outlined: below {threshold * 100:g}%; ?: Wilson interval still holds "
        f"{threshold * 100:g}%; -: not tested",
        fontsize=10,
    )
    _save(fig, path)


def _minor_log_label(value: float, _pos: int) -> str:
    """Label the minor ticks 2 and 5 of each decade of a log axis, as plain numbers."""
    mantissa = value / 10.0 ** np.floor(np.log10(value))
    return f"{value:g}" if np.isclose(mantissa, [2.0, 5.0]).any() else ""


def plot_pose_error(
    summary: pd.DataFrame,
    path: pathlib.Path,
    phi_deg: float | None = None,
    nominal_scale: float = 1.0,
) -> None:
    """Pose error vs alpha at the nominal PSF scale: median and p95, lines vs subpix corners.

    Per lighting a 2 x 2 block: rows rotation (deg) and translation (mm), columns the per-cell
    median and :data:`PERCENTILE` th percentile over detected images. One colour per marker
    size; solid for the ``lines`` refinement, dashed for ``subpix``. Each point collapses phi:
    with ``phi_deg=None`` it is the median over the tested phis of the per-cell statistic
    (cells without a detection are skipped); with a value only that phi is used. A row's y
    axis is logarithmic when its positive values span more than a factor 30.
    """
    p_stat = f"p{PERCENTILE}"
    columns = [
        f"{m}_{r}_{s}"
        for m in ("rot_err_deg", "trans_err_mm")
        for r in REFINEMENTS
        for s in ("median", p_stat)
    ]
    _require(summary, [*CELL_KEYS, *columns], "summary table", nonempty=True)
    table, nominal, scales = _at_nominal(summary, nominal_scale)
    if phi_deg is not None:
        table = table[np.isclose(table["phi_deg"].astype(float), phi_deg)]
        if table.empty:
            raise ValueError(f"phi_deg: no cells with phi_deg == {phi_deg}")
    collapsed = table.groupby(BAND_KEYS, sort=True, dropna=False)[columns].median().reset_index()
    lightings = list(pd.unique(collapsed["lighting"]))
    sizes = sorted(pd.unique(collapsed["size_mm"]))
    colors = _size_colors(sizes)
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
            values = sub[[f"{metric}_{r}_{s}" for r in REFINEMENTS for s, _ in stats]]
            values = values.to_numpy(dtype=float).ravel()
            positive = values[np.isfinite(values) & (values > 0)]
            log = (
                positive.size > 0
                and positive.max() / positive.min() > 30
                and positive.size == np.isfinite(values).sum()
            )
            for ax, (stat, stat_label) in zip(row, stats, strict=True):
                for size, grp in sub.groupby("size_mm", sort=True):
                    for refinement in REFINEMENTS:
                        ax.plot(
                            grp["alpha_deg"],
                            grp[f"{metric}_{refinement}_{stat}"],
                            ls=_REFINEMENT_STYLES[refinement],
                            color=colors[size],
                            marker="o",
                            ms=3.5,
                            lw=1.4,
                        )
                if log:
                    ax.set_yscale("log")
                    # plain numbers (0.2, 0.5, 1) instead of the default 2x10^-1 labels
                    ax.yaxis.set_major_formatter(FormatStrFormatter("%g"))
                    ax.yaxis.set_minor_formatter(FuncFormatter(_minor_log_label))
                title = f"{stat_label} {label}"
                ax.set_title(f"{title}, {lighting}" if len(lightings) > 1 else title, fontsize=10)
                ax.set_ylabel(label)
                ax.set_xticks(alphas)
                ax.set_xticklabels([_fmt_num(a) for a in alphas], fontsize=8)
                ax.grid(True, alpha=0.3, which="both")
    for ax in axes[-1]:
        ax.set_xlabel("field angle alpha (deg)")

    handles = [
        Line2D([], [], color=colors[s], marker="o", ms=4, label=f"{_fmt_num(s)} mm") for s in sizes
    ]
    handles += [
        Line2D([], [], color="0.2", ls=_REFINEMENT_STYLES[r], label=f"corners: {r}")
        for r in REFINEMENTS
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
        else "median over the tested phis of the per-cell statistics"
    )
    fig.suptitle(
        f"Pose error of detected markers vs field angle ({how}), {_scale_note(nominal, scales)}",
        fontsize=11,
    )
    _save(fig, path)
