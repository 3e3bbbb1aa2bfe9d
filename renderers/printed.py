"""A printed marker in a still photograph, drawn exactly without Mitsuba: the imagery that tests
of corner refinement on "real" photographs need and the camera twin does not make.

The twin blurs in linear light (the lens PSF) before the transfer curve. Real cameras also blur
after it (resampling, JPEG) and sharpen (the ISP's unsharp mask), and paper is lit unevenly.
:func:`marker_albedo_image` ray casts the marker on an endless white sheet through any camera
model with stratified, jittered rays (edges exact to the supersampling);
:func:`photograph` applies, in a camera's order: illumination (a gain per pixel, linear light),
optics blur (linear light), sensor noise, the transfer curve, blur after encoding (on the 8-bit
codes), unsharp-mask sharpening and JPEG. Sensor noise, the curve, sharpening and JPEG are the
twin's own (:mod:`renderers.sensor`, :mod:`renderers.stream`).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from renderers import sensor, stream
from scenes.camera import FisheyeCamera
from scenes.conventions import marker_corners_marker, transform_points
from scenes.marker import MarkerSpec, marker_albedo
from scenes.materials import WHITE_ALBEDO
from scenes.profile import Stream

_BAND_ROWS = 32  # image rows ray cast at once (bounds memory at high supersampling)


def marker_albedo_image(
    camera: FisheyeCamera,
    T_cam_marker: np.ndarray,
    spec: MarkerSpec,
    margin_px: int = 12,
    supersample: int = 16,
    seed: int = 0,
) -> tuple[np.ndarray, tuple[int, int], np.ndarray]:
    """The marker's albedo seen through ``camera``: (image, offset, true corners).

    image: (H, W) float32, a crop around the marker's corners plus ``margin_px``, each pixel the
    mean of supersample^2 rays (one per cell of a stratified grid, jittered within it; ``seed``)
    hitting the marker plane; white paper beyond the quiet zone and behind the camera. offset:
    (x0, y0) of the crop in full-image pixels. corners: (4, 2) float64, full-image pixels, ArUco
    order.
    """
    albedo = marker_albedo(spec)
    n_tex = albedo.shape[0]
    half_mm = spec.print_half_mm
    truth = camera.project(transform_points(T_cam_marker, marker_corners_marker(spec.size_mm)))
    lo = np.floor(truth.min(axis=0)).astype(int) - margin_px
    hi = np.ceil(truth.max(axis=0)).astype(int) + margin_px + 1
    rng = np.random.default_rng(seed)
    fine = (np.arange(supersample) + 0.5) / supersample - 0.5
    xs = (np.arange(lo[0], hi[0])[:, None] + fine).ravel()
    R, t = T_cam_marker[:3, :3], T_cam_marker[:3, 3]
    out = np.empty((hi[1] - lo[1], hi[0] - lo[0]), np.float32)
    for y0 in range(lo[1], hi[1], _BAND_ROWS):
        y1 = min(y0 + _BAND_ROWS, hi[1])
        ys = (np.arange(y0, y1)[:, None] + fine).ravel()
        samples = np.stack(np.meshgrid(xs, ys), axis=-1)
        samples += rng.uniform(-0.5, 0.5, samples.shape) / supersample
        rays, _ = camera.unproject(samples)
        along = (t @ R[:, 2]) / (rays @ R[:, 2])  # distance to the marker plane along each ray
        p = (rays * along[..., None] - t) @ R  # hit points in the marker frame (mm)
        col = np.floor((p[..., 0] + half_mm) / (2 * half_mm) * n_tex).astype(int)
        row = np.floor((half_mm - p[..., 1]) / (2 * half_mm) * n_tex).astype(int)
        on = (along > 0) & (col >= 0) & (col < n_tex) & (row >= 0) & (row < n_tex)
        value = np.where(
            on, albedo[np.clip(row, 0, n_tex - 1), np.clip(col, 0, n_tex - 1)], WHITE_ALBEDO
        ).astype(np.float32)
        out[y0 - lo[1] : y1 - lo[1]] = cv2.resize(
            value, (hi[0] - lo[0], y1 - y0), interpolation=cv2.INTER_AREA
        )
    return out, (int(lo[0]), int(lo[1])), truth


def gradient(
    shape: tuple[int, int], low: float, high: float, angle_deg: float = 30.0
) -> np.ndarray:
    """(H, W) float32 illumination rising linearly from ``low`` to ``high`` across the image
    along the direction ``angle_deg`` (0: left to right, 90: top to bottom)."""
    y, x = np.mgrid[0 : shape[0], 0 : shape[1]].astype(np.float64)
    a = np.radians(angle_deg)
    s = x * np.cos(a) + y * np.sin(a)
    s = (s - s.min()) / max(s.max() - s.min(), 1e-9)
    return (low + (high - low) * s).astype(np.float32)


@dataclass(frozen=True)
class Photo:
    """What happens to the light between the paper and the file (sigmas in pixels; 0: off).

    ``exposure`` scales the radiance to the sensor's full scale; ``full_well_e`` 0 means no
    noise; ``jpeg_quality`` 0 means no JPEG."""

    optics_sigma_px: float = 0.0
    encoded_sigma_px: float = 0.0
    sharpen_amount: float = 0.0
    sharpen_sigma_px: float = 1.0
    jpeg_quality: int = 0
    exposure: float = 1.0
    full_well_e: float = 0.0
    read_noise_e: float = 0.0
    transfer: str = "srgb"


def _blur(image: np.ndarray, sigma_px: float) -> np.ndarray:
    if sigma_px <= 0:
        return image
    return cv2.GaussianBlur(image, (0, 0), sigma_px, borderType=cv2.BORDER_REPLICATE)


def photograph(
    albedo: np.ndarray,
    photo: Photo,
    illumination: np.ndarray | None = None,
    rng: np.random.Generator | None = None,
) -> np.ndarray:
    """The 8-bit grey photograph (H, W) uint8 of an (H, W) float32 albedo image.

    ``illumination``: (H, W) gain in linear light (None: 1). ``rng``: the noise's generator,
    needed when ``photo.full_well_e`` > 0.
    """
    x = albedo * np.float32(photo.exposure)
    if illumination is not None:
        x = x * illumination
    x = _blur(x.astype(np.float32), photo.optics_sigma_px)
    if photo.full_well_e > 0:
        if rng is None:
            raise ValueError("photo.full_well_e > 0 needs rng=np.random.default_rng(seed)")
        x = sensor.photosite_signal(x[None], photo.full_well_e, photo.read_noise_e, 0.0, rng, 1)[0]
    codes = sensor.quantize(np.array(x, np.float32), photo.transfer)
    if photo.encoded_sigma_px > 0:
        codes = np.clip(np.rint(_blur(codes.astype(np.float32), photo.encoded_sigma_px)), 0, 255)
        codes = codes.astype(np.uint8)
    if photo.sharpen_amount > 0:
        codes = sensor.sharpen(codes[None], photo.sharpen_amount, photo.sharpen_sigma_px)[0]
    if photo.jpeg_quality > 0:
        jpeg = Stream(codec="mjpeg", quality=int(photo.jpeg_quality))
        codes = stream.decode_grey(stream.encode_frame(codes, jpeg))
    return codes
