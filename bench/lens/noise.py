"""Noise against signal (photon transfer) from still frames: full well and read noise.

Over a run of frames of a static scene each pixel's temporal mean and variance, in linear light
(full-scale units), follow ``var = read^2 / fw^2 + mean / fw`` for a sensor whose full well
``fw`` (electrons) maps to full scale: shot noise plus read noise (the photon transfer method,
EMVA Standard 1288). Pixels are pooled in bins of mean signal; per bin the variance is the
median of the pixels' sample variances (robust to a few moving or flickering pixels) corrected
for the median of a chi-square distribution (Wilson-Hilferty approximation, within 0.3% for 4
or more degrees of freedom), minus the 8-bit quantisation noise ``step^2 / 12`` (EMVA 1288's
correction; valid while the noise spans a code or more). Pixels that touch code 0 or 255 in a
run are left out, and bins where many do (clipped noise is biased) are dropped.

Frames count as still when the median absolute difference from the previous frame is small (a
robust form of a mean-difference test: a small moving object does not stop a run), or all of
them when the caller says so. Within a run, pixels that jump by far more than the noise (a
moving object) are left out.
"""

from __future__ import annotations

import math

import numpy as np

MIN_STILL_FRAMES = 5  # per run: 4 degrees of freedom keep the median correction within 0.3%
#: Median absolute difference (8-bit codes) from the previous frame under which a frame counts
#: as still. Estimate: noise of sigma codes gives 1.35 sigma; sensors show 1-4 codes of noise.
STILL_MAX_MEDIAN_DIFF = 6.0
#: A pixel that changes by more than this many noise sigmas (from the frame pair's median
#: difference at its level), and at least MOVED_MIN_CODES, moved: it leaves its run. Estimates.
MOVED_SIGMAS = 10.0
MOVED_MIN_CODES = 20
LEVEL_CODES = 16  # the noise is estimated per band of this many codes (it varies with signal)
_DIFF_SUBSAMPLE = 4  # the median difference is taken on every 4th row and column
MEAN_BINS = 50
MIN_PIXELS_PER_BIN = 100
MAX_CLIPPED_FRACTION = 0.001
MIN_FIT_BINS = 3


def _chi2_median_ratio(dof: int) -> float:
    """median(chi2_k) / k by the Wilson-Hilferty approximation."""
    return (1.0 - 2.0 / (9.0 * dof)) ** 3


class PhotonTransfer:
    """Accumulates runs of still frames (8-bit grey codes) and fits the photon-transfer line.

    ``lut`` (256,) maps codes to linear light (the profile's transfer curve inverted);
    ``all_still`` treats every frame as one still scene.
    """

    def __init__(self, lut: np.ndarray, all_still: bool = False) -> None:
        self.lut = np.asarray(lut, dtype=np.float64)
        if self.lut.shape != (256,) or np.any(np.diff(self.lut) <= 0):
            raise ValueError("lut: needs 256 increasing linear values, one per code")
        self.all_still = all_still
        self._prev: np.ndarray | None = None
        self._run: list | None = None  # n, sum, sum of squares, min code, max code, moved
        # per mean bin: pixels used, clipped, moved, sum of pixels * variance, * quantisation
        self._bins = np.zeros((5, MEAN_BINS))
        self._mean_sum = np.zeros(MEAN_BINS)
        self.runs: list[int] = []  # frames per accepted run

    def add(self, codes: np.ndarray) -> None:
        """One frame (H, W) uint8; it extends the current still run or starts a new one."""
        previous, self._prev = self._prev, codes.copy()
        step = None if previous is None else np.abs(codes.astype(np.int16) - previous)
        sub = slice(None, None, _DIFF_SUBSAMPLE)
        if step is None or not (
            self.all_still or np.median(step[sub, sub]) <= STILL_MAX_MEDIAN_DIFF
        ):
            self._close_run()
        linear = self.lut[codes]
        if self._run is None:
            zeros = np.zeros_like(linear)
            self._run = [0, zeros, zeros.copy(), codes.copy(), codes.copy(), codes < 0]
        run = self._run
        run[0] += 1
        run[1] += linear
        run[2] += linear * linear
        np.minimum(run[3], codes, out=run[3])
        np.maximum(run[4], codes, out=run[4])
        if run[0] > 1:
            run[5] |= _moved(step, previous, sub)

    def _close_run(self) -> None:
        run, self._run = self._run, None
        if run is None or run[0] < MIN_STILL_FRAMES:
            return
        n, total, squares, low, high, moved = run
        mean = (total / n).ravel()
        var = (np.maximum(squares / n - (total / n) ** 2, 0.0) * (n / (n - 1))).ravel()
        index = np.clip((mean * MEAN_BINS).astype(int), 0, MEAN_BINS - 1)
        clipped = ((low == 0) | (high == 255)).ravel()
        moved = moved.ravel() & ~clipped
        keep = ~(clipped | moved)
        self._bins[1] += np.bincount(index[clipped], minlength=MEAN_BINS)
        self._bins[2] += np.bincount(index[moved], minlength=MEAN_BINS)
        index, mean, var = index[keep], mean[keep], var[keep]
        median = _bin_medians(index, var) / _chi2_median_ratio(n - 1)
        counts = np.bincount(index, minlength=MEAN_BINS)
        self._bins[0] += counts
        self._bins[3] += counts * median
        self._bins[4] += np.bincount(index, self._quantisation_var(mean), minlength=MEAN_BINS)
        self._mean_sum += np.bincount(index, mean, minlength=MEAN_BINS)
        self.runs.append(int(n))

    def _quantisation_var(self, mean: np.ndarray) -> np.ndarray:
        """step^2 / 12 at each mean level, step = linear width of one code there."""
        code = np.interp(mean, self.lut, np.arange(256.0))
        step = np.interp(code, np.arange(255) + 0.5, np.diff(self.lut))
        return step * step / 12.0

    def result(self) -> dict:
        """The fit (full_well_e, read_noise_e, per-bin table) or ``{"skipped": why}``."""
        self._close_run()
        if not self.runs:
            return {
                "skipped": f"no run of >= {MIN_STILL_FRAMES} still frames (consecutive frames "
                f"with a median difference <= {STILL_MAX_MEDIAN_DIFF} codes, or --still)"
            }
        pixels, clipped, moved, var_sum, quant_sum = self._bins
        used = np.maximum(pixels, 1)
        usable = (pixels >= MIN_PIXELS_PER_BIN) & (
            clipped <= MAX_CLIPPED_FRACTION * (pixels + clipped)
        )
        mean = self._mean_sum / used
        var = var_sum / used - quant_sum / used
        table = [
            {
                "mean_fs": float(mean[b]),
                "variance_fs2": float(var[b]),
                "quantisation_variance_fs2": float(quant_sum[b] / used[b]),
                "pixels": int(pixels[b]),
                "clipped_pixels": int(clipped[b]),
                "moved_pixels": int(moved[b]),
                "used": bool(usable[b]),
            }
            for b in np.flatnonzero(pixels + clipped + moved)
        ]
        out = {"runs_frames": self.runs, "bins": table}
        if usable.sum() < MIN_FIT_BINS:
            out["skipped"] = f"{int(usable.sum())} usable signal bins < {MIN_FIT_BINS}"
            return out
        out.update(_fit_line(mean[usable], var[usable], pixels[usable]))
        return out


def _moved(step: np.ndarray, previous: np.ndarray, sub: slice) -> np.ndarray:
    """Pixels whose change ``step`` (codes) is far beyond the noise at their level: the noise of
    each band of LEVEL_CODES codes is the frame pair's median change there (sampled on a
    sub-grid); a band with few samples takes the median over all."""
    level = previous // LEVEL_CODES
    changes = step[sub, sub].ravel().astype(float)
    levels = level[sub, sub].ravel()
    bands = 256 // LEVEL_CODES
    median = _bin_medians(levels, changes, bands)
    sparse = np.bincount(levels, minlength=bands) < MIN_PIXELS_PER_BIN
    median[sparse] = np.median(changes)
    sigma = 1.4826 * median / math.sqrt(2.0)  # of one frame, from the difference of two
    limit = np.maximum(MOVED_MIN_CODES, MOVED_SIGMAS * sigma)
    return step > limit[level]


def _bin_medians(index: np.ndarray, values: np.ndarray, bins: int = MEAN_BINS) -> np.ndarray:
    """Median of ``values`` in each bin 0..bins-1 (0 for empty bins)."""
    order = np.lexsort((values, index))
    counts = np.bincount(index, minlength=bins)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    out = np.zeros(bins)
    full = counts > 0
    lo = starts[full] + (counts[full] - 1) // 2
    hi = starts[full] + counts[full] // 2
    out[full] = 0.5 * (values[order[lo]] + values[order[hi]])
    return out


def _fit_line(mean: np.ndarray, var: np.ndarray, pixels: np.ndarray) -> dict:
    """Weighted least squares of var = a + b * mean; a variance's error grows with it, so the
    weights are pixels / var^2, from the previous fit (three passes)."""
    X = np.column_stack([np.ones_like(mean), mean])
    predicted = np.maximum(var, 1e-12)
    for _ in range(3):
        w = pixels / predicted**2
        cov = np.linalg.inv(X.T @ (X * w[:, None]))
        a, b = cov @ (X.T @ (w * var))
        predicted = np.maximum(a + b * mean, 1e-12)
    rel_rms = float(np.sqrt(np.mean(((var - predicted) / predicted) ** 2)))
    out = {
        "offset_fs2": float(a),
        "slope_fs": float(b),
        "offset_err_fs2": float(math.sqrt(cov[0, 0])),
        "slope_err_fs": float(math.sqrt(cov[1, 1])),
        "relative_rms_residual": rel_rms,
    }
    if b <= 0:
        out["skipped"] = f"slope {b:.3g} <= 0: no shot noise seen"
        return out
    full_well = 1.0 / b
    out["full_well_e"] = float(full_well)
    out["read_noise_e"] = float(math.sqrt(a) * full_well) if a > 0 else 0.0
    if a <= 0:
        out["note"] = "offset <= 0: read noise below what 8-bit frames resolve; reported as 0"
    return out
