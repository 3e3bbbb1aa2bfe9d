"""A lone marker's full frame at the cost of its crop: the crop traced, the rest the open sky.

In the study's scene (one marker on its carrier, nothing else) every ray outside the window
around the carrier (:meth:`renderers.marker_renderer.MarkerRenderer.crop`) misses: its pixel
holds the sky's own radiance, with no sun and nothing to shadow or reflect. That part does not
change from frame to frame, so :func:`sky_background` computes it once per lens and lighting with
the renderer's own sky formula (:func:`renderers.sky_irradiance.sky_luminance`): at the pixel
centre, and averaged over the pixel's stratified sub-cells where the traced render would take
every sample (:func:`renderers.window.edge_pixels`: the image circle's rim, the horizon, a
backdrop's edge); black outside the circle. A frame then traces only its crop and pastes it in.
``whiskerbench bench render`` measures the result against the frame with every pixel traced.
"""

from __future__ import annotations

import math

import numpy as np

from renderers.sky_irradiance import sky_luminance
from renderers.window import edge_pixels
from scenes.camera import FisheyeCamera
from scenes.lighting import Lighting

#: Rows computed at a time: bounds the float64 temporaries to a few tens of MB on any frame.
BAND_ROWS = 128


def sky_background(lens: FisheyeCamera, lighting: Lighting, spp: int) -> np.ndarray:
    """(height, width, 3) float32 linear RGB of the open sky through ``lens``, as the renderer
    would give pixels whose rays all miss: the sky along the pixel-centre ray, or the mean over
    ``spp`` stratified sub-cells (at least 2 x 2) where the light changes across a pixel's
    neighbourhood (the adaptive pass's edges)."""
    if lighting.canopy is not None:
        raise ValueError(f"lighting {lighting.name!r}: a canopy's shadow needs every pixel traced")
    h, w = lens.height_px, lens.width_px
    out = np.empty((h, w), np.float64)
    for r0 in range(0, h, BAND_ROWS):
        ys, xs = np.mgrid[r0 : min(r0 + BAND_ROWS, h), 0:w].astype(np.float64)
        out[r0 : r0 + BAND_ROWS] = _sky(lens, lighting, xs, ys)
    n = max(2, math.isqrt(spp))
    offsets = (np.arange(n) + 0.5) / n - 0.5
    edge_y, edge_x = np.nonzero(edge_pixels(out, out))  # a third of the frame in the sun preset
    for i in range(0, len(edge_y), BAND_ROWS * w):
        y, x = edge_y[i : i + BAND_ROWS * w], edge_x[i : i + BAND_ROWS * w]
        total = np.zeros(len(y))
        for oy in offsets:
            for ox in offsets:
                total += _sky(lens, lighting, x + ox, y + oy)
        out[y, x] = total / n**2
    return (out[..., None] * np.asarray(lighting.sky.color, np.float64)).astype(np.float32)


def _sky(lens: FisheyeCamera, lighting: Lighting, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """The sky's luminance along the rays through pixel positions (0 outside the circle)."""
    dx, dy, dz, valid = lens.unproject_xy(x, y)
    miss = np.zeros_like(valid)
    zero = np.zeros_like(dx)
    return sky_luminance(lighting.sky, valid, miss, miss, (zero, zero, zero), (dx, dy, dz))
