"""Camera/sensor response: clean linear radiance in, the 8-bit images of a real camera out.

A renderer produces one clean luminance image (float, linear, 1.0 = full scale of the sensor at
exposure 1). The real fisheye camera adds lens and sensor effects the marker pipeline has to cope
with; this module adds them, drawing many noisy images from one clean render so that noise
statistics cost no extra rendering. Everything is vectorized over the batch of N images.

Stages, in order (the physical order of a camera):

1. **exposure**: ``exposed = radiance * exposure``; with ``exposure="auto"`` the multiplier is
   chosen so the mean of the metered (``valid``) pixels of the clean radiance is ``auto_target``
   of full scale (one multiplier for the whole batch, see :func:`exposure_for`). Pixels outside
   ``valid`` are set to 0 (no light outside the image circle).
2. **vignetting**: relative illumination ``max(0, 1 - vignetting * (theta / theta_max)**2)``.
3. **lens blur**: Gaussian, sigma growing from ``blur_sigma_centre_px`` on the axis to
   ``blur_sigma_edge_px`` at ``theta_max`` as ``(theta / theta_max)**2``. Computed by blurring at
   sigma levels 0.25 px apart (32 at most) and interpolating linearly per pixel by its sigma;
   one blur when the sigma is uniform.
4. **shot noise**: photo-electrons ``~ Poisson(exposed * full_well_e)``, the well clipping at
   ``full_well_e``. Exact Poisson below 100 e-; above, the Gaussian limit (skewness < 0.1).
5. **read noise**: Gaussian, ``read_noise_e`` rms, then the signal clipped to [0, 1] full scale.
6. **transfer curve**: sRGB (IEC 61966-2-1) or linear.
7. **quantization** to 8 bits, rounding to nearest (via a 65536-entry table of the curve: exact
   except within 1/131070 of full scale of a rounding threshold, where it may be one code off).
8. **JPEG** (optional): each image encoded and decoded as the camera's MJPEG stream would be.

Finally pixels outside ``valid`` are 0 in the output.

Steps 1-3 run once per clean image; noise is drawn per output image. Gaussian deviates come from
a 65536-entry inverse-CDF table indexed by uniform 16-bit integers from the caller's generator:
about 4x faster than ``Generator.standard_normal``, exact at every 1/65536 quantile (tails
truncated at 4.3 sigma, variance normalized to 1). Output is deterministic for a given rng state.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from functools import cache
from statistics import NormalDist

import cv2
import numpy as np

GAMMAS = ("srgb", "linear")
#: Rec. 709 / sRGB luminance weights: the camera response works on the grey the detector sees.
LUMINANCE_RGB = np.array([0.2126, 0.7152, 0.0722])

#: Below this many expected electrons shot noise is drawn exactly from a Poisson distribution.
POISSON_EXACT_BELOW_E = 100.0
#: Largest spacing of the sigma levels used for the spatially varying blur (px).
BLUR_LEVEL_STEP_PX = 0.25
_MAX_BLUR_LEVELS = 32
_CV_MAX_CHANNELS = 512
_LUT_SIZE = 65536  # linear signal -> 8-bit code table; indices are uint16


def _is_number(value: object) -> bool:
    return isinstance(value, int | float | np.integer | np.floating) and not isinstance(
        value, bool | np.bool_
    )


@dataclass(frozen=True)
class CameraResponse:
    """Lens and sensor parameters turning clean radiance into camera images."""

    exposure: float | str = 1.0
    auto_target: float = 0.18
    full_well_e: float = 6000.0
    read_noise_e: float = 3.0
    vignetting: float = 0.0
    blur_sigma_centre_px: float = 0.0
    blur_sigma_edge_px: float = 0.0
    gamma: str = "srgb"
    jpeg_quality: int | None = None

    def __post_init__(self) -> None:
        e = self.exposure
        if isinstance(e, str):
            if e != "auto":
                raise ValueError(f"exposure={e!r}: must be > 0 or 'auto'")
        elif not (_is_number(e) and math.isfinite(e) and e > 0):
            raise ValueError(f"exposure={e!r}: must be > 0 or 'auto'")
        t = self.auto_target
        if not (_is_number(t) and 0.0 < t <= 1.0):
            raise ValueError(f"auto_target={t!r}: allowed range is (0, 1] of full scale")
        fw = self.full_well_e
        if not (_is_number(fw) and math.isfinite(fw) and fw > 0):
            raise ValueError(f"full_well_e={fw!r}: must be a finite number > 0 (electrons)")
        for name in ("read_noise_e", "vignetting", "blur_sigma_centre_px", "blur_sigma_edge_px"):
            value = getattr(self, name)
            if not (_is_number(value) and math.isfinite(value) and value >= 0):
                raise ValueError(f"{name}={value!r}: must be a finite number >= 0")
        if self.gamma not in GAMMAS:
            raise ValueError(f"gamma={self.gamma!r}: must be one of {', '.join(GAMMAS)}")
        q = self.jpeg_quality
        if q is not None and not (
            isinstance(q, int | np.integer) and not isinstance(q, bool) and 1 <= q <= 100
        ):
            raise ValueError(f"jpeg_quality={q!r}: must be None or an integer in 1..100")

    def scaled(self, factor: float) -> CameraResponse:
        """This response with a fixed exposure multiplied by ``factor`` (a lighting preset's
        own exposure); ``"auto"`` meters the scene itself and stays as it is."""
        if self.exposure == "auto":
            return self
        return replace(self, exposure=self.exposure * factor)

    @property
    def blur_on(self) -> bool:
        return self.blur_sigma_centre_px > 0 or self.blur_sigma_edge_px > 0

    @property
    def needs_theta(self) -> bool:
        """Vignetting and a spatially varying blur depend on each pixel's ray angle."""
        return self.vignetting > 0 or self.blur_sigma_centre_px != self.blur_sigma_edge_px


# --- Input checks ---------------------------------------------------------------------------


def _as_clean_stack(radiance: np.ndarray) -> np.ndarray:
    """(N, H, W) float32 >= 0 view/copy of a (H, W) or (N, H, W) radiance array."""
    r = np.asarray(radiance)
    if r.ndim not in (2, 3) or r.size == 0:
        raise ValueError(f"radiance: shape {r.shape}; expected a non-empty (H, W) or (N, H, W)")
    if not np.issubdtype(r.dtype, np.number) or np.iscomplexobj(r):
        raise ValueError(f"radiance: dtype {r.dtype}; expected real numbers")
    r = r.astype(np.float32, copy=False)
    if r.ndim == 2:
        r = r[None]
    if not np.isfinite(r).all():
        raise ValueError("radiance: contains NaN or inf")
    return np.maximum(r, 0.0)  # a renderer's tiny negative values are no light


def _check_map(name: str, arr: np.ndarray | None, shape: tuple[int, int]) -> np.ndarray | None:
    if arr is None:
        return None
    a = np.asarray(arr)
    if a.shape != shape:
        raise ValueError(f"{name}: shape {a.shape}; must match the image, {shape}")
    return a


# --- Exposure -------------------------------------------------------------------------------


def _exposure(clean: np.ndarray, response: CameraResponse, valid: np.ndarray | None) -> float:
    if response.exposure != "auto":
        return float(response.exposure)
    metered = clean[:, valid] if valid is not None else clean
    if metered.size == 0:
        raise ValueError("exposure='auto': no valid pixels to meter")
    mean = float(np.mean(metered, dtype=np.float64))
    if not mean > 0:
        raise ValueError("exposure='auto': the metered pixels are all black; cannot meter")
    return response.auto_target / mean


def exposure_for(
    radiance: np.ndarray, response: CameraResponse, valid: np.ndarray | None = None
) -> float:
    """The exposure multiplier :func:`apply_response` uses, for recording in a manifest.

    The fixed ``response.exposure``, or for ``"auto"`` ``auto_target / mean`` of the clean
    radiance over the ``valid`` pixels of all images in the batch (one exposure for the batch).
    """
    clean = _as_clean_stack(radiance)
    valid_map = _check_map("valid", valid, clean.shape[1:])
    return _exposure(clean, response, None if valid_map is None else valid_map.astype(bool))


# --- Optics ---------------------------------------------------------------------------------


def _gaussian_blur(stack: np.ndarray, sigma: float) -> np.ndarray:
    """Blur each image of an (N, H, W) stack; images travel as channels (at most 512 per call)."""
    if sigma <= 0:
        return stack
    hwc = np.ascontiguousarray(np.moveaxis(stack, 0, -1))
    out = np.empty_like(hwc)
    for start in range(0, hwc.shape[-1], _CV_MAX_CHANNELS):
        chunk = np.ascontiguousarray(hwc[..., start : start + _CV_MAX_CHANNELS])
        blurred = cv2.GaussianBlur(chunk, (0, 0), sigmaX=sigma, sigmaY=sigma)
        out[..., start : start + _CV_MAX_CHANNELS] = blurred.reshape(chunk.shape)
    return np.moveaxis(out, -1, 0)


def _varying_blur(stack: np.ndarray, sigma_map: np.ndarray) -> np.ndarray:
    """Blur with a per-pixel sigma: blurs at sigma levels, blended linearly per pixel."""
    lo, hi = float(sigma_map.min()), float(sigma_map.max())
    if hi - lo < 1e-6:
        return _gaussian_blur(stack, lo)
    n_levels = min(_MAX_BLUR_LEVELS, max(2, math.ceil((hi - lo) / BLUR_LEVEL_STEP_PX) + 1))
    levels = np.linspace(lo, hi, n_levels)
    pos = (sigma_map - lo) / (levels[1] - levels[0])  # fractional level index per pixel
    out = np.zeros_like(stack)
    for k, sigma in enumerate(levels):
        weight = np.clip(1.0 - np.abs(pos - k), 0.0, None).astype(np.float32)
        if weight.any():
            out += weight * _gaussian_blur(stack, float(sigma))
    return out


def _optics(
    clean: np.ndarray,
    response: CameraResponse,
    theta_rad: np.ndarray | None,
    theta_max_rad: float | None,
) -> np.ndarray:
    """Vignetting then lens blur on the exposed clean stack."""
    rel2 = None
    if response.needs_theta:
        if theta_rad is None or theta_max_rad is None:
            raise ValueError(
                "theta_rad and theta_max_rad are required when vignetting or a varying blur is on"
            )
        if not (math.isfinite(theta_max_rad) and theta_max_rad > 0):
            raise ValueError(f"theta_max_rad={theta_max_rad!r}: must be a finite number > 0")
        rel2 = np.square(np.asarray(theta_rad, dtype=np.float64) / theta_max_rad)
    if response.vignetting > 0:
        illum = np.clip(1.0 - response.vignetting * rel2, 0.0, None).astype(np.float32)
        clean = clean * illum
    if response.blur_on:
        c, e = response.blur_sigma_centre_px, response.blur_sigma_edge_px
        if c == e:
            clean = _gaussian_blur(clean, c)
        else:
            clean = _varying_blur(clean, c + (e - c) * np.minimum(rel2, 1.0))
    return clean


# --- Sensor ---------------------------------------------------------------------------------


@cache
def _normal_table() -> np.ndarray:
    """Standard normal quantiles at the 65536 cell midpoints, variance normalized to 1."""
    nd = NormalDist()
    half = np.array([nd.inv_cdf((i + 0.5) / 65536.0) for i in range(32768)])
    table = np.concatenate([half, -half[::-1]])
    table /= np.sqrt(np.mean(np.square(table)))
    table = table.astype(np.float32)
    table.flags.writeable = False
    return table


def _srgb_encode(x: np.ndarray) -> np.ndarray:
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1.0 / 2.4) - 0.055)


@cache
def _code_lut(gamma: str) -> np.ndarray:
    """8-bit code of linear ``i / 65535`` after the transfer curve, for i in 0..65535."""
    x = np.arange(_LUT_SIZE) / (_LUT_SIZE - 1)
    lut = np.rint(255.0 * (x if gamma == "linear" else _srgb_encode(x))).astype(np.uint8)
    lut.flags.writeable = False
    return lut


def _quantize(x: np.ndarray, gamma: str) -> np.ndarray:
    """uint8 codes of linear x (float32, overwritten): clip to [0, 1], transfer curve, round."""
    np.clip(x, 0.0, 1.0, out=x)
    x *= np.float32(_LUT_SIZE - 1)
    x += np.float32(0.5)
    return _code_lut(gamma).take(x.astype(np.uint16))


def _sensor(
    clean: np.ndarray, response: CameraResponse, rng: np.random.Generator, n_out: int
) -> np.ndarray:
    """Shot noise, well clipping, read noise; linear signal in full-scale units, (n_out, H, W)."""
    fw = float(response.full_well_e)
    read = response.read_noise_e > 0
    table = _normal_table()
    draws = rng.integers(0, _LUT_SIZE, size=(1 + read, n_out, *clean.shape[1:]), dtype=np.uint16)
    # Gaussian limit of shot noise, in full-scale units: sd = sqrt(e) / fw = sqrt(clean / fw).
    x = table.take(draws[0])
    x *= np.sqrt(clean * np.float32(1.0 / fw))
    x += clean
    # Exact Poisson where few electrons are expected (same pixels in every image of the batch).
    lam = clean * np.float32(fw)
    low = (lam > 0) & (lam < POISSON_EXACT_BELOW_E)
    if low.any():
        if clean.shape[0] == 1:
            lam_low = lam[0][low[0]]
            x[:, low[0]] = rng.poisson(lam_low, size=(n_out, lam_low.size)) / fw
        else:
            x[low] = rng.poisson(lam[low]) / fw
    np.minimum(x, np.float32(1.0), out=x)  # the well is full at full scale
    if read:
        x += (table * np.float32(response.read_noise_e / fw)).take(draws[1])
    return x


def _jpeg(images: np.ndarray, quality: int) -> np.ndarray:
    out = np.empty_like(images)
    for i, img in enumerate(images):
        ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
        if not ok:
            raise RuntimeError("JPEG encoding failed")
        out[i] = cv2.imdecode(buf, cv2.IMREAD_GRAYSCALE)
    return out


def apply_response(
    radiance: np.ndarray,
    response: CameraResponse,
    rng: np.random.Generator,
    n_images: int = 1,
    theta_rad: np.ndarray | None = None,
    theta_max_rad: float | None = None,
    valid: np.ndarray | None = None,
) -> np.ndarray:
    """Camera images (uint8, (N, H, W)) from clean linear radiance; stages in the module docstring.

    ``radiance`` is (H, W), from which ``n_images`` noisy images are drawn, or (N, H, W), N clean
    images (e.g. different shadows) giving one image each; ``n_images`` is then 1 or N.
    ``theta_rad`` (H, W) and ``theta_max_rad`` are required for vignetting or a varying blur.
    ``valid`` (H, W) bool marks the image circle: outside is black and not metered.
    """
    clean = _as_clean_stack(radiance)
    if not (isinstance(n_images, int | np.integer) and not isinstance(n_images, bool)):
        raise ValueError(f"n_images={n_images!r}: must be an integer >= 1")
    n_clean, height, width = clean.shape
    if np.asarray(radiance).ndim == 3:
        if n_images not in (1, n_clean):
            raise ValueError(
                f"n_images={n_images}: must be 1 or N={n_clean} for an (N, H, W) radiance stack"
            )
        n_out = n_clean
    else:
        if n_images < 1:
            raise ValueError(f"n_images={n_images}: must be an integer >= 1")
        n_out = int(n_images)
    theta = _check_map("theta_rad", theta_rad, (height, width))
    valid_map = _check_map("valid", valid, (height, width))
    if valid_map is not None:
        valid_map = valid_map.astype(bool, copy=False)

    exposure = _exposure(clean, response, valid_map)
    clean = clean * np.float32(exposure)
    if valid_map is not None:
        clean[:, ~valid_map] = 0.0
    clean = _optics(clean, response, theta, theta_max_rad)
    signal = _sensor(clean, response, rng, n_out)
    images = _quantize(signal, response.gamma)
    if response.jpeg_quality is not None:
        images = _jpeg(images, response.jpeg_quality)
    if valid_map is not None:
        images[:, ~valid_map] = 0
    return images
