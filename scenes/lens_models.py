"""The radial functions of the fisheye lens models, exact to each model's own limit.

Every model maps a ray at angle ``theta`` from the optical axis to a normalized image radius
``d(theta)``; :class:`scenes.camera.FisheyeCamera` (whose docstring gives the formulas, their
sources and the pixel mapping) turns it into pixels. This module holds d(theta), its exact
inverse, each model's valid limit and parameter checks, so the camera class stays one job.
"""

from __future__ import annotations

import functools
import math
from typing import Any

import numpy as np

from scenes.array_ops import NUMPY

#: Parameter names per model (``ocamcalib``: a0, a1, ... as many as given).
PARAM_NAMES: dict[str, tuple[str, ...]] = {
    "equidistant": (),
    "kannala_brandt": ("k1", "k2", "k3", "k4"),
    "double_sphere": ("xi", "alpha"),
    "eucm": ("alpha", "beta"),
    "ucm": ("xi",),
    "ocamcalib": (),
}
MODELS = tuple(PARAM_NAMES)
MAX_OCAM_COEFFS = 64  # OCamCalib's own MAX_POL_LENGTH
_TABLE_SIZE = 2049
_MAX_ITER = 100


# --- Radial functions -------------------------------------------------------------------------


def _poly(coeffs: tuple[float, ...], x: np.ndarray, xp=NUMPY) -> np.ndarray:
    """sum_i coeffs[i] x^i (Horner)."""
    out = xp.full_like(x, coeffs[-1])
    for c in reversed(coeffs[:-1]):
        out = out * x + c
    return out


def _poly_derivative(coeffs: tuple[float, ...]) -> tuple[float, ...]:
    return tuple(i * c for i, c in enumerate(coeffs))[1:] or (0.0,)


def _kb_coeffs(params: tuple[float, ...]) -> tuple[float, ...]:
    """d(theta) = sum_i c_i theta^i of Kannala-Brandt (odd powers up to 9)."""
    k1, k2, k3, k4 = params
    return (0.0, 1.0, 0.0, k1, 0.0, k2, 0.0, k3, 0.0, k4)


def _closed_radius(
    model: str, params: tuple[float, ...], theta: np.ndarray, xp=NUMPY
) -> np.ndarray:
    """d(theta) for the models with a closed-form projection (all but OCamCalib)."""
    if model == "equidistant":
        return xp.copy(theta)
    if model == "kannala_brandt":
        return _poly(_kb_coeffs(params), theta, xp)
    s, c = xp.sin(theta), xp.cos(theta)
    with xp.errstate():
        if model == "double_sphere":
            xi, alpha = params
            k = xi + c
            return s / (alpha * xp.sqrt(s * s + k * k) + (1.0 - alpha) * k)
        if model == "eucm":
            alpha, beta = params
            return s / (alpha * xp.sqrt(beta * s * s + c * c) + (1.0 - alpha) * c)
        (xi,) = params  # ucm
        return s / (c + xi)


def _closed_theta(model: str, params: tuple[float, ...], d: np.ndarray, xp=NUMPY) -> np.ndarray:
    """theta(d) for the models with a published closed-form unprojection."""
    r2 = d * d
    with xp.errstate():
        if model == "double_sphere":  # Usenko et al. 2018, eq. (47)-(49)
            xi, alpha = params
            mz = (1.0 - alpha * alpha * r2) / (
                alpha * xp.sqrt(xp.maximum(1.0 - (2.0 * alpha - 1.0) * r2, 0.0)) + 1.0 - alpha
            )
            k = (mz * xi + xp.sqrt(mz * mz + (1.0 - xi * xi) * r2)) / (mz * mz + r2)
            return xp.atan2(k * d, k * mz - xi)
        if model == "eucm":  # Khomutenko et al. 2016, eq. (11)
            alpha, beta = params
            root = xp.sqrt(xp.maximum(1.0 - (2.0 * alpha - 1.0) * beta * r2, 0.0))
            mz = (1.0 - beta * alpha * alpha * r2) / (alpha * root + 1.0 - alpha)
            return xp.atan2(d, mz)
        (xi,) = params  # ucm (Mei): the ray is k (m, 1) - (0, 0, xi)
        k = (xi + xp.sqrt(xp.maximum(1.0 + (1.0 - xi * xi) * r2, 0.0))) / (1.0 + r2)
        return xp.atan2(k * d, k - xi)


def _ocam_theta(params: tuple[float, ...], rho: np.ndarray, xp=NUMPY) -> np.ndarray:
    """OCamCalib: angle from the forward axis of the ray (rho, -P(rho)); rho in pixels."""
    return xp.atan2(rho, -_poly(params, rho, xp))


@functools.lru_cache(maxsize=64)
def _ocam_fold_rho(params: tuple[float, ...]) -> float | None:
    """Where theta(rho) stops increasing: the first root of rho P'(rho) - P(rho), which is
    sum_i (i - 1) a_i rho^i (positive at 0 since a0 < 0); None if theta increases throughout."""
    return _first_positive_root(tuple((i - 1) * a for i, a in enumerate(params)), math.inf)


def _ocam_dtheta(params: tuple[float, ...], rho: np.ndarray, xp=NUMPY) -> np.ndarray:
    p = _poly(params, rho, xp)
    return (rho * _poly(_poly_derivative(params), rho, xp) - p) / (rho * rho + p * p)


def _first_positive_root(coeffs: tuple[float, ...], upper: float) -> float | None:
    """Smallest real root in (0, upper) of sum_i coeffs[i] x^i where the sign turns negative,
    polished by Newton to machine precision; None if there is none."""
    trimmed = np.trim_zeros(np.asarray(coeffs, dtype=float), "b")
    if len(trimmed) < 2:
        return None
    roots = np.roots(trimmed[::-1])
    real = roots[np.abs(roots.imag) <= 1e-9 * np.maximum(1.0, np.abs(roots))].real
    deriv = _poly_derivative(tuple(trimmed))
    best = None
    for x in sorted(real[(real > 0) & (real < upper)]):
        for _ in range(50):
            slope = float(_poly(deriv, np.array(x)))
            if slope == 0.0:
                break
            step = float(_poly(tuple(trimmed), np.array(x))) / slope
            x -= step
            if abs(step) <= 1e-16 * max(1.0, abs(x)):
                break
        # a touching (double) root does not stop the increase; a crossing does
        eps = 1e-7 * max(1.0, x)
        if float(_poly(tuple(trimmed), np.array(x + eps))) < 0 and 0 < x < upper:
            best = x
            break
    return best


def _cos_limit(w: float) -> float:
    return math.acos(max(-1.0, min(1.0, -w)))


def _ucm_w(xi2: float) -> float:
    """A unit-sphere ray is valid for a UCM with parameter xi2 while cos(angle) > -w."""
    return xi2 if xi2 <= 1.0 else 1.0 / xi2


def valid_limit_rad(model: str, params: tuple[float, ...]) -> float:
    """The largest ray angle (rad) the model maps one-to-one: where d(theta) stops strictly
    increasing or its denominator reaches 0; pi when it increases all the way."""
    if model == "equidistant":
        return math.pi
    if model == "kannala_brandt":
        root = _first_positive_root(_poly_derivative(_kb_coeffs(params)), math.pi)
        return math.pi if root is None else root
    if model == "ucm":
        return _cos_limit(_ucm_w(params[0]))
    if model in ("double_sphere", "eucm"):
        alpha = params[1] if model == "double_sphere" else params[0]
        w = 0.0 if alpha >= 1.0 else _ucm_w(alpha / (1.0 - alpha))
        t2 = _cos_limit(w)  # the limit on the second (DS) or the scaled (EUCM) sphere
        if model == "eucm":
            return math.atan2(math.sin(t2) / math.sqrt(params[1]), math.cos(t2))
        xi = params[0]  # back along the ray from the second centre (0, 0, -xi) to the unit sphere
        t = xi * math.cos(t2) + math.sqrt(1.0 - (xi * math.sin(t2)) ** 2)
        return math.atan2(t * math.sin(t2), t * math.cos(t2) - xi)
    rho = _ocam_fold_rho(params)
    if rho is not None:
        return float(_ocam_theta(params, np.array(rho)))
    trimmed = np.trim_zeros(np.asarray(params, dtype=float), "b")
    if len(trimmed) == 2:  # P = a0 + a1 rho: theta tends to atan2(1, -a1)
        return math.atan2(1.0, -trimmed[1])
    return math.pi if len(trimmed) > 2 else math.pi / 2


def _valid_radius(model: str, params: tuple[float, ...], theta_valid: float) -> float:
    """d(theta_valid): the largest normalized radius the model maps back (inf at a pole)."""
    if model == "double_sphere" and params[1] > 0.5:
        return 1.0 / math.sqrt(2.0 * params[1] - 1.0)
    if model == "eucm" and params[0] > 0.5:
        return 1.0 / math.sqrt(params[1] * (2.0 * params[0] - 1.0))
    if model == "ucm" and params[0] > 1.0:
        return 1.0 / math.sqrt(params[0] ** 2 - 1.0)
    if model in ("double_sphere", "eucm", "ucm"):
        return math.inf
    if model == "ocamcalib":
        rho = _ocam_fold_rho(params)
        return math.inf if rho is None else rho / -params[0]
    return float(_closed_radius(model, params, np.array(theta_valid)))


def _invert_increasing(
    func, dfunc, y: np.ndarray, xs: np.ndarray, fs: np.ndarray, xp=NUMPY
) -> np.ndarray:
    """x with func(x) = y for an increasing func tabulated as fs = func(xs): Newton's method
    from the table's linear interpolation, kept inside the table bracket (bisection when a step
    leaves it), run to machine precision. ``y`` is clipped to the table's range."""
    y = xp.clip(xp.asarray(y), float(fs[0]), float(fs[-1]))
    i = xp.clip(xp.searchsorted(fs, y), 1, len(xs) - 1)
    lo, hi = xp.gather(xs, i - 1), xp.gather(xs, i)
    x = xp.interp(y, fs, xs)
    tol = 4 * float(np.finfo(float).eps) * xp.maximum(xp.abs(y), 1.0)  # f's own rounding
    with xp.errstate():
        for _ in range(_MAX_ITER):
            r = func(x) - y
            active = xp.abs(r) > tol
            if not xp.any(active):
                break
            lo = xp.where(r <= 0, x, lo)
            hi = xp.where(r >= 0, x, hi)
            new = x - r / dfunc(x)
            new = xp.where((new >= lo) & (new <= hi), new, 0.5 * (lo + hi))
            active &= new != x
            if not xp.any(active):
                break
            x = xp.where(active, new, x)
    return x


@functools.lru_cache(maxsize=64)
def _kb_table(params: tuple[float, ...], theta_valid: float) -> tuple[np.ndarray, np.ndarray]:
    theta = np.linspace(0.0, theta_valid, _TABLE_SIZE)
    return theta, _closed_radius("kannala_brandt", params, theta)


@functools.lru_cache(maxsize=64)
def _ocam_table(params: tuple[float, ...], theta_top: float) -> tuple[np.ndarray, np.ndarray]:
    """rho from 0 to where theta(rho) first reaches ``theta_top`` (theta_max or the fold)."""
    rho_fold = _ocam_fold_rho(params)
    if rho_fold is None:
        rho_top = -params[0]
        for _ in range(200):
            if float(_ocam_theta(params, np.array(rho_top))) >= theta_top:
                break
            rho_top *= 2.0
    else:
        rho_top = rho_fold
    rho = np.linspace(0.0, rho_top, _TABLE_SIZE)
    return rho, _ocam_theta(params, rho)


# --- The camera -------------------------------------------------------------------------------


def check_params(model: str, params: Any) -> tuple[float, ...]:
    """The model's parameters as floats, or ValueError naming ``params`` and the allowed range."""
    try:
        values = tuple(float(p) for p in params)
    except (TypeError, ValueError):
        raise ValueError(f"params={params!r}: must be a list of numbers") from None
    if not all(math.isfinite(p) for p in values):
        raise ValueError(f"params={values}: must be finite")
    names = PARAM_NAMES[model]
    if model == "ocamcalib":
        if not 1 <= len(values) <= MAX_OCAM_COEFFS or values[0] >= 0:
            raise ValueError(
                f"params={values}: ocamcalib needs 1 to {MAX_OCAM_COEFFS} polynomial "
                "coefficients a0, a1, ... with a0 < 0"
            )
        return values
    if len(values) != len(names):
        expected = f"({', '.join(names)})" if names else "none"
        raise ValueError(f"params={values}: the {model} model takes {expected}")
    ranges = {
        "double_sphere": ((-1.0, 1.0, False), (0.0, 1.0, True)),  # xi in (-1, 1), alpha in [0, 1]
        "eucm": ((0.0, 1.0, True), (0.0, math.inf, False)),  # alpha in [0, 1], beta > 0
        "ucm": ((0.0, math.inf, True),),  # xi >= 0
    }.get(model, ())
    for name, value, (lo, hi, closed) in zip(names, values, ranges, strict=False):
        inside = lo <= value <= hi if closed else lo < value < hi
        if not inside:
            left, right = ("[", "]") if closed else ("(", ")")
            raise ValueError(
                f"params: {name}={value!r}: allowed range is {left}{lo:g}, {hi:g}{right}"
            )
    return values


@functools.lru_cache(maxsize=256)
def valid_limit(model: str, params: tuple[float, ...]) -> float:
    """:func:`valid_limit_rad`, cached: every projection asks for it."""
    return valid_limit_rad(model, params)


@functools.lru_cache(maxsize=256)
def _cached_valid_radius(model: str, params: tuple[float, ...]) -> float:
    return _valid_radius(model, params, valid_limit(model, params))


def radius_of_theta(
    model: str, params: tuple[float, ...], theta_rad: np.ndarray, theta_top_rad: float, xp=NUMPY
) -> np.ndarray:
    """Normalized image radius d(theta) for ray angles up to ``theta_top_rad`` (the image
    circle or the model's limit, whichever is smaller: OCamCalib's inverse is tabulated to it).
    ``xp``: the array namespace (:mod:`scenes.array_ops`)."""
    theta = xp.asarray(theta_rad)
    if model != "ocamcalib":
        return _closed_radius(model, params, theta, xp)
    rho, th = _ocam_table(params, theta_top_rad)
    rho_of_theta = _invert_increasing(
        lambda r: _ocam_theta(params, r, xp),
        lambda r: _ocam_dtheta(params, r, xp),
        theta,
        rho,
        th,
        xp,
    )
    return rho_of_theta / -params[0]


def theta_of_radius(model: str, params: tuple[float, ...], d: np.ndarray, xp=NUMPY) -> np.ndarray:
    """Ray angle theta for a normalized radius d: the exact inverse of :func:`radius_of_theta`.
    Radii beyond the model's reach give its limit."""
    d = xp.minimum(xp.asarray(d), _cached_valid_radius(model, params))
    if model == "equidistant":
        return xp.copy(d)
    if model == "ocamcalib":
        return _ocam_theta(params, d * -params[0], xp)
    limit = valid_limit(model, params)
    if model == "kannala_brandt":
        xs, fs = _kb_table(params, limit)
        coeffs = _kb_coeffs(params)
        deriv = _poly_derivative(coeffs)
        return _invert_increasing(
            lambda t: _poly(coeffs, t, xp), lambda t: _poly(deriv, t, xp), d, xs, fs, xp
        )
    theta = _closed_theta(model, params, d, xp)
    return xp.where(xp.isinf(d), limit, theta)
