"""Which transfer curve an image's edges follow, measured on the marker itself, and whether the
refinement can be trusted when it cannot be measured (``transfer="auto"`` of
:func:`pipeline.refine.refine_corners_by_edges`).

An edge's position (:func:`pipeline.refine_edge.edge_centroids`) is exact when its profile is a
point-symmetric blur of a step in the intensities it is read in. Blur before the camera's curve
(the lens, as in the camera twin) is symmetric in linear light (``"srgb"``); blur after it
(resampling, sharpening, JPEG, as in most photographs handed over) is symmetric in the codes
(``"linear"``).
Read with the wrong curve, every dark-to-light edge moves by the same amount towards the light:
a black region grows, a light one shrinks. The marker's black border is exactly one module wide
and, where the code bit inside it is white, has an inner edge of the opposite polarity: its
measured width minus one module is twice that shift (:func:`border_excess`), zero under the
right curve. Real images are blurred both before the curve (the lens) and after it (their
processing): their edges lie between the two readings, where the border is one module wide.
Shifts this small add linearly, so the corners are taken at that share of the way from the
"srgb" reading to the "linear" one (clipped to the two): on renders blurred after the curve
this leaves a fifth of the error of the "linear" reading alone (tests/test_refine_real.py).

Where the border cannot be measured (modules too small for its windows, no white code bit
along the edges) the camera's own curve, sRGB, is kept, and the refinement is refused as "curve
sensitive" when its corners under the two curves differ by more than a blurred step can make
them differ (:data:`MAX_CURVE_SPREAD_PX`): the edges are then no blurred step (a dark surround
within the window, a cube's edge), and neither reading can be trusted.
"""

from __future__ import annotations

from collections.abc import Callable

import cv2
import numpy as np

from pipeline.refine_edge import ALONG, OUTWARD, SQUARE, WINDOW_PX, edge_centroids

#: Depths across an edge (modules, + outward) of the border measurement's profiles: from the
#: centre of the code bit inside the border to past the outer edge's window.
_DEPTHS = (-1.75, 0.75)
_BLACK, _WHITE_OUT, _WHITE_IN = (-0.7, -0.3), (0.45, 0.75), (-1.65, -1.35)  # level windows
#: The border's two edges are a module apart; each is found in a window of +-WINDOW_PX, which
#: must end 2 blur sigmas (of 1 px) before the other edge. A 5 px floor (2 sigmas of 1.5 px)
#: left more markers to sRGB: on tests/test_refine_real.py's 20-40 px markers blurred after the
#: curve it gave 0.34-0.60 px mean corner error, this one 0.20-0.37; on blur before the curve
#: 0.059-0.106 px (exactly "srgb") against 0.065-0.117. Smaller modules measured with narrower
#: windows lost more there.
MIN_MODULE_PX = 4.0
MIN_BORDER_PROFILES = 6  # profiles with a white code bit inside the border, over the 4 edges
#: Largest corner spread between the two curves that a blurred black-to-white step explains:
#: per edge, the two readings' edges (:func:`pipeline.refine_edge.edge_centroids`, +-2 px) of a
#: step from albedo 0.04 to 0.8 blurred with sigma up to 1.5 px (the widest blur of
#: tests/test_refine_real.py's families), before or after the curve, at any sub-pixel phase,
#: differ by 0.66 px at most; at a corner two edges add (x sqrt 2): 0.93 px, and 0.23 px more
#: for noise and uneven light.
MAX_CURVE_SPREAD_PX = 1.16


def border_excess(
    patch: np.ndarray, homography: np.ndarray, modules: int, to_patch: Callable
) -> float:
    """The black border's measured width minus one module (virtual px), from the profiles with a
    white code bit inside it; NaN where there are too few or the modules are too small.

    ``homography`` maps the marker's modules to virtual pixels; ``to_patch`` virtual pixels to
    the (linearized) patch's pixels.
    """
    corners = cv2.perspectiveTransform((SQUARE * modules)[None], homography)[0]
    module_px = np.linalg.norm(corners - np.roll(corners, 1, axis=0), axis=1).min() / modules
    if module_px < MIN_MODULE_PX:
        return float("nan")
    square, along = SQUARE * modules, ALONG * modules
    # three profiles in the middle of each module along an edge, border modules left out
    t = (np.arange(1, modules - 1)[:, None] + np.array([0.3, 0.5, 0.7])).ravel() / modules
    n_d = int(np.ceil((_DEPTHS[1] - _DEPTHS[0]) * module_px / 0.5)) + 1
    d = np.linspace(*_DEPTHS, n_d)
    pts = (square[:, None, None] + t[None, :, None, None] * along[:, None, None]) + d[
        None, None, :, None
    ] * OUTWARD[:, None, None]  # (4, n_t, n_d, 2) modules
    virt = cv2.perspectiveTransform(pts.reshape(1, -1, 2), homography)[0]
    px = to_patch(virt.reshape(pts.shape)).astype(np.float32).reshape(-1, n_d, 2)
    v = cv2.remap(patch, px[..., 0], px[..., 1], cv2.INTER_LINEAR)  # (profiles, n_d)

    def level(window: tuple[float, float]) -> np.ndarray:
        return np.median(v[:, (d >= window[0]) & (d <= window[1])], axis=1)

    black, white_out, white_in = level(_BLACK), level(_WHITE_OUT), level(_WHITE_IN)
    contrast = white_out - black
    use = (contrast > 0.2 * white_out) & (white_in - black > 0.5 * contrast)
    if use.sum() < MIN_BORDER_PROFILES:
        return float("nan")
    # both edges found as the corners' are (the same window, in samples of this profile)
    step = (d[1] - d[0]) * module_px
    half = WINDOW_PX / step
    rising = v[use]
    start = np.ones(len(rising))
    edges, _ = edge_centroids(  # the outer edges, then the inner ones (falling: negated)
        np.concatenate([rising, -rising]),
        np.concatenate([start * np.argmin(np.abs(d)), start * np.argmin(np.abs(d + 1.0))]),
        half,
    )
    e_out, e_in = edges[: len(rising)], edges[len(rising) :]
    width = (e_out - e_in)[np.isfinite(e_out - e_in)] * step
    if width.size < MIN_BORDER_PROFILES:
        return float("nan")
    return float(np.median(width)) - module_px


def choose_curve(
    codes: np.ndarray,
    luts: dict[str, np.ndarray],
    run: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]],
    modules: int,
    to_patch: Callable,
    errors: type[Exception],
) -> tuple[np.ndarray | None, str | None]:
    """The corners (virtual px) under the curve the marker's border follows, or None and why not.

    ``run(patch)`` refines on a linearized patch and returns the corners and the homography of
    the marker's modules, or raises ``errors`` (the refinement's failure).
    """
    found, failures = {}, {}
    patches = {curve: luts[curve][codes].astype(np.float32, copy=False) for curve in luts}
    for curve in ("srgb", "linear"):
        try:
            found[curve] = run(patches[curve])
        except (errors, np.linalg.LinAlgError, cv2.error) as exc:
            failures[curve] = exc
    if "srgb" in failures:
        raise failures["srgb"]
    if "linear" in failures:
        return None, "curve sensitive"  # one reading fits the edges, the other does not
    excess = {
        curve: border_excess(patches[curve], h, modules, to_patch)
        for curve, (_, h) in found.items()
    }
    e_srgb, e_linear = excess["srgb"], excess["linear"]
    if np.isfinite([e_srgb, e_linear]).all():
        # where between the two readings the border is one module wide (clipped to them)
        share = (
            float(np.clip(e_srgb / (e_srgb - e_linear), 0.0, 1.0)) if e_srgb != e_linear else 0.0
        )
        return found["srgb"][0] + share * (found["linear"][0] - found["srgb"][0]), None
    spread = np.linalg.norm(found["srgb"][0] - found["linear"][0], axis=1).max()
    if spread > MAX_CURVE_SPREAD_PX:
        return None, "curve sensitive"
    return found["srgb"][0], None
