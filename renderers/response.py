"""Camera/sensor response: clean linear luminance in, the 8-bit grey images of a camera out.

The grey-only camera model of the earlier studies, kept for its callers; it is a thin layer over
the camera twin's stages (:mod:`renderers.optics`, :mod:`renderers.sensor`,
:mod:`renderers.stream`), which :mod:`renderers.camera_twin` applies to colour radiance from a
camera profile. A renderer produces one clean luminance image (float, linear, 1.0 = full scale of
the sensor at exposure 1); many noisy images are drawn from it, vectorized over the batch.

Stages, in order (the physical order of a camera):

1. **exposure**: ``exposed = radiance * exposure``; with ``exposure="auto"`` the multiplier is
   chosen so the mean of the metered (``valid``) pixels of the clean radiance is ``auto_target``
   of full scale (one multiplier for the whole batch, see :func:`exposure_for`). Pixels outside
   ``valid`` are set to 0 (no light outside the image circle).
2. **vignetting**: relative illumination ``max(0, 1 - vignetting * (theta / theta_max)**2)``.
3. **lens blur**: isotropic Gaussian, sigma growing from ``blur_sigma_centre_px`` on the axis to
   ``blur_sigma_edge_px`` at ``theta_max`` as ``(theta / theta_max)**2``: the twin's
   field-dependent PSF (:func:`renderers.optics.apply_psf`), one convolution when uniform.
4. **shot noise**: photo-electrons ``~ Poisson(exposed * full_well_e)``, the well clipping at
   ``full_well_e``. Exact Poisson below 100 e-; above, the Gaussian limit (skewness < 0.1).
5. **read noise**: Gaussian, ``read_noise_e`` rms, then the signal clipped to [0, 1] full scale.
6. **transfer curve**: sRGB (IEC 61966-2-1) or linear.
7. **quantization** to 8 bits, rounding to nearest (via a 65536-entry table of the curve: exact
   except within 1/131070 of full scale of a rounding threshold, where it may be one code off).
8. **JPEG** (optional): each image encoded and decoded as the camera's MJPEG stream would be.

Finally pixels outside ``valid`` are 0 in the output. Steps 1-3 run once per clean image; noise
is drawn per output image (:func:`renderers.sensor.photosite_signal`). Output is deterministic
for a given rng state.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from renderers import optics, sensor, stream
from renderers.sensor import LUMINANCE_RGB
from scenes.profile import Stream

__all__ = ["GAMMAS", "LUMINANCE_RGB", "CameraResponse", "apply_response", "exposure_for"]

GAMMAS = ("srgb", "linear")


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


def _blur_field(response: CameraResponse, rel2: np.ndarray | None) -> optics.PsfField:
    """The isotropic blur as a PSF field: sigma from the centre value to the edge value."""
    c, e = response.blur_sigma_centre_px, response.blur_sigma_edge_px
    sigma = None if c == e else c + (e - c) * np.minimum(rel2, 1.0)

    def field(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        s = np.full(np.shape(x), c, dtype=float) if sigma is None else sigma[y, x]
        return s, s, np.zeros(np.shape(x))

    return field


def _optics(
    clean: np.ndarray,
    response: CameraResponse,
    theta_rad: np.ndarray | None,
    theta_max_rad: float | None,
) -> np.ndarray:
    """Vignetting then lens blur on the exposed clean (N, H, W, 1) stack."""
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
        clean = optics.relative_illumination(
            clean, np.clip(1.0 - response.vignetting * rel2, 0.0, None)
        )
    if response.blur_on:
        clean = optics.apply_psf(clean, _blur_field(response, rel2))
    return clean


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
    clean = (clean * np.float32(exposure))[..., None]
    if valid_map is not None:
        clean = optics.image_circle(clean, valid_map)
    clean = _optics(clean, response, theta, theta_max_rad)
    signal = sensor.photosite_signal(
        clean[..., 0], response.full_well_e, response.read_noise_e, 0.0, rng, n_out
    )
    images = sensor.quantize(signal, response.gamma)
    if response.jpeg_quality is not None:
        images = stream.grey_images(images, Stream(codec="mjpeg", quality=response.jpeg_quality))
    if valid_map is not None:
        images[:, ~valid_map] = 0
    return images
