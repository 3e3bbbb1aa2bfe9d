"""Tests for bench.report: Wilson interval, per-cell summary, max-phi, CSV and plots."""

from __future__ import annotations

import math
import pathlib

import numpy as np
import pandas as pd
import pytest

from bench.report import (
    CELL_KEYS,
    MAX_PHI_COLUMNS,
    SUMMARY_COLUMNS,
    max_phi,
    plot_heatmap,
    plot_max_phi,
    plot_pose_error,
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


def _hand_table() -> pd.DataFrame:
    """Two lightings, 5 images in cell A, 3 in cell B, 2 in cell C (no right id)."""
    nan = float("nan")
    rows = [
        # lighting, size, alpha, phi, idx, detected, id_ok, corner, rot, trans, amb
        ("lab", 11.0, 20.0, 0.0, 0, True, True, 1.0, 2.0, 0.5, 0.1),
        ("lab", 11.0, 20.0, 0.0, 1, True, True, 3.0, 4.0, 1.5, 0.3),
        ("lab", 11.0, 20.0, 0.0, 2, True, False, 99.0, 99.0, 99.0, 99.0),  # wrong id: ignored
        ("lab", 11.0, 20.0, 0.0, 3, False, False, nan, nan, nan, nan),
        ("lab", 11.0, 20.0, 0.0, 4, True, True, 2.0, 9.0, 0.7, 0.2),
        ("lab", 11.0, 20.0, 10.0, 0, True, True, 0.5, 1.0, 0.1, 0.5),
        ("lab", 11.0, 20.0, 10.0, 1, True, True, 1.5, 3.0, 0.3, 0.7),
        ("lab", 11.0, 20.0, 10.0, 2, True, True, 1.0, 2.0, 0.2, 0.6),
        ("dim", 11.0, 20.0, 0.0, 0, False, False, nan, nan, nan, nan),
        ("dim", 11.0, 20.0, 0.0, 1, True, False, nan, nan, nan, nan),
    ]
    cols = [
        *CELL_KEYS,
        "image_index",
        "detected",
        "id_ok",
        "corner_err_px",
        "rot_err_deg",
        "trans_err_mm",
        "ambiguity_ratio",
    ]
    df = pd.DataFrame(rows, columns=cols)
    df["image_path"] = [f"img_{i:03d}.png" for i in range(len(df))]
    df["gt_corners"] = [np.zeros(8).tolist()] * len(df)
    return df


def test_summarize_counts_rates_and_errors() -> None:
    images = _hand_table()
    before = images.copy(deep=True)
    s = summarize(images)
    pd.testing.assert_frame_equal(images, before)  # input untouched
    assert list(s.columns) == SUMMARY_COLUMNS
    assert list(s["lighting"]) == ["dim", "lab", "lab"]  # sorted by CELL_KEYS
    assert list(s["phi_deg"]) == [0.0, 0.0, 10.0]

    dim, a, b = (s.iloc[i] for i in range(3))
    assert (a["n_images"], a["n_detected"], a["n_id_ok"]) == (5, 4, 3)
    assert a["detection_rate"] == pytest.approx(0.6)
    assert (a["rate_lo"], a["rate_hi"]) == pytest.approx(wilson_reference(3, 5))
    assert a["corner_err_px_median"] == 2.0 and a["corner_err_px_max"] == 3.0
    assert a["rot_err_deg_median"] == 4.0 and a["rot_err_deg_max"] == 9.0
    assert a["trans_err_mm_median"] == 0.7 and a["trans_err_mm_max"] == 1.5
    assert a["ambiguity_ratio_median"] == 0.2

    assert (b["n_images"], b["n_detected"], b["n_id_ok"]) == (3, 3, 3)
    assert b["detection_rate"] == 1.0 and b["rate_hi"] == 1.0
    assert b["rot_err_deg_median"] == 2.0 and b["trans_err_mm_max"] == 0.3

    assert (dim["n_images"], dim["n_detected"], dim["n_id_ok"]) == (2, 1, 0)
    assert dim["detection_rate"] == 0.0 and dim["rate_lo"] == 0.0
    err_cols = [c for c in SUMMARY_COLUMNS if c.endswith(("_median", "_max"))]
    assert dim[err_cols].isna().all()
    for col in ("n_images", "n_detected", "n_id_ok"):
        assert pd.api.types.is_integer_dtype(s[col])


def test_summarize_missing_column_raises() -> None:
    with pytest.raises(ValueError, match="id_ok"):
        summarize(_hand_table().drop(columns=["id_ok"]))


# --------------------------------------------------------------------------------------
# synthetic study tables
# --------------------------------------------------------------------------------------

DEFAULT_GRID = {
    "lightings": ["bright", "dim", "lab", "sun"],
    "sizes": [8.8, 11.0, 13.2, 17.6],
    "alphas": [0.0, 20.0, 40.0, 60.0, 70.0, 80.0, 85.0, 90.0],
    "phis": [float(p) for p in range(0, 80, 10)],
}
TINY_GRID = {"lightings": ["lab"], "sizes": [11.0], "alphas": [0.0, 60.0], "phis": [0.0, 30.0]}


def synthetic_images(grid: dict, n_images: int, seed: int) -> pd.DataFrame:
    """Per-image table with a detection probability falling with alpha, phi, small size."""
    rng = np.random.default_rng(seed)
    idx = pd.MultiIndex.from_product(
        [grid["lightings"], grid["sizes"], grid["alphas"], grid["phis"], range(n_images)],
        names=[*CELL_KEYS, "image_index"],
    )
    df = idx.to_frame(index=False)
    light_penalty = df["lighting"].map({name: 0.4 * i for i, name in enumerate(grid["lightings"])})
    score = (
        7.0
        - 0.0012 * df["alpha_deg"] ** 2
        - 0.09 * df["phi_deg"]
        + 0.25 * df["size_mm"]
        - light_penalty
    )
    p = 1.0 / (1.0 + np.exp(-score))
    df["detected"] = rng.random(len(df)) < np.minimum(1.0, p + 0.05)
    df["id_ok"] = df["detected"] & (rng.random(len(df)) < p / np.minimum(1.0, p + 0.05))
    ok = df["id_ok"].to_numpy()
    scale = 1.0 + df["alpha_deg"].to_numpy() / 30.0
    for col, base in [("corner_err_px", 0.3), ("rot_err_deg", 0.5), ("trans_err_mm", 0.2)]:
        vals = base * scale * rng.lognormal(0.0, 0.5, len(df))
        df[col] = np.where(ok, vals, np.nan)
    df["ambiguity_ratio"] = np.where(ok, rng.uniform(0.0, 1.0, len(df)), np.nan)
    df["image_path"] = "x.png"
    return df


@pytest.fixture(scope="module")
def default_images() -> pd.DataFrame:
    return synthetic_images(DEFAULT_GRID, n_images=60, seed=7)


@pytest.fixture(scope="module")
def default_summary(default_images: pd.DataFrame) -> pd.DataFrame:
    return summarize(default_images)


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
    n_cells = np.prod([len(v) for v in DEFAULT_GRID.values()])
    assert len(text.splitlines()) == n_cells + 1


def test_csv_bytes_independent_of_summary_row_order(default_summary: pd.DataFrame) -> None:
    reordered = default_summary.iloc[::-1].reset_index(drop=True)
    assert summary_to_csv_bytes(reordered) == summary_to_csv_bytes(default_summary)


# --------------------------------------------------------------------------------------
# max_phi
# --------------------------------------------------------------------------------------


def _summary_from_counts(counts: dict[tuple[float, float], tuple[int, int]]) -> pd.DataFrame:
    """Summary-like table for one lighting/size: {(alpha, phi): (n_id_ok, n_images)}."""
    keys = list(counts)
    k = np.array([counts[c][0] for c in keys], dtype=float)
    n = np.array([counts[c][1] for c in keys], dtype=int)
    lo, hi = wilson_interval(k, n)
    return pd.DataFrame(
        {
            "lighting": "lab",
            "size_mm": 11.0,
            "alpha_deg": [c[0] for c in keys],
            "phi_deg": [c[1] for c in keys],
            "n_images": n,
            "n_id_ok": k.astype(int),
            "detection_rate": k / n,
            "rate_lo": lo,
            "rate_hi": hi,
        }
    )


def test_max_phi_hand_made() -> None:
    counts = {
        # alpha 0: passes up to 40 (95/100 exactly), 50 fails -> 40; the Wilson lower bound
        # of 98/100 is 0.93, only 100/100 (lower bound 0.963) passes -> 0
        (0.0, 0.0): (100, 100),
        (0.0, 20.0): (98, 100),
        (0.0, 40.0): (95, 100),
        (0.0, 50.0): (94, 100),
        # alpha 40: isolated pass at 50 after a failure at 20 -> largest passing = 50
        (40.0, 0.0): (60, 60),
        (40.0, 20.0): (40, 60),
        (40.0, 50.0): (100, 100),
        # alpha 90: nothing passes
        (90.0, 0.0): (50, 60),
        (90.0, 20.0): (0, 55),
    }
    out = max_phi(_summary_from_counts(counts))
    assert list(out.columns) == MAX_PHI_COLUMNS
    assert list(out["alpha_deg"]) == [0.0, 40.0, 90.0]
    assert out["max_phi_deg"].tolist()[:2] == [40.0, 50.0]
    assert np.isnan(out["max_phi_deg"].iloc[2])
    assert out["max_phi_lower_deg"].tolist()[:2] == [0.0, 50.0]
    assert np.isnan(out["max_phi_lower_deg"].iloc[2])
    assert out["n_images_per_cell"].tolist() == [100, 60, 55]
    assert out["phi_max_tested_deg"].tolist() == [50.0, 50.0, 20.0]


def test_max_phi_exact_threshold_counts_as_pass() -> None:
    # 57/60 == 0.95 must pass despite floating point
    out = max_phi(_summary_from_counts({(0.0, 0.0): (57, 60), (0.0, 10.0): (56, 60)}))
    assert out["max_phi_deg"].iloc[0] == 0.0


@pytest.mark.parametrize("threshold", [0.5, 0.8, 0.9])
def test_max_phi_lower_never_exceeds_point(default_summary: pd.DataFrame, threshold: float) -> None:
    out = max_phi(default_summary, threshold=threshold)
    assert len(out) == np.prod([len(DEFAULT_GRID[k]) for k in ("lightings", "sizes", "alphas")])
    both = out.dropna(subset=["max_phi_deg", "max_phi_lower_deg"])
    assert len(both) > 0
    assert (both["max_phi_lower_deg"] <= both["max_phi_deg"]).all()
    # lower defined implies point defined
    assert not (out["max_phi_deg"].isna() & out["max_phi_lower_deg"].notna()).any()
    # brute-force check of the point estimate against the summary
    merged = default_summary.merge(out, on=["lighting", "size_mm", "alpha_deg"])
    passing = merged[merged["detection_rate"] >= threshold]
    expected = passing.groupby(["lighting", "size_mm", "alpha_deg"])["phi_deg"].max()
    got = out.set_index(["lighting", "size_mm", "alpha_deg"])["max_phi_deg"]
    pd.testing.assert_series_equal(
        got.dropna(), expected.reindex(got.dropna().index), check_names=False
    )
    assert got.isna().sum() == len(got) - len(expected)


def test_max_phi_has_nan_somewhere_in_default(default_summary: pd.DataFrame) -> None:
    out = max_phi(default_summary)
    assert out["max_phi_deg"].isna().any()  # plot path for "never detected" gets exercised
    assert out["max_phi_deg"].notna().any()


@pytest.mark.parametrize("n", [60, 72, 73, 100])
def test_max_phi_lower_needs_73_images_at_95_percent(n: int) -> None:
    # even n/n successes have a Wilson lower bound n / (n + z^2) < 0.95 for n <= 72
    out = max_phi(_summary_from_counts({(0.0, 0.0): (n, n)}))
    assert out["max_phi_deg"].iloc[0] == 0.0
    assert np.isnan(out["max_phi_lower_deg"].iloc[0]) == (n <= 72)


@pytest.mark.parametrize("threshold", [-0.1, 1.5])
def test_max_phi_rejects_bad_threshold(default_summary: pd.DataFrame, threshold: float) -> None:
    with pytest.raises(ValueError):
        max_phi(default_summary, threshold=threshold)


# --------------------------------------------------------------------------------------
# plots
# --------------------------------------------------------------------------------------


@pytest.fixture(scope="module", params=["default", "tiny"])
def grid_summary(request: pytest.FixtureRequest, default_summary: pd.DataFrame) -> pd.DataFrame:
    if request.param == "default":
        return default_summary
    return summarize(synthetic_images(TINY_GRID, n_images=10, seed=11))


def _assert_png(path: pathlib.Path) -> None:
    assert path.is_file()
    data = path.read_bytes()
    assert len(data) > 1000
    assert data[:8] == PNG_MAGIC


def test_plot_max_phi_writes_png(grid_summary: pd.DataFrame, tmp_path: pathlib.Path) -> None:
    path = tmp_path / "sub" / "max_phi.png"
    plot_max_phi(max_phi(grid_summary), path)
    _assert_png(path)


def test_plot_max_phi_all_nan(tmp_path: pathlib.Path) -> None:
    table = max_phi(_summary_from_counts({(0.0, 0.0): (1, 60), (30.0, 0.0): (0, 60)}))
    assert table["max_phi_deg"].isna().all()
    path = tmp_path / "max_phi_nan.png"
    plot_max_phi(table, path)
    _assert_png(path)


def test_plot_heatmap_writes_png(grid_summary: pd.DataFrame, tmp_path: pathlib.Path) -> None:
    path = tmp_path / "heatmap.png"
    plot_heatmap(grid_summary, path)
    _assert_png(path)


@pytest.mark.parametrize("phi_deg", [None, 0.0])
def test_plot_pose_error_writes_png(
    grid_summary: pd.DataFrame, tmp_path: pathlib.Path, phi_deg: float | None
) -> None:
    path = tmp_path / "pose.png"
    plot_pose_error(grid_summary, path, phi_deg=phi_deg)
    _assert_png(path)


def test_plots_reject_empty_table(tmp_path: pathlib.Path) -> None:
    empty = pd.DataFrame(columns=SUMMARY_COLUMNS)
    with pytest.raises(ValueError):
        plot_heatmap(empty, tmp_path / "e.png")
    assert not (tmp_path / "e.png").exists()


def test_plot_pose_error_without_any_detection(tmp_path: pathlib.Path) -> None:
    images = synthetic_images(TINY_GRID, n_images=5, seed=2)
    images["id_ok"] = False
    summary = summarize(images)
    assert summary["rot_err_deg_median"].isna().all()
    path = tmp_path / "pose_none.png"
    plot_pose_error(summary, path)
    _assert_png(path)


def test_plot_pose_error_wide_range_log_axis(
    default_summary: pd.DataFrame, tmp_path: pathlib.Path
) -> None:
    summary = default_summary.copy()
    summary["rot_err_deg_median"] *= np.exp(summary["alpha_deg"] / 10.0)  # spans > 1e3
    path = tmp_path / "pose_log.png"
    plot_pose_error(summary, path)
    _assert_png(path)
