"""The camera twin: a profile's optics, sensor, processing and stream applied to colour radiance.

The study and the dataset call three functions. :func:`optical_image` applies the deterministic
optics once per clean image; :func:`sensor_images` draws noisy images from its result (the costly
optics are reused by every draw); :func:`record` does both. Stages run in the camera's physical
order, :data:`STAGES`; any stage left out of ``stages`` is skipped, and a stage the profile leaves
off (no fall-off, no PSF, no lateral colour, a grey sensor, no sharpening, no MJPEG) costs nothing.
Without ``mosaic`` (or with ``cfa="none"``) the sensor is grey and sees the Rec. 709 luminance;
without ``demosaic`` a colour sensor's grey image is its raw mosaic, each pixel its own photosite.

Crops are windows of the full frame at ``origin_px`` = (x0, y0): the field angle of every pixel,
the Bayer phase and the MJPEG block grid all follow the full frame.

Example (per-stage cost, seconds per image, for docs/performance.md)::

    from scenes.profile import load_profile
    from renderers.camera_twin import stage_costs
    stage_costs(load_profile("prototype"), shape=(128, 128), n_images=100)
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterable, Iterator
from contextlib import contextmanager

import numpy as np

from renderers import optics, sensor, stream
from scenes.profile import CameraProfile

STAGES = (
    "relative_illumination",
    "image_circle",
    "psf",
    "lateral_colour",
    "mosaic",
    "noise",
    "demosaic",
    "transfer",
    "sharpen",
    "stream",
)

#: The optics stages that only scale each pixel: a renderer may apply them itself
#: (:func:`pixel_gain`) and leave them out of :func:`optical_image`'s ``stages``.
PIXEL_GAIN_STAGES = ("relative_illumination", "image_circle")

_costs: dict[str, float] | None = None  # seconds per stage while stage_costs() measures


@contextmanager
def _stage(name: str) -> Iterator[None]:
    if _costs is None:
        yield
        return
    t0 = time.perf_counter()
    yield
    _costs[name] = _costs.get(name, 0.0) + time.perf_counter() - t0


# --- Input checks -----------------------------------------------------------------------------


def _check_stages(stages: Iterable[str]) -> frozenset[str]:
    names = frozenset(stages) if not isinstance(stages, str) else frozenset([stages])
    unknown = sorted(names - set(STAGES))
    if unknown:
        raise ValueError(f"stages: unknown {unknown}; allowed: {', '.join(STAGES)}")
    return names


def _as_rgb_stack(image: np.ndarray, name: str) -> tuple[np.ndarray, bool]:
    """(N, H, W, 3) float32 >= 0 from (H, W, 3) or (N, H, W, 3); and whether it was one image."""
    a = np.asarray(image)
    if a.ndim not in (3, 4) or a.shape[-1] != 3 or a.size == 0:
        raise ValueError(f"{name}: shape {a.shape}; expected (H, W, 3) or (N, H, W, 3) linear RGB")
    if not np.issubdtype(a.dtype, np.number) or np.iscomplexobj(a):
        raise ValueError(f"{name}: dtype {a.dtype}; expected real numbers")
    a = a.astype(np.float32, copy=False)
    if not np.isfinite(a).all():
        raise ValueError(f"{name}: contains NaN or inf")
    single = a.ndim == 3
    return np.maximum(a[None] if single else a, 0.0), single  # tiny negative values are no light


def _check_origin(
    origin_px: tuple[int, int], shape: tuple[int, int], profile: CameraProfile
) -> tuple[int, int]:
    lens = profile.lens
    try:
        x0, y0 = (int(v) for v in origin_px)
        ok = (x0, y0) == tuple(origin_px) and x0 >= 0 and y0 >= 0
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise ValueError(f"origin_px={origin_px!r}: must be two integers >= 0 (x0, y0)")
    if x0 + shape[1] > lens.width_px or y0 + shape[0] > lens.height_px:
        raise ValueError(
            f"origin_px={origin_px!r}: a {shape[1]} x {shape[0]} crop there leaves the "
            f"{lens.width_px} x {lens.height_px} frame"
        )
    return x0, y0


def _n_out(stack: np.ndarray, single: bool, n_images: int) -> int:
    if not (isinstance(n_images, int | np.integer) and not isinstance(n_images, bool)):
        raise ValueError(f"n_images={n_images!r}: must be an integer >= 1")
    if single:
        if n_images < 1:
            raise ValueError(f"n_images={n_images}: must be an integer >= 1")
        return int(n_images)
    if n_images not in (1, len(stack)):
        raise ValueError(f"n_images={n_images}: must be 1 or N={len(stack)} for an (N, ...) stack")
    return len(stack)


# --- The stages -------------------------------------------------------------------------------


def optical_image(
    radiance: np.ndarray,
    profile: CameraProfile,
    origin_px: tuple[int, int] = (0, 0),
    stages: Iterable[str] = STAGES,
) -> np.ndarray:
    """The irradiance on the sensor after the optics stages, float32, shaped like ``radiance``.

    ``radiance``: (H, W, 3) or (N, H, W, 3) linear RGB at exposure 1 (1.0 = sensor full scale), a
    crop of the full frame at ``origin_px``. Stages: relative illumination (the profile's table at
    each pixel's field angle), image circle (0 beyond ``lens.theta_max``), PSF, lateral colour.
    """
    on = _check_stages(stages)
    stack, single = _as_rgb_stack(radiance, "radiance")
    shape = stack.shape[1:3]
    origin = _check_origin(origin_px, shape, profile)
    lens = profile.lens
    ri = "relative_illumination" in on and profile.relative_illumination.on
    lc = "lateral_colour" in on and profile.lateral_colour.on
    if ri or "image_circle" in on:
        theta, inside = optics.field_angles(lens, origin, shape)
    if ri:
        with _stage("relative_illumination"):
            factor = profile.relative_illumination.at(np.degrees(theta))
            stack = optics.relative_illumination(stack, factor)
    if "image_circle" in on and not inside.all():
        with _stage("image_circle"):
            stack = optics.image_circle(stack, inside)
    if "psf" in on and profile.psf.on:
        with _stage("psf"):
            plan = optics.lens_psf_plan(profile.psf, lens, origin, shape)
            if plan is not None:
                stack = plan.apply(stack)
    if lc:
        with _stage("lateral_colour"):
            maps = optics.lateral_colour_maps(profile.lateral_colour, lens, origin, shape)
            stack = optics.lateral_colour(stack, maps)
    return stack[0] if single else stack


def pixel_gain(
    profile: CameraProfile, origin_px: tuple[int, int], shape: tuple[int, int]
) -> np.ndarray:
    """(H, W) float32: the :data:`PIXEL_GAIN_STAGES` over a crop as one factor per pixel,
    relative illumination times the image circle (exact: the circle is 0 or 1).

    Multiplying a radiance by it equals running those stages in :func:`optical_image`, bit for
    bit; the frame renderer applies it on the Dr.Jit side, where the pixels already are."""
    origin = _check_origin(origin_px, shape, profile)
    theta, inside = optics.field_angles(profile.lens, origin, tuple(shape))
    gain = inside.astype(np.float32)
    if profile.relative_illumination.on:
        gain *= profile.relative_illumination.at(np.degrees(theta)).astype(np.float32)
    return gain


def sensor_images(
    irradiance: np.ndarray,
    profile: CameraProfile,
    rng: np.random.Generator,
    n_images: int = 1,
    origin_px: tuple[int, int] = (0, 0),
    exposure: float = 1.0,
    stages: Iterable[str] = STAGES,
) -> np.ndarray:
    """The grey images the detector sees, (N, H, W) uint8, drawn from sensor irradiance.

    ``irradiance``: (H, W, 3), from which ``n_images`` noisy images are drawn, or (N, H, W, 3),
    one image each (``n_images`` 1 or N); linear RGB times ``exposure`` is the signal in
    full-scale units. Stages: mosaic, noise, demosaic, transfer, sharpen, stream.
    """
    on = _check_stages(stages)
    stack, single = _as_rgb_stack(irradiance, "irradiance")
    n_out = _n_out(stack, single, n_images)
    origin = _check_origin(origin_px, stack.shape[1:3], profile)
    number = isinstance(exposure, int | float | np.integer | np.floating)
    if not (number and not isinstance(exposure, bool) and math.isfinite(exposure) and exposure > 0):
        raise ValueError(f"exposure={exposure!r}: must be a finite number > 0")
    sens, proc = profile.sensor, profile.processing
    noise_rng = rng if "noise" in on else None
    transfer = proc.transfer if "transfer" in on else "linear"
    if sens.cfa == "none" or "mosaic" not in on:
        with _stage("mosaic"):
            grey = (stack @ sensor.LUMINANCE_RGB).astype(np.float32) * np.float32(exposure)
        with _stage("noise"):
            signal = sensor.photosite_signal(
                grey, sens.full_well_e, sens.read_noise_e, sens.dark_signal_e, noise_rng, n_out
            )
        with _stage("transfer"):
            images = sensor.quantize(signal, transfer)
    else:
        with _stage("mosaic"):
            raw = sensor.mosaic(stack, sens.cfa, origin) * np.float32(exposure)
        with _stage("noise"):
            signal = sensor.photosite_signal(
                raw, sens.full_well_e, sens.read_noise_e, sens.dark_signal_e, noise_rng, n_out
            )
            codes = sensor.adc(signal)
        images = _process(codes, sensor.crop_pattern(sens.cfa, origin), proc.demosaic, transfer, on)
    if "sharpen" in on and proc.sharpen_amount > 0:
        with _stage("sharpen"):
            images = sensor.sharpen(images, proc.sharpen_amount, proc.sharpen_sigma_px)
    with _stage("stream"):
        return stream.grey_images(images, profile.stream, origin, mjpeg="stream" in on)


def _process(
    codes: np.ndarray, pattern: str, method: str, transfer: str, on: frozenset[str]
) -> np.ndarray:
    """12-bit mosaics to 8-bit RGB (or the raw mosaic as grey without ``demosaic``)."""
    lut = sensor.transfer_lut(transfer, 1 << sensor.ADC_BITS)
    if "demosaic" not in on:
        with _stage("transfer"):
            return lut.take(codes)
    if method == "vng":  # OpenCV's VNG is 8-bit only: encode first
        with _stage("transfer"):
            encoded = lut.take(codes)
        with _stage("demosaic"):
            return sensor.demosaic(encoded, pattern, method)
    with _stage("demosaic"):
        rgb = sensor.demosaic(codes, pattern, method)
    with _stage("transfer"):
        return lut.take(rgb)


def record(
    radiance: np.ndarray,
    profile: CameraProfile,
    rng: np.random.Generator,
    n_images: int = 1,
    origin_px: tuple[int, int] = (0, 0),
    exposure: float = 1.0,
    stages: Iterable[str] = STAGES,
) -> np.ndarray:
    """:func:`optical_image` then :func:`sensor_images`: (N, H, W) uint8 grey images."""
    irradiance = optical_image(radiance, profile, origin_px, stages)
    return sensor_images(irradiance, profile, rng, n_images, origin_px, exposure, stages)


# --- Cost per stage ---------------------------------------------------------------------------


def stage_costs(
    profile: CameraProfile,
    shape: tuple[int, int] = (128, 128),
    n_images: int = 100,
    origin_px: tuple[int, int] | None = None,
    seed: int = 0,
) -> dict[str, float]:
    """Seconds per image of each stage recording ``n_images`` draws of a random-texture crop.

    The optics run once for the batch, so their cost per image is divided by ``n_images``, as in
    the study. The default crop is centred 45 degrees off axis along +x, on the block grid.
    Stages the profile leaves off are absent (they cost nothing).
    """
    global _costs
    lens = profile.lens
    if origin_px is None:
        centre = lens.project(np.array([math.sin(math.pi / 4), 0.0, math.cos(math.pi / 4)]))
        grid = profile.crop_grid_px
        limits = (lens.width_px, lens.height_px)
        origin_px = tuple(
            int(max(0, min(c - s // 2, limit - s)) // grid * grid)
            for c, s, limit in zip(centre, shape[::-1], limits, strict=True)
        )
    rng = np.random.default_rng(seed)
    radiance = rng.uniform(0.05, 0.8, (*shape, 3)).astype(np.float32)
    record(radiance, profile, rng, 2, origin_px)  # warm the caches and tables
    optics.field_angles.cache_clear()  # the per-crop set-up counts, once per batch
    optics.lens_psf_plan.cache_clear()
    optics.lateral_colour_maps.cache_clear()
    _costs = {}
    try:
        record(radiance, profile, rng, n_images, origin_px)
        costs = dict(_costs)
    finally:
        _costs = None
    return {name: costs[name] / n_images for name in STAGES if name in costs}
