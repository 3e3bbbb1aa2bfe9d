"""The sensor and the camera's processing: photosites, read-out, demosaicing, transfer, sharpening.

Input is the irradiance on the sensor in full-scale units (1.0 fills a photosite's well at
exposure 1); output is the camera's 8-bit image. Everything works on a batch of N images.

Sensor
    A colour sensor samples one channel per photosite through its Bayer colour filter array
    (:func:`mosaic`); a grey sensor (``cfa="none"``) sees the Rec. 709 luminance. Each photosite
    collects Poisson photo-electrons plus the dark signal, clips at the full well, has the mean dark
    signal subtracted (black-level correction: its shot noise stays) and gains Gaussian read noise
    (:func:`photosite_signal`). A colour sensor digitizes with a 12-bit ADC (MT9P001 datasheet:
    12-bit ADC); the grey sensor is the ideal profile's camera (the project's camera before the
    twin), whose signal goes straight through the transfer curve to 8 bits.

Processing
    OpenCV's demosaicing (bilinear, edge-aware or VNG) on the 12-bit codes, then the transfer curve
    (sRGB, IEC 61966-2-1, or linear) to 8 bits by table look-up, then an optional unsharp mask.
    OpenCV's VNG only takes 8-bit input, so for ``vng`` the twin applies the transfer curve to the
    mosaic first and VNG interpolates the 8-bit encoded values (bilinear and edge-aware interpolate
    the linear 12-bit codes, as a camera's processor does).

Gaussian deviates come from a 65536-entry inverse-CDF table indexed by uniform 16-bit integers:
about 4x faster than ``Generator.standard_normal``, exact at every 1/65536 quantile (tails cut at
4.3 sigma, variance normalized to 1). Output is deterministic for a given generator state.
"""

from __future__ import annotations

from functools import cache
from statistics import NormalDist

import cv2
import numpy as np

#: Rec. 709 / sRGB luminance weights: what a grey sensor (and the legacy response model) sees.
LUMINANCE_RGB = np.array([0.2126, 0.7152, 0.0722])
#: Below this many expected electrons shot noise is drawn exactly from a Poisson distribution;
#: above, from its Gaussian limit (skewness 1/sqrt(100) = 0.1 at the switch).
POISSON_EXACT_BELOW_E = 100.0
#: MT9P001 datasheet: 12-bit ADC.
ADC_BITS = 12
_TABLE_SIZE = 65536  # uniform uint16 draws; linear signal -> 8-bit code table for the grey sensor
_CHANNEL = {"R": 0, "G": 1, "B": 2}
#: OpenCV 5's Bayer codes named by the 2 x 2 tile at the image's top-left (checked by
#: tests/test_sensor.py: a flat colour mosaicked then demosaicked returns that colour).
_DEMOSAIC_CODES = {
    (pattern, method): getattr(cv2, f"COLOR_Bayer{pattern}2RGB{suffix}")
    for pattern in ("RGGB", "BGGR", "GRBG", "GBRG")
    for method, suffix in (("bilinear", ""), ("edge_aware", "_EA"), ("vng", "_VNG"))
}


# --- Colour filter array ----------------------------------------------------------------------


def crop_pattern(cfa: str, origin_px: tuple[int, int]) -> str:
    """The 2 x 2 pattern at the top-left of a crop at ``origin_px`` = (x0, y0) of the full frame,
    whose own top-left tile is ``cfa`` (e.g. RGGB at an odd x0 reads GRBG)."""
    x0, y0 = origin_px
    tile = [[cfa[0], cfa[1]], [cfa[2], cfa[3]]]
    return "".join(tile[(y0 + i) % 2][(x0 + j) % 2] for i in (0, 1) for j in (0, 1))


def mosaic(rgb: np.ndarray, cfa: str, origin_px: tuple[int, int]) -> np.ndarray:
    """Each photosite's own channel: (N, H, W, 3) float RGB -> (N, H, W), phase from the origin."""
    pattern = crop_pattern(cfa, origin_px)
    height, width = rgb.shape[1:3]
    out = np.empty(rgb.shape[:3], rgb.dtype)
    for i in (0, 1):
        for j in (0, 1):
            out[:, i::2, j::2] = rgb[:, i:height:2, j:width:2, _CHANNEL[pattern[2 * i + j]]]
    return out


# --- Photosites -------------------------------------------------------------------------------


@cache
def normal_table() -> np.ndarray:
    """Standard normal quantiles at the 65536 cell midpoints, variance normalized to 1."""
    nd = NormalDist()
    half = np.array([nd.inv_cdf((i + 0.5) / _TABLE_SIZE) for i in range(_TABLE_SIZE // 2)])
    table = np.concatenate([half, -half[::-1]])
    table /= np.sqrt(np.mean(np.square(table)))
    table = table.astype(np.float32)
    table.flags.writeable = False
    return table


def photosite_signal(
    expected: np.ndarray,
    full_well_e: float,
    read_noise_e: float,
    dark_signal_e: float,
    rng: np.random.Generator | None,
    n_out: int,
) -> np.ndarray:
    """Read-out signal in full-scale units, (n_out, H, W) float32, from the expected signal.

    ``expected`` is (1, H, W) (every output image drawn from it) or (n_out, H, W), float32 >= 0.
    Noise: Poisson electrons of ``expected * full_well_e + dark_signal_e`` (Gaussian limit from
    :data:`POISSON_EXACT_BELOW_E` up), well clipped, mean dark subtracted, read noise added; not
    clipped below 0 (the ADC or the transfer table does that). ``rng=None``: no noise at all.
    """
    fw = float(full_well_e)
    dark = np.float32(dark_signal_e / fw)
    mean = expected + dark if dark_signal_e > 0 else expected
    if rng is None:
        x = np.broadcast_to(mean, (n_out, *mean.shape[1:])).astype(np.float32)
        np.minimum(x, np.float32(1.0), out=x)
        if dark_signal_e > 0:
            x -= dark
        return x
    read = read_noise_e > 0
    table = normal_table()
    draws = rng.integers(0, _TABLE_SIZE, size=(1 + read, n_out, *mean.shape[1:]), dtype=np.uint16)
    # Gaussian limit of shot noise, in full-scale units: sd = sqrt(e) / fw = sqrt(mean / fw).
    x = table.take(draws[0])
    x *= np.sqrt(mean * np.float32(1.0 / fw))
    x += mean
    # Exact Poisson where few electrons are expected (same pixels in every image of the batch).
    lam = mean * np.float32(fw)
    low = (lam > 0) & (lam < POISSON_EXACT_BELOW_E)
    if low.any():
        if mean.shape[0] == 1:
            lam_low = lam[0][low[0]]
            x[:, low[0]] = rng.poisson(lam_low, size=(n_out, lam_low.size)) / fw
        else:
            x[low] = rng.poisson(lam[low]) / fw
    np.minimum(x, np.float32(1.0), out=x)  # the well is full at full scale
    if dark_signal_e > 0:
        x -= dark  # black-level correction removes the mean dark signal, not its noise
    if read:
        x += (table * np.float32(read_noise_e / fw)).take(draws[1])
    return x


def adc(signal: np.ndarray) -> np.ndarray:
    """12-bit codes (uint16, 0..4095) of a full-scale signal, rounding to nearest."""
    top = (1 << ADC_BITS) - 1
    x = np.clip(signal, 0.0, 1.0) * np.float32(top) + np.float32(0.5)
    return x.astype(np.uint16)


# --- Transfer curve ---------------------------------------------------------------------------


def _srgb_encode(x: np.ndarray) -> np.ndarray:
    """IEC 61966-2-1 sRGB encoding of linear x in [0, 1]."""
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1.0 / 2.4) - 0.055)


@cache
def transfer_lut(transfer: str, levels: int) -> np.ndarray:
    """8-bit code of linear ``i / (levels - 1)`` after the transfer curve, i in 0..levels-1."""
    x = np.arange(levels) / (levels - 1)
    lut = np.rint(255.0 * (x if transfer == "linear" else _srgb_encode(x))).astype(np.uint8)
    lut.flags.writeable = False
    return lut


def quantize(x: np.ndarray, transfer: str) -> np.ndarray:
    """uint8 codes of a linear signal (float32, overwritten): clip to [0, 1], curve, round.

    Through a 65536-entry table: exact except within 1/131070 of full scale of a rounding
    threshold, where it may be one code off. The grey sensor's path (no ADC).
    """
    np.clip(x, 0.0, 1.0, out=x)
    x *= np.float32(_TABLE_SIZE - 1)
    x += np.float32(0.5)
    return transfer_lut(transfer, _TABLE_SIZE).take(x.astype(np.uint16))


# --- Demosaicing and sharpening ---------------------------------------------------------------


def demosaic(mosaics: np.ndarray, pattern: str, method: str) -> np.ndarray:
    """RGB (N, H, W, 3) from Bayer mosaics (N, H, W) whose top-left tile is ``pattern``.

    uint16 or uint8 in, the same out; ``vng`` takes uint8 only (OpenCV's VNG is 8-bit).
    """
    if method == "vng" and mosaics.dtype != np.uint8:
        raise ValueError("demosaic='vng' needs 8-bit mosaics: apply the transfer curve first")
    code = _DEMOSAIC_CODES[(pattern, method)]
    return np.stack([cv2.cvtColor(m, code) for m in mosaics])


def sharpen(images: np.ndarray, amount: float, sigma_px: float) -> np.ndarray:
    """Unsharp mask of uint8 (N, H, W[, 3]) images: ``in + amount * (in - blur(in))``, rounded.

    One image at a time: OpenCV's blur and weighted sum on a small image beat one pass over the
    whole stack (7x on 100 images of 128 x 128 x 3).
    """
    out = np.empty_like(images)
    for i, image in enumerate(images):
        x = image.astype(np.float32)
        blurred = cv2.GaussianBlur(x, (0, 0), sigma_px, borderType=cv2.BORDER_REPLICATE)
        out[i] = cv2.addWeighted(x, 1.0 + amount, blurred, -amount, 0.0, dtype=cv2.CV_8U)
    return out
