"""Tests for bench.study.report: Wilson interval, per-cell summary, max-phi, band, CSV and plots."""

from __future__ import annotations

import math
import pathlib
from collections.abc import Callable

import numpy as np
import pandas as pd
import pytest

from bench.study.plots import plot_heatmap, plot_max_phi, plot_pose_error
from bench.study.report import (
    BAND_COLUMNS,
    CELL_KEYS,
    IMAGE_METRIC_COLUMNS,
    MAX_PHI_COLUMNS,
    METRICS,
    PERCENTILE,
    REFINEMENTS,
    STATISTICS,
    SUMMARY_COLUMNS,
    band,
    excludes_threshold,
    max_phi,
    summarize,
    summary_to_csv_bytes,
    wilson_interval,
)

Z = 1.959963984540054
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def wilson_reference(k: int, n: int, z: float = Z) -> tuple[float, float]:
    """Independent scalar Wilson interval: roots of (p_hat - p)^2 = z^2 p (1 - p) / n."""
    # n (p_hat - p)^2 = z^2 p (1 - p)  <=>  (n + z^2) p^2 - (2 k + z^2) p + k^2 / n = 0
    a = n + z * z
    b = -(2.0 * k + z * z)
    c = k * k / n
    disc = math.sqrt(b * b - 4.0 * a * c)
    return (-b - disc) / (2.0 * a), (-b + disc) / (2.0 * a)


# --------------------------------------------------------------------------------------
# wilson_interval
# --------------------------------------------------------------------------------------


def test_wilson_57_of_60_hand_checked() -> None:
    # hand computation: p = .95, center = .92292, half-width = .05993
    lo, hi = wilson_interval(57, 60)
    assert lo == pytest.approx(0.8630, abs=5e-4)
    assert hi == pytest.approx(0.9829, abs=5e-4)


@pytest.mark.parametrize(
    ("k", "n"), [(57, 60), (1, 60), (30, 60), (59, 60), (3, 7), (81, 263), (1, 1), (5, 10)]
)
def test_wilson_matches_quadratic_roots(k: int, n: int) -> None:
    lo, hi = wilson_interval(k, n)
    ref_lo, ref_hi = wilson_reference(k, n)
    assert float(lo) == pytest.approx(ref_lo, abs=1e-12)
    assert float(hi) == pytest.approx(ref_hi, abs=1e-12)


@pytest.mark.parametrize("n", [1, 10, 60, 1000])
def test_wilson_boundaries_closed_form(n: int) -> None:
    z2 = Z * Z
    lo0, hi0 = wilson_interval(0, n)
    assert float(lo0) == 0.0
    assert float(hi0) == pytest.approx(z2 / (n + z2), rel=1e-12)
    lon, hin = wilson_interval(n, n)
    assert float(hin) == 1.0  # exactly, not 0.9999999
    assert float(lon) == pytest.approx(n / (n + z2), rel=1e-12)


def test_wilson_zero_trials_is_uninformative() -> None:
    lo, hi = wilson_interval(np.array([0, 0]), np.array([0, 0]))
    np.testing.assert_array_equal(lo, [0.0, 0.0])
    np.testing.assert_array_equal(hi, [1.0, 1.0])


def test_wilson_vectorised_properties() -> None:
    rng = np.random.default_rng(1234)
    n = rng.integers(1, 200, size=500)
    k = rng.integers(0, n + 1)
    lo, hi = wilson_interval(k, n)
    assert lo.shape == hi.shape == (500,)
    p = k / n
    assert np.all((lo >= 0.0) & (lo <= p) & (p <= hi) & (hi <= 1.0))
    # symmetry: interval for failures is the mirror image
    lo_f, hi_f = wilson_interval(n - k, n)
    np.testing.assert_allclose(lo, 1.0 - hi_f, atol=1e-12)
    np.testing.assert_allclose(hi, 1.0 - lo_f, atol=1e-12)
    # elementwise equal to the scalar reference
    for i in range(0, 500, 50):
        ref = wilson_reference(int(k[i]), int(n[i]))
        assert (lo[i], hi[i]) == pytest.approx(ref, abs=1e-12)


def test_wilson_narrows_with_more_trials() -> None:
    lo1, hi1 = wilson_interval(19, 20)
    lo2, hi2 = wilson_interval(190, 200)
    assert hi2 - lo2 < hi1 - lo1
    assert lo2 > lo1


@pytest.mark.parametrize(("k", "n"), [(5, 4), (-1, 3), (1, -1)])
def test_wilson_rejects_invalid_counts(k: int, n: int) -> None:
    with pytest.raises(ValueError):
        wilson_interval(k, n)


# --------------------------------------------------------------------------------------
# summarize
# --------------------------------------------------------------------------------------

NAN = float("nan")


def _image_row(cell: tuple, detected: bool, id_ok: bool, lines: tuple, subpix: tuple) -> dict:
    """One per-image row; ``lines``/``subpix`` are (corner, rot, trans, ambiguity)."""
    row = dict(zip(CELL_KEYS, cell, strict=True))
    row.update(detected=detected, id_ok=id_ok)
    for refinement, values in (("lines", lines), ("subpix", subpix)):
        row.update({f"{m}_{refinement}": v for m, v in zip(METRICS, values, strict=True)})
    return row


def _hand_table() -> pd.DataFrame:
    """Cell A: 5 images, 3 right ids; B: same cell at PSF scale 0.5; C: no right id."""
    a = ("lab", 1.0, 11.0, 20.0, 0.0)
    b = ("lab", 0.5, 11.0, 20.0, 0.0)
    c = ("dim", 1.0, 11.0, 20.0, 0.0)
    bad = (99.0, 99.0, 99.0, 99.0)
    rows = [
        _image_row(a, True, True, (1.0, 2.0, 0.5, 0.1), (4.0, 1.0, 0.4, 0.3)),
        _image_row(a, True, True, (3.0, 4.0, 1.5, 0.3), (NAN, NAN, NAN, NAN)),  # subpix lost
        _image_row(a, True, False, bad, bad),  # wrong id: ignored
        _image_row(a, False, False, (NAN,) * 4, (NAN,) * 4),
        _image_row(a, True, True, (2.0, 9.0, 0.7, 0.2), (6.0, 3.0, 0.8, 0.5)),
        _image_row(b, True, True, (0.5, 1.0, 0.1, 0.5), (0.7, 1.5, 0.2, 0.6)),
        _image_row(b, True, True, (1.5, 3.0, 0.3, 0.7), (1.7, 2.5, 0.4, 0.8)),
        _image_row(c, False, False, (NAN,) * 4, (NAN,) * 4),
        _image_row(c, True, False, bad, bad),
    ]
    df = pd.DataFrame(rows)
    df["image_index"] = df.groupby(CELL_KEYS).cumcount()
    df["image_path"] = [f"img_{i:03d}.png" for i in range(len(df))]
    return df


def test_summary_columns_layout() -> None:
    assert REFINEMENTS == ("lines", "subpix")
    assert ("median", f"p{PERCENTILE}", "max") == STATISTICS
    metric_stats = [f"{m}_{r}_{s}" for m in METRICS for r in REFINEMENTS for s in STATISTICS]
    assert SUMMARY_COLUMNS[: len(CELL_KEYS)] == CELL_KEYS
    assert SUMMARY_COLUMNS[-len(metric_stats) :] == metric_stats
    assert "psf_scale" in CELL_KEYS and "decided" in SUMMARY_COLUMNS


def test_summarize_counts_rates_and_errors() -> None:
    images = _hand_table()
    before = images.copy(deep=True)
    s = summarize(images)
    pd.testing.assert_frame_equal(images, before)  # input untouched
    assert list(s.columns) == SUMMARY_COLUMNS
    assert list(s["lighting"]) == ["dim", "lab", "lab"]  # sorted by CELL_KEYS
    assert list(s["psf_scale"]) == [1.0, 0.5, 1.0]

    dim, b, a = (s.iloc[i] for i in range(3))
    assert (a["n_images"], a["n_detected"], a["n_id_ok"]) == (5, 4, 3)
    assert a["detection_rate"] == pytest.approx(0.6)
    assert (a["rate_lo"], a["rate_hi"]) == pytest.approx(wilson_reference(3, 5))
    # lines corner errors {1, 3, 2}: sorted rank 0.95 * (3 - 1) = 1.9 -> 2 + 0.9 * (3 - 2)
    assert a["corner_err_px_lines_median"] == 2.0
    assert a["corner_err_px_lines_p95"] == pytest.approx(2.9)
    assert a["corner_err_px_lines_max"] == 3.0
    # rot {2, 4, 9}: 4 + 0.9 * (9 - 4)
    assert a["rot_err_deg_lines_median"] == 4.0
    assert a["rot_err_deg_lines_p95"] == pytest.approx(8.5)
    assert a["trans_err_mm_lines_max"] == 1.5 and a["ambiguity_ratio_lines_median"] == 0.2
    # subpix has a NaN among the right ids: {4, 6} -> median 5, p95 rank 0.95 -> 4 + 0.95 * 2
    assert a["corner_err_px_subpix_median"] == 5.0
    assert a["corner_err_px_subpix_p95"] == pytest.approx(5.9)
    assert a["corner_err_px_subpix_max"] == 6.0
    assert a["ambiguity_ratio_subpix_max"] == 0.5

    assert (b["n_images"], b["n_id_ok"]) == (2, 2)
    assert b["detection_rate"] == 1.0 and b["rate_hi"] == 1.0
    assert b["rot_err_deg_subpix_median"] == 2.0 and b["trans_err_mm_lines_max"] == 0.3

    assert (dim["n_images"], dim["n_detected"], dim["n_id_ok"]) == (2, 1, 0)
    assert dim["detection_rate"] == 0.0 and dim["rate_lo"] == 0.0
    err_cols = [f"{c}_{st}" for c in IMAGE_METRIC_COLUMNS for st in STATISTICS]
    assert dim[err_cols].isna().all()
    for col in ("n_images", "n_detected", "n_id_ok"):
        assert pd.api.types.is_integer_dtype(s[col])
    assert pd.api.types.is_bool_dtype(s["decided"])


def test_summarize_p95_matches_numpy_on_random_cells() -> None:
    rng = np.random.default_rng(5)
    n = 137
    images = pd.DataFrame(
        {
            "lighting": "lab",
            "psf_scale": 1.0,
            "size_mm": 11.0,
            "alpha_deg": 0.0,
            "phi_deg": rng.choice([0.0, 10.0], n),
            "detected": True,
            "id_ok": rng.random(n) < 0.8,
            **{c: rng.lognormal(0.0, 1.0, n) for c in IMAGE_METRIC_COLUMNS},
        }
    )
    s = summarize(images)
    for row in s.itertuples():
        ok = images[(images["phi_deg"] == row.phi_deg) & images["id_ok"]]
        for col in IMAGE_METRIC_COLUMNS:
            values = ok[col].to_numpy()
            assert getattr(row, f"{col}_p{PERCENTILE}") == pytest.approx(
                np.percentile(values, PERCENTILE)
            )
            assert getattr(row, f"{col}_median") == pytest.approx(np.median(values))


@pytest.mark.parametrize(
    ("k", "n"), [(80, 80), (73, 73), (72, 72), (60, 60), (57, 60), (0, 10), (3, 10), (150, 160)]
)
def test_summarize_decided_means_wilson_excludes_095(k: int, n: int) -> None:
    images = pd.DataFrame(
        {
            "lighting": "lab",
            "psf_scale": 1.0,
            "size_mm": 11.0,
            "alpha_deg": 0.0,
            "phi_deg": 0.0,
            "detected": True,
            "id_ok": np.arange(n) < k,
            **{c: 1.0 for c in IMAGE_METRIC_COLUMNS},
        }
    )
    lo, hi = wilson_reference(k, n)
    assert bool(summarize(images)["decided"].iloc[0]) == (lo > 0.95 or hi < 0.95)


def test_decided_known_cases() -> None:
    # n/n has lower bound n / (n + z^2): above 0.95 from n = 73 on; 0/10 has upper bound
    # z^2 / (10 + z^2) = 0.28
    lo, hi = wilson_interval([73, 72, 0, 57], [73, 72, 10, 60])
    np.testing.assert_array_equal(excludes_threshold(lo, hi), [True, False, True, False])
    assert not excludes_threshold(0.95, 1.0)  # touching the threshold is not excluding it
    assert excludes_threshold(0.5, 0.89, threshold=0.9)


@pytest.mark.parametrize("column", ["psf_scale", "id_ok", "rot_err_deg_subpix"])
def test_summarize_missing_column_raises(column: str) -> None:
    with pytest.raises(ValueError, match=f"lacks columns.*{column}"):
        summarize(_hand_table().drop(columns=[column]))


@pytest.mark.parametrize("scale", [-0.5, NAN, float("inf")])
def test_summarize_rejects_bad_psf_scale(scale: float) -> None:
    images = _hand_table()
    images.loc[0, "psf_scale"] = scale
    with pytest.raises(ValueError, match="psf_scale"):
        summarize(images)


# --------------------------------------------------------------------------------------
# synthetic study tables
# --------------------------------------------------------------------------------------

DEFAULT_GRID = {
    "lightings": ["dim", "sun"],
    "scales": [1.0],
    "sizes": [8.8, 11.0, 13.2, 17.6],
    "alphas": [0.0, 20.0, 40.0, 60.0, 70.0, 80.0, 85.0, 90.0],
    "phis": [float(p) for p in range(0, 80, 10)],
}
BAND_GRID = {**DEFAULT_GRID, "lightings": ["sun"], "scales": [0.5, 0.75, 1.0, 1.25, 1.5]}
SMALL_GRID = {
    **DEFAULT_GRID,
    "sizes": [8.8, 17.6],
    "alphas": [0.0, 40.0, 70.0, 90.0],
}
TINY_GRID = {
    "lightings": ["lab"],
    "scales": [1.0],
    "sizes": [11.0],
    "alphas": [0.0, 60.0],
    "phis": [0.0, 30.0],
}


def synthetic_images(grid: dict, seed: int, steps: tuple[int, ...] = (10, 30, 80)) -> pd.DataFrame:
    """Per-image table whose detection probability falls with alpha, phi, PSF scale, small size.

    Images per cell are drawn from ``steps`` (as adaptive sampling leaves them), and the groups
    at alpha 40 get two extra tilts, 45 and 47.5, as the study's refinement adds them.
    """
    rng = np.random.default_rng(seed)
    cells = pd.MultiIndex.from_product(
        [grid["lightings"], grid["scales"], grid["sizes"], grid["alphas"], grid["phis"]],
        names=CELL_KEYS,
    ).to_frame(index=False)
    extra = cells[(cells["alpha_deg"] == 40.0) & (cells["phi_deg"] == 0.0)]
    cells = pd.concat(
        [cells, extra.assign(phi_deg=45.0), extra.assign(phi_deg=47.5)], ignore_index=True
    )
    n = rng.choice(steps, len(cells))
    df = cells.loc[cells.index.repeat(n)].reset_index(drop=True)
    df["image_index"] = df.groupby(CELL_KEYS).cumcount()
    light_penalty = df["lighting"].map({name: 0.4 * i for i, name in enumerate(grid["lightings"])})
    score = (
        8.0
        - 0.0012 * df["alpha_deg"] ** 2
        - 0.09 * df["phi_deg"]
        + 0.25 * df["size_mm"]
        - 2.0 * df["psf_scale"]
        - light_penalty
    )
    p = 1.0 / (1.0 + np.exp(-score))
    df["detected"] = rng.random(len(df)) < np.minimum(1.0, p + 0.05)
    df["id_ok"] = df["detected"] & (rng.random(len(df)) < p / np.minimum(1.0, p + 0.05))
    ok = df["id_ok"].to_numpy()
    spread = 1.0 + df["alpha_deg"].to_numpy() / 30.0
    for metric, base in zip(METRICS, (0.3, 0.5, 0.2, 0.5), strict=True):
        for refinement, factor in (("lines", 1.0), ("subpix", 3.0)):
            vals = base * factor * spread * rng.lognormal(0.0, 0.5, len(df))
            df[f"{metric}_{refinement}"] = np.where(ok, vals, np.nan)
    df["image_path"] = "x.png"
    return df


@pytest.fixture(scope="module")
def default_images() -> pd.DataFrame:
    return synthetic_images(DEFAULT_GRID, seed=7)


@pytest.fixture(scope="module")
def default_summary(default_images: pd.DataFrame) -> pd.DataFrame:
    return summarize(default_images)


@pytest.fixture(scope="module")
def band_summary() -> pd.DataFrame:
    return summarize(synthetic_images(BAND_GRID, seed=13))


# --------------------------------------------------------------------------------------
# CSV determinism
# --------------------------------------------------------------------------------------


def test_csv_bytes_identical_for_same_and_shuffled_input(default_images: pd.DataFrame) -> None:
    first = summary_to_csv_bytes(summarize(default_images))
    again = summary_to_csv_bytes(summarize(default_images.copy()))
    shuffled = default_images.sample(frac=1.0, random_state=np.random.default_rng(3))
    shuffled = shuffled[list(reversed(shuffled.columns))]
    from_shuffled = summary_to_csv_bytes(summarize(shuffled))
    assert first == again == from_shuffled
    text = first.decode("utf-8")
    assert "\r" not in text
    assert text.splitlines()[0] == ",".join(SUMMARY_COLUMNS)
    n_groups = np.prod([len(DEFAULT_GRID[k]) for k in ("lightings", "scales", "sizes", "alphas")])
    n_cells = n_groups * len(DEFAULT_GRID["phis"])
    n_extra = 2 * n_groups // len(DEFAULT_GRID["alphas"])  # 45 and 47.5 at alpha 40
    assert len(text.splitlines()) == n_cells + n_extra + 1


def test_csv_bytes_independent_of_summary_row_order(default_summary: pd.DataFrame) -> None:
    reordered = default_summary.iloc[::-1].reset_index(drop=True)
    assert summary_to_csv_bytes(reordered) == summary_to_csv_bytes(default_summary)


# --------------------------------------------------------------------------------------
# max_phi
# --------------------------------------------------------------------------------------


def _summary_from_counts(counts: dict[tuple, tuple[int, int]]) -> pd.DataFrame:
    """Summary-like table for lighting lab, size 11: {(scale, alpha, phi): (n_id_ok, n)}."""
    keys = list(counts)
    k = np.array([counts[c][0] for c in keys], dtype=float)
    n = np.array([counts[c][1] for c in keys], dtype=int)
    lo, hi = wilson_interval(k, n)
    return pd.DataFrame(
        {
            "lighting": "lab",
            "psf_scale": [c[0] for c in keys],
            "size_mm": 11.0,
            "alpha_deg": [c[1] for c in keys],
            "phi_deg": [c[2] for c in keys],
            "n_images": n,
            "n_id_ok": k.astype(int),
            "detection_rate": k / n,
            "rate_lo": lo,
            "rate_hi": hi,
        }
    )


MAX_PHI_COUNTS = {
    # alpha 0: grid tilts pass to 40 (95/100 exactly); refined 45 passes (57/60), 47.5 fails
    # (56/60), 50 fails -> max 45, first fail 47.5, bracket 2.5. The Wilson lower bound passes
    # only where all of >= 73 images are detected: 0 (100/100), 20 (80/80)
    (1.0, 0.0, 0.0): (100, 100),
    (1.0, 0.0, 10.0): (79, 80),
    (1.0, 0.0, 20.0): (80, 80),
    (1.0, 0.0, 40.0): (95, 100),
    (1.0, 0.0, 45.0): (57, 60),
    (1.0, 0.0, 47.5): (56, 60),
    (1.0, 0.0, 50.0): (94, 100),
    # alpha 40: isolated pass at 50 (the largest tested) after a failure at 20 -> max 50,
    # censored: no first fail, no bracket; 100/100 passes the Wilson lower bound too
    (1.0, 40.0, 0.0): (60, 60),
    (1.0, 40.0, 20.0): (40, 60),
    (1.0, 40.0, 50.0): (100, 100),
    # alpha 90: nothing passes -> max NaN, first fail is the smallest tested phi (0)
    (1.0, 90.0, 0.0): (50, 60),
    (1.0, 90.0, 20.0): (0, 10),
    # the same alpha at another PSF scale is its own group: passes 0, fails 10
    (1.5, 0.0, 0.0): (10, 10),
    (1.5, 0.0, 10.0): (0, 10),
}


def test_max_phi_hand_made() -> None:
    out = max_phi(_summary_from_counts(MAX_PHI_COUNTS))
    assert list(out.columns) == MAX_PHI_COLUMNS
    assert list(zip(out["psf_scale"], out["alpha_deg"], strict=True)) == [
        (1.0, 0.0),
        (1.0, 40.0),
        (1.0, 90.0),
        (1.5, 0.0),
    ]
    np.testing.assert_array_equal(out["max_phi_deg"], [45.0, 50.0, NAN, 0.0])
    np.testing.assert_array_equal(out["first_fail_phi_deg"], [47.5, NAN, 0.0, 10.0])
    np.testing.assert_array_equal(out["resolution_deg"], [2.5, NAN, NAN, 10.0])
    np.testing.assert_array_equal(out["max_phi_lower_deg"], [20.0, 50.0, NAN, NAN])
    np.testing.assert_array_equal(out["phi_max_tested_deg"], [50.0, 50.0, 20.0, 10.0])
    assert out["n_images_min"].tolist() == [60, 60, 10, 10]
    assert out["n_images_max"].tolist() == [100, 100, 60, 10]
    # independent count of cells whose Wilson interval holds 0.95
    undecided: dict[tuple[float, float], int] = {}
    for (scale, alpha, _), (k, n) in MAX_PHI_COUNTS.items():
        lo, hi = wilson_reference(k, n)
        undecided[scale, alpha] = undecided.get((scale, alpha), 0) + int(lo <= 0.95 <= hi)
    assert out["undecided_cells"].tolist() == list(undecided.values())
    assert pd.api.types.is_integer_dtype(out["undecided_cells"])


def test_max_phi_exact_threshold_counts_as_pass() -> None:
    # 57/60 == 0.95 must pass despite floating point
    out = max_phi(_summary_from_counts({(1.0, 0.0, 0.0): (57, 60), (1.0, 0.0, 10.0): (56, 60)}))
    assert out["max_phi_deg"].iloc[0] == 0.0
    assert out["first_fail_phi_deg"].iloc[0] == 10.0


@pytest.mark.parametrize("threshold", [0.5, 0.8, 0.9])
def test_max_phi_matches_brute_force(default_summary: pd.DataFrame, threshold: float) -> None:
    out = max_phi(default_summary, threshold=threshold)
    keys = ["lighting", "psf_scale", "size_mm", "alpha_deg"]
    assert len(out) == np.prod([len(DEFAULT_GRID[k]) for k in ("lightings", "sizes", "alphas")])
    both = out.dropna(subset=["max_phi_deg", "max_phi_lower_deg"])
    assert len(both) > 0
    assert (both["max_phi_lower_deg"] <= both["max_phi_deg"]).all()
    assert not (out["max_phi_deg"].isna() & out["max_phi_lower_deg"].notna()).any()
    for row in out.itertuples():
        cells = default_summary[
            (default_summary[keys] == [getattr(row, k) for k in keys]).all(axis=1)
        ]
        passing = cells.loc[cells["detection_rate"] >= threshold, "phi_deg"]
        expected = passing.max() if len(passing) else NAN
        above = cells.loc[cells["phi_deg"] > (expected if len(passing) else -1.0), "phi_deg"]
        assert (cells.loc[cells["phi_deg"].isin(above), "detection_rate"] < threshold).all()
        np.testing.assert_equal(row.max_phi_deg, expected)
        np.testing.assert_equal(row.first_fail_phi_deg, above.min() if len(above) else NAN)
        assert row.n_images_min == cells["n_images"].min()
        assert row.n_images_max == cells["n_images"].max()


def test_max_phi_has_nan_and_brackets_in_default(default_summary: pd.DataFrame) -> None:
    out = max_phi(default_summary)
    assert out["max_phi_deg"].isna().any()  # plot path for "never detected" gets exercised
    assert out["max_phi_deg"].notna().any()
    refined = out[out["alpha_deg"] == 40.0]
    assert set(refined["resolution_deg"].dropna()) <= {2.5, 5.0, 10.0}


@pytest.mark.parametrize("threshold", [-0.1, 1.5])
def test_max_phi_rejects_bad_threshold(default_summary: pd.DataFrame, threshold: float) -> None:
    with pytest.raises(ValueError, match="threshold"):
        max_phi(default_summary, threshold=threshold)


def test_max_phi_without_psf_scale_raises(default_summary: pd.DataFrame) -> None:
    with pytest.raises(ValueError, match="lacks columns.*psf_scale"):
        max_phi(default_summary.drop(columns=["psf_scale"]))


# --------------------------------------------------------------------------------------
# band
# --------------------------------------------------------------------------------------


def _max_phi_table(values: dict[tuple[float, float], list[float]], scales: list[float]):
    """Per-scale max-phi table for lighting sun: {(size, alpha): max_phi per scale}."""
    rows = [
        {
            "lighting": "sun",
            "psf_scale": scale,
            "size_mm": size,
            "alpha_deg": alpha,
            "max_phi_deg": phi,
            "max_phi_lower_deg": phi - 10.0,
            "resolution_deg": 2.5 * (i + 1),
            "phi_max_tested_deg": 70.0,
        }
        for (size, alpha), phis in values.items()
        for i, (scale, phi) in enumerate(zip(scales, phis, strict=True))
    ]
    return pd.DataFrame(rows)


BAND_VALUES = {
    (8.8, 0.0): [40.0, 30.0, 20.0],
    (8.8, 60.0): [NAN, NAN, NAN],  # fails at every scale
    (11.0, 0.0): [70.0, 60.0, 50.0],
    (11.0, 60.0): [50.0, 40.0, NAN],  # fails at the widest PSF only
}


def test_band_hand_made() -> None:
    table = _max_phi_table(BAND_VALUES, [0.5, 1.0, 1.5])
    out = band(table.iloc[::-1])  # row order does not matter
    assert list(out.columns) == BAND_COLUMNS
    assert list(zip(out["size_mm"], out["alpha_deg"], strict=True)) == list(BAND_VALUES)
    np.testing.assert_array_equal(out["max_phi_deg"], [30.0, NAN, 60.0, 40.0])
    np.testing.assert_array_equal(out["band_lo_deg"], [20.0, NAN, 50.0, NAN])
    np.testing.assert_array_equal(out["band_hi_deg"], [40.0, NAN, 70.0, 50.0])
    assert out["robust"].tolist() == [True, False, True, False]
    np.testing.assert_array_equal(out["max_phi_lower_deg"], [20.0, NAN, 50.0, 30.0])
    assert (out["resolution_deg"] == 5.0).all()  # the nominal scale's
    assert (out["psf_scale_nominal"] == 1.0).all()
    assert (out["psf_scale_min"] == 0.5).all() and (out["psf_scale_max"] == 1.5).all()
    # another nominal scale moves the line, not the band
    wide = band(table, nominal_scale=1.5)
    np.testing.assert_array_equal(wide["max_phi_deg"], [20.0, NAN, 50.0, NAN])
    pd.testing.assert_series_equal(wide["band_lo_deg"], out["band_lo_deg"])


def test_band_single_scale_is_its_own_nominal() -> None:
    table = _max_phi_table({k: v[:1] for k, v in BAND_VALUES.items()}, [0.5])
    out = band(table)
    assert (out["psf_scale_nominal"] == 0.5).all()
    np.testing.assert_array_equal(out["band_lo_deg"], out["max_phi_deg"])
    np.testing.assert_array_equal(out["band_hi_deg"], out["max_phi_deg"])
    assert out["robust"].tolist() == out["max_phi_deg"].notna().tolist()


def test_band_rejects_missing_nominal_and_missing_scale() -> None:
    table = _max_phi_table(BAND_VALUES, [0.5, 1.0, 1.5])
    with pytest.raises(ValueError, match="psf_scale.*1.25"):
        band(table, nominal_scale=1.25)
    with pytest.raises(ValueError, match="psf_scale"):
        band(table.drop(index=[0]))  # one group lacks scale 0.5


def test_band_from_study_tables(band_summary: pd.DataFrame) -> None:
    per_scale = max_phi(band_summary)
    out = band(per_scale)
    assert len(out) == len(per_scale) // len(BAND_GRID["scales"])
    keys = ["lighting", "size_mm", "alpha_deg"]
    grouped = per_scale.groupby(keys)["max_phi_deg"]
    np.testing.assert_array_equal(out["robust"], grouped.apply(lambda s: s.notna().all()))
    np.testing.assert_array_equal(out["band_hi_deg"], grouped.max())
    ok = out["robust"]
    np.testing.assert_array_equal(out.loc[ok, "band_lo_deg"], grouped.min()[ok.to_numpy()])
    assert out["band_lo_deg"].isna().tolist() == (~ok).tolist()
    both = out.dropna(subset=["max_phi_deg", "band_lo_deg"])
    assert (
        (both["band_lo_deg"] <= both["max_phi_deg"]) & (both["max_phi_deg"] <= both["band_hi_deg"])
    ).all()
    # the synthetic detector gets worse with the PSF: a real band, and some non-robust sizes
    assert (out["band_hi_deg"] > out["band_lo_deg"]).any()
    assert (~ok & out["band_hi_deg"].notna()).any()


# --------------------------------------------------------------------------------------
# plots
# --------------------------------------------------------------------------------------


@pytest.fixture(scope="module", params=["two_lightings", "five_scales", "tiny"])
def grid_summary(request: pytest.FixtureRequest, band_summary: pd.DataFrame) -> pd.DataFrame:
    if request.param == "two_lightings":
        return summarize(synthetic_images(SMALL_GRID, seed=17))
    if request.param == "five_scales":
        return band_summary
    return summarize(synthetic_images(TINY_GRID, seed=11, steps=(10,)))


def _assert_png(path: pathlib.Path) -> None:
    assert path.is_file()
    data = path.read_bytes()
    assert len(data) > 1000
    assert data[:8] == PNG_MAGIC


@pytest.mark.slow
def test_plot_max_phi_writes_png(grid_summary: pd.DataFrame, tmp_path: pathlib.Path) -> None:
    path = tmp_path / "sub" / "max_phi.png"
    plot_max_phi(max_phi(grid_summary), path)
    _assert_png(path)


def test_plot_max_phi_all_nan(tmp_path: pathlib.Path) -> None:
    table = max_phi(_summary_from_counts({(1.0, 0.0, 0.0): (1, 60), (1.0, 30.0, 0.0): (0, 60)}))
    assert table["max_phi_deg"].isna().all()
    path = tmp_path / "max_phi_nan.png"
    plot_max_phi(table, path)
    _assert_png(path)


@pytest.mark.slow
def test_plot_heatmap_writes_png(grid_summary: pd.DataFrame, tmp_path: pathlib.Path) -> None:
    path = tmp_path / "heatmap.png"
    plot_heatmap(grid_summary, path)
    _assert_png(path)


@pytest.mark.slow
def test_plot_pose_error_writes_png(grid_summary: pd.DataFrame, tmp_path: pathlib.Path) -> None:
    path = tmp_path / "pose.png"
    plot_pose_error(grid_summary, path)
    _assert_png(path)


@pytest.mark.slow
def test_plot_pose_error_at_one_phi_wide_range(
    band_summary: pd.DataFrame, tmp_path: pathlib.Path
) -> None:
    summary = band_summary.copy()
    summary["rot_err_deg_lines_median"] *= np.exp(summary["alpha_deg"] / 10.0)  # log axis
    path = tmp_path / "pose_phi0.png"
    plot_pose_error(summary, path, phi_deg=0.0)
    _assert_png(path)
    with pytest.raises(ValueError, match="phi_deg"):
        plot_pose_error(summary, path, phi_deg=5.0)


@pytest.mark.parametrize("plot", [plot_heatmap, plot_pose_error])
def test_plots_reject_empty_table(plot: Callable, tmp_path: pathlib.Path) -> None:
    empty = pd.DataFrame(columns=SUMMARY_COLUMNS)
    with pytest.raises(ValueError, match="empty"):
        plot(empty, tmp_path / "e.png")
    assert not (tmp_path / "e.png").exists()


def test_plots_reject_unknown_nominal_scale(
    band_summary: pd.DataFrame, tmp_path: pathlib.Path
) -> None:
    with pytest.raises(ValueError, match="psf_scale"):
        plot_heatmap(band_summary, tmp_path / "h.png", nominal_scale=2.0)


@pytest.mark.slow
def test_plot_pose_error_without_any_detection(tmp_path: pathlib.Path) -> None:
    images = synthetic_images(TINY_GRID, seed=2, steps=(5,))
    images["id_ok"] = False
    summary = summarize(images)
    assert summary["rot_err_deg_lines_median"].isna().all()
    path = tmp_path / "pose_none.png"
    plot_pose_error(summary, path)
    _assert_png(path)
