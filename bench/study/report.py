"""Aggregate per-image detection results into per-cell statistics and the max-phi band.

The input is the per-image table written by the study (one row per rendered image). A *cell*
is one combination of :data:`CELL_KEYS`; every statistic here is computed per cell. The study's
figure of merit (:func:`max_phi`) is derived per PSF scale from the per-cell summary, and
:func:`band` collapses the scales into the nominal value and its sensitivity band. The figures
are drawn by :mod:`bench.study.plots`.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pandas as pd

from bench.common.marker_score import ERRORS

__all__ = [
    "BAND_COLUMNS",
    "BAND_KEYS",
    "CELL_KEYS",
    "GROUP_KEYS",
    "IMAGE_METRIC_COLUMNS",
    "MAX_PHI_COLUMNS",
    "METRICS",
    "PEER_REFINEMENTS",
    "PERCENTILE",
    "REFINEMENTS",
    "STATISTICS",
    "SUMMARY_COLUMNS",
    "THRESHOLD",
    "band",
    "excludes_threshold",
    "image_metric_columns",
    "passes",
    "max_phi",
    "refinements_of",
    "summarize",
    "summary_columns",
    "summary_to_csv_bytes",
    "wilson_interval",
]

#: Two-sided 95 % standard normal quantile.
Z_95 = 1.959963984540054

#: Detection rate a cell must reach: the original study's criterion (SPEC section 4).
THRESHOLD = 0.95

#: Corner refinements scored per image with the ``opencv`` detector: OpenCV's ``subpix`` (what
#: the original system used) and this project's ``lines`` refined from them.
REFINEMENTS: tuple[str, ...] = ("lines", "subpix")

#: The same with a peer detector: its ``own`` corners and ``lines`` refined from them; no column
#: claims ``subpix`` for corners that are not OpenCV's cornerSubPix.
PEER_REFINEMENTS: tuple[str, ...] = ("lines", "own")

#: Upper percentile reported beside median and max (NumPy's default linear interpolation
#: between order statistics, i.e. Hyndman & Fan type 7).
PERCENTILE = 95

#: Per-image error quantities (:mod:`bench.common.marker_score`'s); each comes once per
#: refinement, as ``<metric>_<refinement>``.
METRICS: tuple[str, ...] = ERRORS

#: Per-cell statistics of every metric column, as suffixes ``_<statistic>``.
STATISTICS: tuple[str, ...] = ("median", f"p{PERCENTILE}", "max")


def refinements_of(backend: str) -> tuple[str, ...]:
    """The refinements a study with this detector backend scores (:data:`REFINEMENTS` or
    :data:`PEER_REFINEMENTS`); the last is the detector's own corners."""
    return REFINEMENTS if backend == "opencv" else PEER_REFINEMENTS


def image_metric_columns(refinements: tuple[str, ...] = REFINEMENTS) -> list[str]:
    """Per-image metric columns, in order."""
    return [f"{m}_{r}" for m in METRICS for r in refinements]


IMAGE_METRIC_COLUMNS: list[str] = image_metric_columns()  #: of the ``opencv`` detector

#: Columns that identify one cell of the study grid.
CELL_KEYS: list[str] = ["lighting", "psf_scale", "size_mm", "alpha_deg", "phi_deg"]

#: Columns that identify one max-phi value (a cell without phi).
GROUP_KEYS: list[str] = ["lighting", "psf_scale", "size_mm", "alpha_deg"]

#: Columns that identify one row of the band (a max-phi group without the PSF scale).
BAND_KEYS: list[str] = ["lighting", "size_mm", "alpha_deg"]


def summary_columns(refinements: tuple[str, ...] = REFINEMENTS) -> list[str]:
    """Columns of :func:`summarize`'s output, in order."""
    return [
        *CELL_KEYS,
        "n_images",
        "n_detected",
        "n_id_ok",
        "backend_failures",
        "detection_rate",
        "rate_lo",
        "rate_hi",
        "decided",
        *[f"{c}_{s}" for c in image_metric_columns(refinements) for s in STATISTICS],
    ]


SUMMARY_COLUMNS: list[str] = summary_columns()  #: of the ``opencv`` detector

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

# Rates are ratios of small integers; allow for the last-bit rounding of e.g. 57/60 vs 0.95.
RATE_TOL = 1e-12


def passes(rate, threshold: float = THRESHOLD):
    """Whether a detection rate (scalar or array) reaches the threshold, up to RATE_TOL."""
    return rate >= threshold - RATE_TOL


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


def summarize(
    images: pd.DataFrame,
    threshold: float = THRESHOLD,
    refinements: tuple[str, ...] = REFINEMENTS,
) -> pd.DataFrame:
    """Collapse the per-image table into one row per cell (:data:`CELL_KEYS`).

    Counts: ``n_images`` (may differ per cell: sampling is adaptive), ``n_detected`` (any
    marker found), ``n_id_ok`` (right id found: what counts as a detection), ``backend_failures``
    (images the detector's worker crashed on, column ``backend_failed`` where present: neither
    detected nor missed, they count in nothing else). ``detection_rate = n_id_ok / n_images``
    (NaN where every image failed) with its Wilson 95 % interval ``rate_lo``/``rate_hi``, and
    ``decided`` (:func:`excludes_threshold`). For every metric column ``<metric>_<refinement>`` (of
    ``refinements``, :func:`refinements_of`) the median, the :data:`PERCENTILE` th percentile
    (linear interpolation) and the max, as ``<column>_<statistic>``, over the images with
    ``id_ok`` (errors of a wrong id are meaningless) whose value is finite; NaN where there is
    none. Extra input columns are ignored and the input is not modified. Rows are sorted by
    :data:`CELL_KEYS`, so the result does not depend on the input row order.
    """
    _check_threshold(threshold)
    metrics = image_metric_columns(refinements)
    require_columns(images, [*CELL_KEYS, "detected", "id_ok", *metrics], "per-image table")
    scales = images["psf_scale"].to_numpy(dtype=float)
    bad = scales[~(np.isfinite(scales) & (scales >= 0))]
    if bad.size:
        raise ValueError(f"psf_scale must be a finite factor >= 0 (0: no blur), got {bad[0]}")

    failed = images.get("backend_failed", pd.Series(False, index=images.index)).astype(bool)
    id_ok = images["id_ok"].astype(bool) & ~failed
    work = pd.DataFrame(
        {
            **{key: images[key] for key in CELL_KEYS},
            "scored": (~failed).astype(np.int64),
            "failed": failed.astype(np.int64),
            "detected": (images["detected"].astype(bool) & ~failed).astype(np.int64),
            "id_ok": id_ok.astype(np.int64),
            **{c: images[c].astype(float).where(id_ok) for c in metrics},
        }
    )
    grouped = work.groupby(CELL_KEYS, sort=True, dropna=False)
    counts = grouped.agg(
        n_images=("scored", "sum"),
        n_detected=("detected", "sum"),
        n_id_ok=("id_ok", "sum"),
        backend_failures=("failed", "sum"),
    ).astype(np.int64)
    errors = grouped[metrics]
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
    with np.errstate(invalid="ignore"):
        out["detection_rate"] = k / n  # NaN where every image of the cell failed
    out["rate_lo"], out["rate_hi"] = wilson_interval(k, n)
    out["decided"] = excludes_threshold(out["rate_lo"], out["rate_hi"], threshold)
    out = out.sort_values(CELL_KEYS, kind="mergesort").reset_index(drop=True)
    return out[summary_columns(refinements)]


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
    require_columns(
        summary,
        [*CELL_KEYS, "n_images", "detection_rate", "rate_lo", "rate_hi"],
        "summary table",
    )
    phi = summary["phi_deg"].astype(float)
    work = pd.DataFrame(
        {
            **{key: summary[key] for key in GROUP_KEYS},
            "pass_point": phi.where(passes(summary["detection_rate"], threshold)),
            "pass_lower": phi.where(passes(summary["rate_lo"], threshold)),
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
    require_columns(
        max_phi_table,
        [*GROUP_KEYS, "max_phi_deg", "max_phi_lower_deg", "resolution_deg", "phi_max_tested_deg"],
        "max-phi table",
        nonempty=True,
    )
    table = max_phi_table
    scales = np.sort(pd.unique(table["psf_scale"].astype(float)))
    nominal = nominal_scale_of(scales, nominal_scale)
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


def nominal_scale_of(scales: np.ndarray, requested: float) -> float:
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


def require_columns(
    table: pd.DataFrame, columns: Sequence[str], what: str, nonempty: bool = False
) -> None:
    missing = [c for c in columns if c not in table.columns]
    if missing:
        raise ValueError(f"{what} lacks columns: {missing}")
    if nonempty and table.empty:
        raise ValueError(f"{what} is empty")
