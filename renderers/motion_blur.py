"""Linear motion blur of a clean radiance image: the marker moving during one exposure."""

from __future__ import annotations

import math

import numpy as np


def motion_kernel(length_px: float) -> np.ndarray:
    """Weights of a horizontal box of ``length_px``, sampled on whole pixels: (2m + 1,) float32.

    Tap ``k`` (offset ``k - m`` px) gets the overlap of pixel ``[k - m - 0.5, k - m + 0.5]`` with
    the box ``[-L/2, L/2]``, divided by ``L``: an odd whole ``L`` gives ``L`` equal taps, an even
    one ``L - 1`` full taps and a half tap at each end. The box is centred, so the blurred marker
    sits at its mid-exposure position (the ground truth). ``L <= 1`` is no blur: ``[1]``.
    """
    if not (math.isfinite(length_px) and length_px >= 0):
        raise ValueError(f"length_px={length_px!r}: must be a finite number >= 0")
    if length_px <= 1:
        return np.ones(1, np.float32)
    half = length_px / 2
    m = math.ceil(half - 0.5)
    k = np.arange(-m, m + 1, dtype=float)
    overlap = np.clip(np.minimum(k + 0.5, half) - np.maximum(k - 0.5, -half), 0.0, None)
    return (overlap / length_px).astype(np.float32)


def motion_blur(radiance: np.ndarray, length_px: float) -> np.ndarray:
    """Horizontal motion blur of linear radiance: the scene moves ``length_px`` px along image x
    during the exposure (a box of that length, :func:`motion_kernel`), so it belongs before the
    camera response (noise is added after the light is integrated).

    ``radiance``: (..., H, W, C) float, any leading axes (e.g. N canopy images); image edges are
    extended by their last pixel. Returns the same shape, float32.
    """
    weights = motion_kernel(length_px)
    if len(weights) == 1:
        return radiance
    m = len(weights) // 2
    width = radiance.shape[-2]
    pad = [(0, 0)] * radiance.ndim
    pad[-2] = (m, m)
    padded = np.pad(np.asarray(radiance, np.float32), pad, mode="edge")
    out = np.zeros(radiance.shape, np.float32)
    for k, w in enumerate(weights):
        out += w * padded[..., k : k + width, :]
    return out
