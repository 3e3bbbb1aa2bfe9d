"""Edge-spread fits on the black outer borders of detected ArUco markers.

Each of a marker's four outer border edges is a slanted black/white edge: its pixels sit at every
sub-pixel distance from the edge line, so the pixels themselves sample the edge-spread function
finely (the idea behind the ISO 12233 slanted-edge method). Here the samples are fitted directly:
linear-light value ``I(d) = A + B * Phi(d / s)`` with ``d`` the pixel centre's signed distance to
the edge (outward, towards the white quiet zone), the line's angle, offset and a slight curvature
(a fisheye bends straight borders) refined in the same Levenberg-Marquardt fit. For a Gaussian
point-spread function, ``s^2`` is its variance along the edge normal plus 1/12 px^2, the
variance of the square pixel's aperture projected on any direction.

Only clean parts of each edge are used: pixels within one module (at most ``BAND_MAX_PX``) of the
edge, at least one module from the marker's corners, and only where the cells just inside the
black border are black too, so that no other edge lies within a module of any sample. The
marker's bits come from its dictionary and id.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cache

import cv2
import numpy as np

from scenes.camera import FisheyeCamera
from scenes.marker import get_dictionary

BAND_MODULES = 1.0  # half-width of the sampled band and clearance from other edges, in modules
BAND_MAX_PX = 16.0  # ... and at most this many pixels: room for s up to BAND_MAX_PX / 3
MAX_PIXELS_PER_EDGE = 3000  # beyond this, every k-th pixel (bounds memory and time)
MIN_PIXELS_PER_EDGE = 40
# Acceptance of a fit. Estimates, chosen so that printed black-on-white markers in ordinary light
# pass and clipped, low-contrast or contaminated edges do not.
MIN_CONTRAST_FS = 0.02  # B, full-scale linear units
MIN_MODULATION = 0.5  # B / (2 A + B): printed black on white paper is about 0.9
MAX_SATURATED_FRACTION = 0.005  # of the band's pixels at code 255
MAX_RESIDUAL_FRACTION = 0.1  # rms residual / B
MAX_SHIFT_PX = 2.0  # the fitted line may move this far from the detector's corners
MIN_S_PX = 0.25  # sqrt(1/12) = 0.29 px is the sharpest an area-sampled edge can be
PIXEL_VARIANCE_PX2 = 1.0 / 12.0  # a unit square aperture, projected on any direction
LM_ITERATIONS = 60

_PARAMS = ("black", "contrast", "angle", "offset", "curvature", "log_s")


@dataclass(frozen=True)
class EdgeSamples:
    """One edge's pixels: distances along the detector's normal and tangent, values, codes."""

    marker_id: int
    edge: int  # 0..3: from ArUco corner k to corner k + 1
    mid_px: np.ndarray  # (2,) midpoint between the two corners
    normal: np.ndarray  # (2,) unit, outward
    tangent: np.ndarray  # (2,) unit, corner k -> k + 1
    d0_px: np.ndarray  # (n,) signed distance of each pixel centre to the detector's line
    along_px: np.ndarray  # (n,)
    value: np.ndarray  # (n,) linear light, full-scale units
    saturated_fraction: float
    band_px: float


_PHI_STEP = 1e-3
_PHI_HALF_RANGE = 8.0


@cache
def _phi_table() -> np.ndarray:
    """Standard normal CDF on z in [-8, 8] every 0.001 from math.erf, one spare entry at the end
    (linear interpolation in it is exact to 3e-8)."""
    z = np.arange(-_PHI_HALF_RANGE, _PHI_HALF_RANGE + 2 * _PHI_STEP, _PHI_STEP)
    return 0.5 * (1.0 + np.array([math.erf(v / math.sqrt(2.0)) for v in z]))


def _phi(z: np.ndarray) -> np.ndarray:
    """Standard normal CDF by linear interpolation in the uniform table (0 or 1 beyond 8)."""
    table = _phi_table()
    pos = (np.clip(z, -_PHI_HALF_RANGE, _PHI_HALF_RANGE) + _PHI_HALF_RANGE) / _PHI_STEP
    i = pos.astype(np.intp)
    frac = pos - i
    return table[i] * (1.0 - frac) + table[i + 1] * frac


@cache
def black_cells(dictionary: str, marker_id: int) -> np.ndarray:
    """(M, M) bool, True where the marker's cell (border included) is black; [row, col]."""
    modules = int(get_dictionary(dictionary).markerSize) + 2
    image = cv2.aruco.generateImageMarker(get_dictionary(dictionary), marker_id, modules)
    return image < 128


def edge_samples(
    linear: np.ndarray, codes: np.ndarray, corners_px: np.ndarray, dictionary: str, marker_id: int
) -> list[EdgeSamples]:
    """The clean pixels of each outer border edge of one detected marker.

    ``linear`` (H, W) is the frame in linear light, ``codes`` the same frame's 8-bit codes;
    ``corners_px`` (4, 2) the detector's corners in ArUco order (TL, TR, BR, BL of the marker).
    """
    black = black_cells(dictionary, marker_id)
    modules = black.shape[0]
    square = np.array([[0, 0], [modules, 0], [modules, modules], [0, modules]], np.float32)
    H_img_mod = cv2.getPerspectiveTransform(square, corners_px.astype(np.float32))
    if not np.isfinite(H_img_mod).all() or abs(np.linalg.det(H_img_mod)) < 1e-12:
        return []  # degenerate corners
    side_px = float(np.mean(np.linalg.norm(corners_px - np.roll(corners_px, -1, 0), axis=1)))
    module_px = side_px / modules
    margin = 1.5 * min(module_px, BAND_MAX_PX) + 2.0
    height, width = linear.shape
    x0, y0 = np.maximum(np.floor(corners_px.min(0) - margin).astype(int), 0)
    x1, y1 = np.minimum(np.ceil(corners_px.max(0) + margin).astype(int) + 1, (width, height))
    if x1 <= x0 or y1 <= y0:
        return []
    ys, xs = np.mgrid[y0:y1, x0:x1]
    pix = np.stack([xs.ravel(), ys.ravel()], axis=-1).astype(float)
    uv = cv2.perspectiveTransform(pix[None], np.linalg.inv(H_img_mod))[0]
    centre = corners_px.mean(axis=0)
    band = min(BAND_MODULES, BAND_MAX_PX / module_px)
    out = []
    for k in range(4):
        u, v = uv[:, 0], uv[:, 1]
        for _ in range(k):  # turn the marker so that edge k is the top edge, run left to right
            u, v = v, modules - u
        row = np.rot90(black, k)[1]  # the cells just inside the border along edge k
        white_before = np.concatenate([[0], np.cumsum(~row)])
        lo = np.clip(np.floor(u - BAND_MODULES + 1e-9), 0, modules - 1).astype(int)
        hi = np.clip(np.ceil(u + BAND_MODULES - 1e-9), 1, modules).astype(int)
        clear = white_before[hi] - white_before[lo] == 0
        keep = (np.abs(v) <= band) & (u >= BAND_MODULES) & (u <= modules - BAND_MODULES) & clear
        idx = np.flatnonzero(keep)
        if idx.size > MAX_PIXELS_PER_EDGE:
            idx = idx[:: math.ceil(idx.size / MAX_PIXELS_PER_EDGE)]
        if idx.size < MIN_PIXELS_PER_EDGE:
            continue
        start, end = corners_px[k], corners_px[(k + 1) % 4]
        tangent = (end - start) / np.linalg.norm(end - start)
        normal = np.array([tangent[1], -tangent[0]])
        mid = 0.5 * (start + end)
        if np.dot(mid - centre, normal) < 0:
            normal = -normal
        rel = pix[idx] - mid
        px_x, px_y = xs.ravel()[idx], ys.ravel()[idx]
        out.append(
            EdgeSamples(
                marker_id=marker_id,
                edge=k,
                mid_px=mid,
                normal=normal,
                tangent=tangent,
                d0_px=rel @ normal,
                along_px=rel @ tangent,
                value=linear[px_y, px_x].astype(float),
                saturated_fraction=float(np.mean(codes[px_y, px_x] == 255)),
                band_px=band * module_px,
            )
        )
    return out


# --- The batched edge-spread fit ----------------------------------------------------------------


def _model(p: np.ndarray, d0: np.ndarray, along: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Model values (E, N) and Jacobian (E, N, 6) for parameters p (E, 6), see ``_PARAMS``."""
    black, contrast, angle, offset, curvature, log_s = (p[:, i : i + 1] for i in range(6))
    s = np.exp(log_s)
    cos, sin = np.cos(angle), np.sin(angle)
    d = d0 * cos + along * sin - offset - curvature * along * along
    z = d / s
    cdf = _phi(z)
    slope = contrast * np.exp(-0.5 * z * z) / (math.sqrt(2.0 * math.pi) * s)  # dI/dd
    jac = np.stack(
        [
            np.ones_like(z),
            cdf,
            slope * (along * cos - d0 * sin),
            -slope,
            -slope * along * along,
            -slope * d,
        ],
        axis=-1,
    )
    return black + contrast * cdf, jac


def fit_edges(edges: list[EdgeSamples]) -> list[dict]:
    """Fit every edge's spread at once (padded arrays); one dict per edge, in order, with
    ``s_px`` and ``s_err_px`` (None when the fit is rejected) and ``status`` ("ok" or why not)."""
    if not edges:
        return []
    n = np.array([e.value.size for e in edges])
    shape = (len(edges), int(n.max()))
    d0, along, value, weight = (np.zeros(shape) for _ in range(4))
    for i, e in enumerate(edges):
        d0[i, : n[i]], along[i, : n[i]], value[i, : n[i]] = e.d0_px, e.along_px, e.value
        weight[i, : n[i]] = 1.0
    p = _initial(d0, value, weight, np.array([e.band_px for e in edges]))
    p, cost, jtj = _levenberg_marquardt(p, d0, along, value, weight)
    dof = np.maximum(n - len(_PARAMS), 1)
    rms = np.sqrt(cost / dof)
    with np.errstate(invalid="ignore"):
        cov = np.linalg.pinv(jtj) * (rms**2)[:, None, None]
    results = []
    for i, e in enumerate(edges):
        black, contrast, angle, offset, curvature, log_s = p[i]
        s = float(np.exp(log_s))
        normal = e.normal * math.cos(angle) + e.tangent * math.sin(angle)
        status = _status(e, black, contrast, offset, s, rms[i])
        results.append(
            {
                "marker_id": e.marker_id,
                "edge": e.edge,
                "centre_px": (e.mid_px + e.normal * offset).tolist(),
                "normal": normal.tolist(),
                "pixels": int(n[i]),
                "black": float(black),
                "contrast": float(contrast),
                "rms_residual_fraction": float(rms[i] / abs(contrast)) if contrast else None,
                "curvature_per_px": float(curvature),
                "s_px": s if status == "ok" else None,
                "s_err_px": float(s * math.sqrt(max(cov[i, 5, 5], 0.0)))
                if status == "ok"
                else None,
                "status": status,
            }
        )
    return results


def _initial(d0: np.ndarray, value: np.ndarray, weight: np.ndarray, band: np.ndarray):
    """Start values: plateau levels from the outer halves of the band, s = 1 px."""
    inner = weight * (d0 < -0.5 * band[:, None])
    outer = weight * (d0 > 0.5 * band[:, None])
    black = (value * inner).sum(1) / np.maximum(inner.sum(1), 1)
    white = (value * outer).sum(1) / np.maximum(outer.sum(1), 1)
    zeros = np.zeros_like(black)
    return np.stack([black, white - black, zeros, zeros, zeros, zeros], axis=1)


def _levenberg_marquardt(p, d0, along, value, weight):
    """Minimize sum(weight * residual^2) per edge; returns parameters, cost and J^T W J."""
    lam = np.full(p.shape[0], 1e-3)
    f, jac = _model(p, d0, along)
    cost = np.sum(weight * (value - f) ** 2, axis=1)
    eye = np.eye(p.shape[1])
    for _ in range(LM_ITERATIONS):
        wjt = np.swapaxes(jac * weight[..., None], 1, 2)
        jtj = wjt @ jac
        grad = (wjt @ (value - f)[..., None])[..., 0]
        diag = np.einsum("epp->ep", jtj)
        damped = (
            jtj
            + (lam[:, None] * diag + 1e-12 * (1.0 + diag.max(1, keepdims=True)))[:, :, None] * eye
        )
        step = np.linalg.solve(damped, grad[..., None])[..., 0]
        trial = p + step
        f_new, jac_new = _model(trial, d0, along)
        cost_new = np.sum(weight * (value - f_new) ** 2, axis=1)
        better = cost_new < cost
        p = np.where(better[:, None], trial, p)
        f = np.where(better[:, None], f_new, f)
        jac = np.where(better[:, None, None], jac_new, jac)
        converged = np.abs(cost - cost_new) <= 1e-10 * cost
        cost = np.where(better, cost_new, cost)
        lam = np.where(better, lam / 3.0, np.minimum(lam * 4.0, 1e12))
        if np.all(converged | (lam >= 1e12)):
            break
    return p, cost, np.swapaxes(jac * weight[..., None], 1, 2) @ jac


def _status(e: EdgeSamples, black, contrast, offset, s, rms) -> str:
    if e.saturated_fraction > MAX_SATURATED_FRACTION:
        return "saturated"
    if not (contrast >= MIN_CONTRAST_FS and contrast / (2 * black + contrast) >= MIN_MODULATION):
        return "low contrast"
    if rms > MAX_RESIDUAL_FRACTION * contrast:
        return "poor fit"
    if abs(offset) > MAX_SHIFT_PX:
        return "line moved"
    if s < MIN_S_PX:
        return "sharper than a pixel"
    if 3.0 * s > e.band_px:
        return "blur wider than the band"
    return "ok"


def edge_geometry(result: dict, lens: FisheyeCamera) -> tuple[float, float]:
    """(theta_deg, psi_deg) of a fitted edge: its centre's field angle and the angle between its
    normal and the radial direction (from the principal point through the centre)."""
    centre = np.asarray(result["centre_px"])
    theta = float(np.degrees(lens.theta_of_pixel(centre)))
    radial = centre - np.array([lens.cx_px, lens.cy_px])
    norm = float(np.linalg.norm(radial))
    cos_psi = abs(float(np.dot(radial, result["normal"]))) / norm if norm > 0 else 1.0
    return theta, float(np.degrees(np.arccos(min(cos_psi, 1.0))))
