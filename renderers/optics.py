"""The lens's optics on the sensor: relative illumination, image circle, PSF, lateral colour.

All stages are linear and deterministic, so they run once per clean image and every noisy image
drawn from it reuses the result. Images are (N, H, W, C) float32 stacks in linear light, a crop of
the full frame at ``origin_px`` = (x0, y0); field positions are full-frame pixels.

The point-spread function varies over the field and is anisotropic: a Gaussian with
``sigma_radial`` along the line from the principal point through the pixel and
``sigma_tangential`` across it. Its covariance is evaluated on a grid of anchor pixels (the
crop's corners and points inside, spaced so neighbouring anchors' widths differ by at most
:data:`PSF_STEP_PX`, 8 to 64 px apart) and is bilinear in between. Each cell between four anchors
is convolved once (``cv2.filter2D``, edges replicated) with the normalized sampled kernel of the
cell's mean covariance, cut at 4 sigma; each pixel is then moved to its own covariance to first
order by the heat equation, d(blur)/d(Sigma_ij) = 1/2 d_i d_j blur, with central differences.
This costs one convolution per pixel; blending four anchor convolutions per pixel was as
accurate (both within 0.2% of the contrast of a per-pixel kernel on a field whose width grows
six-fold across a 200 px crop) but 1.6 to 1.9 times slower. A uniform field is one convolution.
Only the convolutions depend on the image: the cells, their kernels and every pixel's stencil
weights are a :class:`PsfPlan`, built once per crop and reused by every image of it (1.6x
faster on the prototype's 2592 x 144 band, bit for bit the same output).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np

from scenes.camera import FisheyeCamera
from scenes.profile import LateralColour, PsfTable

#: Largest difference in width (px) between the kernels of neighbouring PSF anchors.
PSF_STEP_PX = 0.2
#: Anchor spacing limits (px): the probe grid and the coarsest grid.
PSF_MIN_SPACING_PX = 8
PSF_MAX_SPACING_PX = 64
#: Kernels are cut at this many sigma of each axis (about 1e-4 of the mass lies beyond).
PSF_TRUNCATE_SIGMA = 4.0
#: Widths below this (px) are a sharp image (the sampled kernel is a delta).
PSF_MIN_SIGMA_PX = 0.05
#: OpenCV 5 filters take at most 128 channels (CV_CN_MAX); larger stacks go in chunks.
CV_MAX_CHANNELS = 128

#: Per-pixel PSF of a field: (x, y) window pixels -> (sigma_radial, sigma_tangential, radial
#: direction angle in rad), each shaped like x.
PsfField = Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray, np.ndarray]]


# --- Field geometry ---------------------------------------------------------------------------


@lru_cache(maxsize=8)
def field_angles(
    lens: FisheyeCamera, origin_px: tuple[int, int], shape: tuple[int, int]
) -> tuple[np.ndarray, np.ndarray]:
    """(theta_rad float32, inside bool) of a crop's pixel centres, (H, W) each, read-only, cached.

    ``inside`` is the image circle, theta <= theta_max; a pixel the lens model cannot reach has
    theta = inf (so field tables hold their last value there).
    """
    x0, y0 = origin_px
    height, width = shape
    xs = np.arange(x0, x0 + width, dtype=float)
    ys = np.arange(y0, y0 + height, dtype=float)
    theta = np.asarray(lens.theta_of_pixel(np.stack(np.meshgrid(xs, ys), axis=-1)), dtype=float)
    theta = np.where(np.isnan(theta), np.inf, theta)
    inside = theta <= lens.theta_max_rad
    theta = theta.astype(np.float32)
    for a in (theta, inside):
        a.flags.writeable = False
    return theta, inside


def relative_illumination(stack: np.ndarray, factor: np.ndarray) -> np.ndarray:
    """Irradiance times the (H, W) fall-off ``factor`` (1 on the axis)."""
    return stack * factor.astype(np.float32)[..., None]


def image_circle(stack: np.ndarray, inside: np.ndarray) -> np.ndarray:
    """No light outside the image circle: 0 where ``inside`` (H, W) is False."""
    return stack * inside.astype(np.float32)[..., None]


# --- Point-spread function --------------------------------------------------------------------


def covariance(sigma_r: np.ndarray, sigma_t: np.ndarray, angle_rad: np.ndarray) -> np.ndarray:
    """(..., 3) covariance entries (xx, yy, xy), px^2, of ``R diag(sigma_r^2, sigma_t^2) R^T``
    with R rotating x onto the radial direction at ``angle_rad``."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    r2, t2 = np.square(sigma_r), np.square(sigma_t)
    return np.stack([r2 * c * c + t2 * s * s, r2 * s * s + t2 * c * c, (r2 - t2) * c * s], -1)


def covariance_kernel(cov: np.ndarray) -> np.ndarray:
    """Normalized Gaussian of covariance (xx, yy, xy) sampled at integer offsets, float32,
    (2ry+1, 2rx+1): cut at ``PSF_TRUNCATE_SIGMA`` sigma of each axis's marginal."""
    a, b, c = (float(v) for v in cov)
    floor2 = PSF_MIN_SIGMA_PX**2
    if max(a, b) < floor2:
        return np.ones((1, 1), np.float32)
    if a * b - c * c < floor2 * max(a, b):  # a zero width (a line kernel): keep it invertible
        a, b = a + floor2, b + floor2
    rx = math.ceil(PSF_TRUNCATE_SIGMA * math.sqrt(a))
    ry = math.ceil(PSF_TRUNCATE_SIGMA * math.sqrt(b))
    dx = np.arange(-rx, rx + 1, dtype=float)[None, :]
    dy = np.arange(-ry, ry + 1, dtype=float)[:, None]
    k = np.exp(-0.5 * (b * dx * dx - 2.0 * c * dx * dy + a * dy * dy) / (a * b - c * c))
    return (k / k.sum()).astype(np.float32)


def gaussian_kernel(sigma_r: float, sigma_t: float, angle_rad: float) -> np.ndarray:
    """The sampled anisotropic Gaussian of widths ``sigma_r`` (radial), ``sigma_t``."""
    return covariance_kernel(covariance(sigma_r, sigma_t, angle_rad))


def anchor_axis(length: int, spacing: int) -> np.ndarray:
    """Anchor positions 0 .. length-1 along one axis, at most ``spacing`` apart, both ends in."""
    segments = max(1, math.ceil((length - 1) / spacing))
    return np.unique(np.rint(np.linspace(0, length - 1, segments + 1)).astype(int))


def anchor_spacing(shape: tuple[int, int], field: PsfField) -> int | None:
    """Anchor spacing (px) for the field over a crop of ``shape``; 0 if one kernel fits all,
    None if the PSF is below :data:`PSF_MIN_SIGMA_PX` everywhere (nothing to do)."""
    xs = anchor_axis(shape[1], PSF_MIN_SPACING_PX)
    ys = anchor_axis(shape[0], PSF_MIN_SPACING_PX)
    gx, gy = np.meshgrid(xs, ys)
    sr, st, angle = field(gx, gy)
    sigma = np.maximum(sr, st)
    if sigma.max() < PSF_MIN_SIGMA_PX:
        return None
    cov = covariance(sr, st, angle)
    # Width change between probe neighbours: d(sigma^2) / (2 sigma), sigma floored at 0.5 px.
    scale = 2.0 * np.maximum(sigma, 0.5)[..., None]
    step = 0.0
    if cov.shape[1] > 1:
        step = max(step, float(np.max(np.abs(np.diff(cov, axis=1)) / scale[:, 1:])))
    if cov.shape[0] > 1:
        step = max(step, float(np.max(np.abs(np.diff(cov, axis=0)) / scale[1:])))
    if step < 1e-9:
        return 0
    probe = float(np.max(np.diff(xs))) if len(xs) > 1 else float(PSF_MIN_SPACING_PX)
    if len(ys) > 1:
        probe = max(probe, float(np.max(np.diff(ys))))
    spacing = probe * PSF_STEP_PX / step
    return int(np.clip(spacing, PSF_MIN_SPACING_PX, PSF_MAX_SPACING_PX))


def _cells(axis: np.ndarray, length: int) -> list[tuple[int, int, int, int]]:
    """(lo, hi, k0, k1): pixels lo..hi-1 between anchors k0 and k1 (the last cell keeps its end)."""
    if len(axis) == 1:
        return [(0, length, 0, 0)]
    last = len(axis) - 2
    return [
        (int(axis[k]), int(axis[k + 1]) if k < last else length, k, k + 1) for k in range(last + 1)
    ]


def _chunked(image: np.ndarray, fn: Callable[[np.ndarray], np.ndarray]) -> np.ndarray:
    """``fn`` over an (H, W, C) image in chunks of at most CV_MAX_CHANNELS channels."""
    out = np.empty_like(image)
    for start in range(0, image.shape[-1], CV_MAX_CHANNELS):
        chunk = np.ascontiguousarray(image[..., start : start + CV_MAX_CHANNELS])
        out[..., start : start + CV_MAX_CHANNELS] = fn(chunk).reshape(chunk.shape)
    return out


def _filter(image: np.ndarray, kernel: np.ndarray) -> np.ndarray:
    """filter2D (correlation; the kernel is symmetric) with edge replication, any channel count."""
    if kernel.size == 1:
        return image
    return _chunked(image, lambda c: cv2.filter2D(c, -1, kernel, borderType=cv2.BORDER_REPLICATE))


def _ring_blur(padded: np.ndarray, rows: slice, cols: slice, kernel: np.ndarray) -> np.ndarray:
    """Blur of the cell ``rows`` x ``cols`` plus a one-pixel ring, from the image ``padded`` by
    one replicated pixel on each side: (h + 2, w + 2, C)."""
    height, width = padded.shape[:2]
    ry, rx = kernel.shape[0] // 2, kernel.shape[1] // 2
    sy0, sy1 = max(0, rows.start - ry), min(height, rows.stop + 2 + ry)
    sx0, sx1 = max(0, cols.start - rx), min(width, cols.stop + 2 + rx)
    blur = _filter(padded[sy0:sy1, sx0:sx1], kernel)
    return blur[rows.start - sy0 : rows.stop + 2 - sy0, cols.start - sx0 : cols.stop + 2 - sx0]


def _bilinear(corners: np.ndarray, v: np.ndarray, u: np.ndarray) -> np.ndarray:
    """(len(v), len(u), K) bilinear blend of corner values (2, 2, K) at fractions v (rows), u."""
    top = corners[0, 0] + u[:, None] * (corners[0, 1] - corners[0, 0])
    bottom = corners[1, 0] + u[:, None] * (corners[1, 1] - corners[1, 0])
    return top[None] + v[:, None, None] * (bottom - top)[None]


@dataclass(frozen=True)
class PsfPlan:
    """Everything of a PSF field over one crop that does not depend on the image: the cells,
    their kernels and each pixel's first-order weights. Built once per (field, crop) by
    :func:`psf_plan` and applied to every image of that crop (a video's frames, a study's draws).

    ``cells``: (rows, columns, kernel) of each cell, or one cell over the whole crop for a
    uniform field. ``weights``: None for a uniform field, else (4, H, W, 1) float32: the centre
    weight 1 - 2 (hx + hy), then hx, hy (half the covariance's xx, yy deviation from the cell's
    kernel) and q (a quarter of its xy deviation), the heat-equation stencil's coefficients.
    """

    shape: tuple[int, int]
    cells: tuple[tuple[slice, slice, np.ndarray], ...]
    weights: np.ndarray | None

    def apply(self, stack: np.ndarray) -> np.ndarray:
        """The PSF applied to an (N, H, W, C) float32 stack (see the module docstring)."""
        n, height, width, channels = stack.shape
        if (height, width) != self.shape:
            raise ValueError(f"stack of {height} x {width} px; the plan is for {self.shape}")
        hwc = np.ascontiguousarray(np.moveaxis(stack, 0, 2).reshape(height, width, n * channels))
        uniform = self.weights is None  # one kernel everywhere
        out = _filter(hwc, self.cells[0][2]) if uniform else self._varying(hwc)
        np.maximum(out, 0.0, out=out)  # FFT-based convolution leaves rounding-level negatives
        out = out.reshape(height, width, n, channels)
        return np.ascontiguousarray(np.moveaxis(out, 2, 0))

    def _varying(self, hwc: np.ndarray) -> np.ndarray:
        """Each cell blurred once with its kernel; the stencil's neighbour sums gathered cell by
        cell, then weighted over the whole crop (in the order the per-cell sum used)."""
        padded = np.pad(hwc, ((1, 1), (1, 1), (0, 0)), mode="edge")
        mid, across, along, diagonal = (np.empty_like(hwc) for _ in range(4))
        for rows, cols, kernel in self.cells:
            b = _ring_blur(padded, rows, cols, kernel)
            mid[rows, cols] = b[1:-1, 1:-1]
            np.add(b[1:-1, 2:], b[1:-1, :-2], out=across[rows, cols])
            np.add(b[2:, 1:-1], b[:-2, 1:-1], out=along[rows, cols])
            d = diagonal[rows, cols]
            np.subtract(b[2:, 2:], b[2:, :-2], out=d)
            d -= b[:-2, 2:]
            d += b[:-2, :-2]
        centre, hx, hy, q = self.weights
        out = mid * centre
        across *= hx
        along *= hy
        across += along
        out += across
        diagonal *= q
        out += diagonal
        return out


def psf_plan(shape: tuple[int, int], field: PsfField) -> PsfPlan | None:
    """The plan of ``field`` over a crop of ``shape`` (H, W); None if the PSF is below
    :data:`PSF_MIN_SIGMA_PX` everywhere (nothing to do)."""
    height, width = shape
    spacing = anchor_spacing(shape, field)
    if spacing is None:
        return None
    if spacing == 0:
        cov = covariance(*field(np.zeros(1, int), np.zeros(1, int)))[0]
        whole = (slice(0, height), slice(0, width), covariance_kernel(cov))
        return PsfPlan((height, width), (whole,), None)
    xs, ys = anchor_axis(width, spacing), anchor_axis(height, spacing)
    cov = covariance(*field(*np.meshgrid(xs, ys)))  # (ny, nx, 3) at the anchors
    cells = []
    weights = np.empty((4, height, width, 1), np.float32)
    for y_lo, y_hi, i0, i1 in _cells(ys, height):
        v = (np.arange(y_lo, y_hi) - ys[i0]) / max(1, ys[i1] - ys[i0])
        for x_lo, x_hi, j0, j1 in _cells(xs, width):
            u = (np.arange(x_lo, x_hi) - xs[j0]) / max(1, xs[j1] - xs[j0])
            corners = cov[[[i0, i0], [i1, i1]], [[j0, j1], [j0, j1]]]  # (2, 2, 3)
            centre = corners.mean(axis=(0, 1))
            rows, cols = slice(y_lo, y_hi), slice(x_lo, x_hi)
            cells.append((rows, cols, covariance_kernel(centre)))
            # Each pixel's own covariance is bilinear between the anchors; to first order
            # d(blur)/d(Sigma_ij) = 1/2 d_i d_j blur (heat equation), by central differences.
            d = (_bilinear(corners, v, u) - centre).astype(np.float32)
            hx, hy, q = 0.5 * d[..., 0:1], 0.5 * d[..., 1:2], 0.25 * d[..., 2:3]
            weights[:, rows, cols] = (1.0 - 2.0 * (hx + hy), hx, hy, q)
    for a in (weights, *(c[2] for c in cells)):
        a.flags.writeable = False
    return PsfPlan((height, width), tuple(cells), weights)


@lru_cache(maxsize=4)
def lens_psf_plan(
    psf: PsfTable, lens: FisheyeCamera, origin_px: tuple[int, int], shape: tuple[int, int]
) -> PsfPlan | None:
    """:func:`psf_plan` of a lens's PSF table over a crop, cached: every image of the crop
    reuses it (a band's plan holds 16 bytes per pixel)."""
    return psf_plan(shape, lens_psf_field(psf.at, lens, origin_px))


def lens_psf_field(
    sigma_at_theta: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]],
    lens: FisheyeCamera,
    origin_px: tuple[int, int],
) -> PsfField:
    """A lens's PSF field over a crop: widths at each pixel's field angle, radial direction from
    the principal point (cx, cy); ``sigma_at_theta`` maps theta (deg) to (radial, tangential)."""
    x0, y0 = origin_px

    def field(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        px = np.stack([x + x0, y + y0], axis=-1).astype(float)
        theta = np.asarray(lens.theta_of_pixel(px), dtype=float)
        theta = np.where(np.isfinite(theta), theta, lens.theta_max_rad)
        sr, st = sigma_at_theta(np.degrees(theta))
        angle = np.arctan2(px[..., 1] - lens.cy_px, px[..., 0] - lens.cx_px)
        return np.asarray(sr, float), np.asarray(st, float), angle

    return field


# --- Lateral colour ---------------------------------------------------------------------------


#: A channel's resampling maps: (channel index, map_x (H, W) float32, map_y (H, W) float32).
ChannelMaps = tuple[int, np.ndarray, np.ndarray]


def radial_maps(
    scale: np.ndarray, centre_px: tuple[float, float], origin_px: tuple[int, int]
) -> tuple[np.ndarray, np.ndarray]:
    """(map_x, map_y) (H, W) float32 crop pixels that pixel p reads, c + (p - c) / scale(p).

    ``scale`` (H, W) is the channel's image scale relative to green; ``centre_px`` the principal
    point and ``origin_px`` the crop's origin, in full-frame pixels.
    """
    height, width = scale.shape
    cx, cy = centre_px[0] - origin_px[0], centre_px[1] - origin_px[1]
    inverse = (1.0 / scale).astype(np.float32)
    map_x = np.float32(cx) + (np.arange(width, dtype=np.float32) - np.float32(cx)) * inverse
    map_y = (
        np.float32(cy) + (np.arange(height, dtype=np.float32)[:, None] - np.float32(cy)) * inverse
    )
    return map_x, map_y


def radial_remap(stack: np.ndarray, map_x: np.ndarray, map_y: np.ndarray) -> np.ndarray:
    """Resample (N, H, W) images at the :func:`radial_maps`: bicubic (OpenCV takes at most 4
    channels at a time for it), edges replicated, negative overshoot clipped to 0."""
    n = stack.shape[0]
    hwc = np.moveaxis(stack, 0, -1)
    out = np.empty_like(hwc)
    for start in range(0, n, 4):
        chunk = np.ascontiguousarray(hwc[..., start : start + 4])
        res = cv2.remap(chunk, map_x, map_y, cv2.INTER_CUBIC, borderMode=cv2.BORDER_REPLICATE)
        out[..., start : start + 4] = res.reshape(chunk.shape)
    np.maximum(out, 0.0, out=out)
    return np.moveaxis(out, -1, 0)


@lru_cache(maxsize=4)
def lateral_colour_maps(
    table: LateralColour, lens: FisheyeCamera, origin_px: tuple[int, int], shape: tuple[int, int]
) -> tuple[ChannelMaps, ...]:
    """The maps of red (channel 0) and blue (2) over a crop, those whose scale is not 1
    everywhere; cached, as every image of the crop reuses them."""
    theta, _ = field_angles(lens, origin_px, shape)
    red, blue = table.at(np.degrees(theta))
    maps = []
    for channel, scale in ((0, red), (2, blue)):
        if np.any(scale != 1.0):
            map_x, map_y = radial_maps(scale, (lens.cx_px, lens.cy_px), origin_px)
            for a in (map_x, map_y):
                a.flags.writeable = False
            maps.append((channel, map_x, map_y))
    return tuple(maps)


def lateral_colour(stack: np.ndarray, maps: tuple[ChannelMaps, ...]) -> np.ndarray:
    """An (N, H, W, 3) RGB stack with red and blue rescaled about the principal point by their
    :func:`lateral_colour_maps`; green stays."""
    out = stack.copy()
    for channel, map_x, map_y in maps:
        out[..., channel] = radial_remap(stack[..., channel], map_x, map_y)
    return out
