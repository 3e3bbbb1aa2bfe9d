"""Radial and tangential PSF widths per field-angle bin, from many fitted edges.

An edge whose normal makes angle ``psi`` with the radial direction sees the variance of the PSF
along that normal: for a Gaussian with variances ``s_r^2`` (radial) and ``s_t^2`` (tangential),
``v = s_r^2 cos^2 psi + s_t^2 sin^2 psi``, where ``v`` is the edge's fitted variance less the
pixel aperture's (and less what the camera's processing adds, :mod:`bench.lens.calibrate`). Per bin
this is a linear least-squares problem in (s_r^2, s_t^2); it needs edges at several ``psi``.
Where they all share one orientation only an isotropic width can be told, and it is flagged.
"""

from __future__ import annotations

import math

import numpy as np

MIN_EDGES_PER_BIN = 8  # estimate: two unknowns plus enough to reject an outlier and see a residual
#: Standard deviation of cos^2(psi) below which the two widths are not separable (uniform psi
#: gives 0.35; a single orientation 0). An estimate.
MIN_PSI_SPREAD = 0.15
OUTLIER_MADS = 4.0  # residuals beyond this many robust sigmas are dropped (one pass)


def solve_bins(
    theta_deg: np.ndarray, psi_deg: np.ndarray, variance_px2: np.ndarray, bin_deg: float
) -> list[dict]:
    """Per-bin results (list of dicts, in angle order) for edges at ``theta_deg`` whose PSF
    variance along the normal is ``variance_px2`` (pixel aperture removed), the normal at
    ``psi_deg`` from the radial direction."""
    theta_deg, psi_deg, variance = (
        np.asarray(a, dtype=float) for a in (theta_deg, psi_deg, variance_px2)
    )
    index = np.floor(theta_deg / bin_deg).astype(int)
    bins = []
    for b in np.unique(index):
        sel = index == b
        row = {
            "theta_lo_deg": float(b * bin_deg),
            "theta_hi_deg": float((b + 1) * bin_deg),
            "theta_mean_deg": float(theta_deg[sel].mean()),
            "edges": int(sel.sum()),
        }
        row.update(_solve_bin(psi_deg[sel], variance[sel]))
        bins.append(row)
    return bins


def _solve_bin(psi_deg: np.ndarray, y: np.ndarray) -> dict:
    n = psi_deg.size
    if n < MIN_EDGES_PER_BIN:
        return {"mode": "too few edges", "note": f"{n} edges < {MIN_EDGES_PER_BIN}"}
    c2 = np.cos(np.radians(psi_deg)) ** 2
    spread = float(np.std(c2))
    if spread < MIN_PSI_SPREAD:
        keep = _inliers(y - np.median(y))
        var = float(np.mean(y[keep]))
        se = float(np.std(y[keep], ddof=1) / math.sqrt(keep.sum()))
        sigma = math.sqrt(max(var, 0.0))
        return {
            "mode": "isotropic",
            "note": f"psi spread {spread:.2f} < {MIN_PSI_SPREAD}: only an isotropic width",
            "sigma_radial_px": sigma,
            "sigma_tangential_px": sigma,
            **_errors(var, se, var, se),
            "outliers": int(n - keep.sum()),
            "residual_rms_px2": float(np.std(y[keep])),
        }
    X = np.column_stack([c2, 1.0 - c2])
    keep = np.ones(n, bool)
    for _ in range(2):  # fit, drop outliers, refit
        coef, *_ = np.linalg.lstsq(X[keep], y[keep], rcond=None)
        resid = y - X @ coef
        keep = _inliers(resid)
    dof = max(int(keep.sum()) - 2, 1)
    rms = float(np.sqrt(np.sum(resid[keep] ** 2) / dof))
    cov = np.linalg.inv(X[keep].T @ X[keep]) * rms**2
    var_r, var_t = (float(v) for v in coef)
    se_r, se_t = (float(math.sqrt(cov[i, i])) for i in range(2))
    clipped = [name for name, v in (("radial", var_r), ("tangential", var_t)) if v < 0]
    return {
        "mode": "anisotropic",
        "note": f"{' and '.join(clipped)} variance < 0, clipped to 0" if clipped else "",
        "sigma_radial_px": math.sqrt(max(var_r, 0.0)),
        "sigma_tangential_px": math.sqrt(max(var_t, 0.0)),
        **_errors(var_r, se_r, var_t, se_t),
        "outliers": int(n - keep.sum()),
        "residual_rms_px2": rms,
        "psi_spread": spread,
    }


def _inliers(resid: np.ndarray) -> np.ndarray:
    mad = 1.4826 * float(np.median(np.abs(resid - np.median(resid))))
    if mad == 0.0:
        return np.ones(resid.size, bool)
    return np.abs(resid - np.median(resid)) <= OUTLIER_MADS * mad


def _errors(var_r: float, se_r: float, var_t: float, se_t: float) -> dict:
    """Standard errors of the widths from those of the variances (d sigma = d var / 2 sigma)."""
    out = {"variance_radial_px2": var_r, "variance_tangential_px2": var_t}
    for name, var, se in (("radial", var_r, se_r), ("tangential", var_t, se_t)):
        out[f"sigma_{name}_err_px"] = se / (2.0 * math.sqrt(var)) if var > 0 else None
    return out
