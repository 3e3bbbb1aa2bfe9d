"""Where a blurred edge lies on a sampled profile across it: the centroid of the profile's
derivative over a window re-centred on its own estimate (used by :mod:`pipeline.refine` for the
corners and by :mod:`pipeline.refine_curve` for the border's width).

Over a window [a, b] the centroid of the derivative is ``(b v(b) - a v(a) - area) / (v(b) -
v(a))``: the area under the profile normalized by its own values at the window's ends. When the
window is centred on the edge, any point-symmetric blur (pixel area, bilinear reading, the lens,
resampling, sharpening), truncated at the window's ends, leaves it exactly at the edge; light
falling across the edge by a fraction g per px moves it by g h^2 / 2 for a window of half-width
h (0.01 px where the light halves over 100 px). Neither level has to be known: levels taken
further out, on a quiet zone only one module wide (a tag on a cube, with the cube's edge beyond
it) or on paper lit unevenly, moved corners by up to 1.4 px on real photographs
(docs/refine_real.md).
"""

from __future__ import annotations

import numpy as np

#: The marker's outer square in units of its side (ArUco corner order TL, TR, BR, BL, image y
#: down); edge k runs from corner k to corner k + 1, ``OUTWARD`` its outward normal.
SQUARE = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
ALONG = np.roll(SQUARE, -1, axis=0) - SQUARE
OUTWARD = np.array([[0.0, -1.0], [1.0, 0.0], [0.0, 1.0], [-1.0, 0.0]])
for _constant in (SQUARE, ALONG, OUTWARD):
    _constant.flags.writeable = False

#: Half-width of the window (px): it holds 90% of a step blurred with sigma 1.2 px (the camera
#: twin's lens) and ends short of the code bits' edges one module inside on modules of 4 px.
WINDOW_PX = 2.0
#: Re-centrings of the window, from the halfway crossing. More (4, 5 or 10) move the corners of
#: the twin's noisy 20-240 px markers (tests/test_refine_real.py) by up to 0.04 px, either way.
ITERATIONS = 3


def _at(
    values: np.ndarray, area: np.ndarray, rows: np.ndarray, x: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The profiles' linear interpolation at x (samples) and their integral from 0 to x.

    ``values``, ``area``: (profiles, n_s); ``rows``: each x's profile, broadcast against x.
    """
    i = np.minimum(np.maximum(np.floor(x).astype(int), 0), values.shape[-1] - 2)  # np.clip's
    # overhead is most of the cost on these few hundred profiles
    f = x - i
    v0, v1, a0 = values[rows, i], values[rows, i + 1], area[rows, i]
    return v0 + f * (v1 - v0), a0 + f * v0 + 0.5 * f * f * (v1 - v0)


def edge_centroids(
    values: np.ndarray, start: np.ndarray, half: float | np.ndarray, smooth=None
) -> tuple[np.ndarray, np.ndarray]:
    """Each profile's edge (samples from its first) and its rise across the window.

    ``values`` (..., n_s): profiles rising across the edge, in linear light; ``start``: each
    edge's first guess (samples); ``half``: the window's half-width (samples), shrunk where a
    profile's end is nearer. ``smooth``, if given, maps the window's end values to less noisy
    ones (e.g. a median over neighbouring profiles along the edge, whose windows sit alike on
    their edges), called on both ends at once, stacked on a new first axis. NaN where the
    profile does not rise across the window.
    """
    n_s = values.shape[-1]
    steps = np.cumsum(0.5 * (values[..., 1:] + values[..., :-1]), axis=-1)
    area = np.concatenate([np.zeros(values.shape[:-1] + (1,)), steps], axis=-1)
    c = np.minimum(np.maximum(np.asarray(start, dtype=float), 0.0), n_s - 1.0)
    rows = np.arange(c.size).reshape(c.shape)  # each profile's row in the flattened arrays
    flat_values, flat_area = values.reshape(-1, n_s), area.reshape(-1, n_s)
    good = np.ones(c.shape, bool)
    for _ in range(ITERATIONS):
        h = np.minimum(half, np.minimum(c, n_s - 1 - c))
        a, b = c - h, c + h
        ends, (fa, fb) = _at(flat_values, flat_area, rows, np.stack([a, b]))
        va, vb = ends if smooth is None else smooth(ends)
        rise = vb - va
        good &= rise > 0
        found = (b * vb - a * va - (fb - fa)) / np.where(good, rise, 1.0)
        c = np.where(good, np.minimum(np.maximum(found, 0.0), n_s - 1.0), c)  # a bad one stays
        # put, finite
    return np.where(good, c, np.nan), rise
