"""Tests of the sensor and processing stages: Bayer phase, OpenCV's demosaic codes, photon
transfer per colour plane, the 12-bit ADC, the transfer curve and sharpening."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from renderers import sensor
from renderers.camera_twin import STAGES, sensor_images
from scenes.profile import CameraProfile, Processing, Sensor

PATTERNS = ("RGGB", "BGGR", "GRBG", "GBRG")
CHANNEL = {"R": 0, "G": 1, "B": 2}
COLOUR = np.array([0.62, 0.35, 0.13])  # distinct per channel, no ties at half codes
NO_NOISE_RAW = tuple(s for s in STAGES if s not in ("noise", "demosaic"))


def full_frame_channel(pattern: str, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """The channel index of full-frame pixel (x, y) under a 2 x 2 pattern named row by row."""
    tile = np.array(
        [[CHANNEL[pattern[0]], CHANNEL[pattern[1]]], [CHANNEL[pattern[2]], CHANNEL[pattern[3]]]]
    )
    return tile[y % 2, x % 2]


def colour_profile(cfa: str = "RGGB", **sensor_fields) -> CameraProfile:
    return CameraProfile(
        sensor=Sensor(cfa=cfa, **sensor_fields), processing=Processing(transfer="linear")
    )


# --- Mosaic phase and demosaicing -------------------------------------------------------------


@pytest.mark.parametrize("pattern", PATTERNS)
@pytest.mark.parametrize("origin", [(0, 0), (1, 0), (0, 1), (1, 1), (17, 32)])
def test_mosaic_phase_follows_the_crop_origin(pattern, origin):
    # Without noise or demosaicing the grey image is the raw mosaic: each pixel reads its own
    # photosite's colour, chosen by the full-frame position of the pixel.
    h, w = 6, 8
    irradiance = np.broadcast_to(COLOUR, (h, w, 3))
    out = sensor_images(
        irradiance,
        colour_profile(pattern),
        np.random.default_rng(0),
        1,
        origin,
        stages=NO_NOISE_RAW,
    )
    ys, xs = np.mgrid[origin[1] : origin[1] + h, origin[0] : origin[0] + w]
    expected = np.rint(255.0 * np.rint(4095.0 * COLOUR[full_frame_channel(pattern, xs, ys)]) / 4095)
    np.testing.assert_array_equal(out[0], expected)


@pytest.mark.parametrize("pattern", PATTERNS)
@pytest.mark.parametrize(
    ("method", "dtype"),
    [
        ("bilinear", np.uint8),
        ("bilinear", np.uint16),
        ("edge_aware", np.uint8),
        ("edge_aware", np.uint16),
        ("vng", np.uint8),  # OpenCV's VNG is 8-bit only
    ],
)
def test_demosaic_codes_return_a_flat_colour(pattern, method, dtype):
    # OpenCV's Bayer names are checked, not trusted: a flat colour mosaicked by the pattern
    # (built here from the letters) comes back as that colour, in RGB order.
    top = 255 if dtype == np.uint8 else 4095
    rgb = np.rint(COLOUR * top).astype(dtype)
    ys, xs = np.mgrid[0:16, 0:20]
    mosaic = rgb[full_frame_channel(pattern, xs, ys)]
    out = sensor.demosaic(mosaic[None], pattern, method)[0]
    inner = out[2:-2, 2:-2]  # OpenCV leaves the outermost pixels approximate
    np.testing.assert_array_equal(inner, np.broadcast_to(rgb, inner.shape))


def test_vng_refuses_wide_codes():
    with pytest.raises(ValueError, match="vng"):
        sensor.demosaic(np.zeros((1, 8, 8), np.uint16), "RGGB", "vng")


@pytest.mark.parametrize("pattern", PATTERNS)
@pytest.mark.parametrize("method", ["bilinear", "edge_aware", "vng"])
@pytest.mark.parametrize("origin", [(0, 0), (1, 1), (3, 2)])
def test_flat_colour_through_the_colour_path_is_its_grey(pattern, method, origin):
    # Through the public path (no noise, no stream): the grey of the demosaicked colour is
    # OpenCV's Rec. 601 grey of the colour's 8-bit codes, at every crop phase.
    profile = CameraProfile(
        sensor=Sensor(cfa=pattern), processing=Processing(demosaic=method, transfer="linear")
    )
    irradiance = np.broadcast_to(COLOUR, (12, 14, 3))
    stages = tuple(s for s in STAGES if s != "noise")
    out = sensor_images(irradiance, profile, np.random.default_rng(0), 1, origin, stages=stages)[0]
    codes = np.rint(255.0 * np.rint(4095.0 * COLOUR) / 4095.0)
    grey = 0.299 * codes[0] + 0.587 * codes[1] + 0.114 * codes[2]
    assert np.abs(out[2:-2, 2:-2].astype(float) - grey).max() <= 0.55  # OpenCV's fixed point


# --- Noise ------------------------------------------------------------------------------------


@pytest.mark.parametrize("cfa", ["none", "RGGB", "GBRG"])
def test_flat_field_noise_follows_photon_transfer(cfa):
    # Per colour plane, in electrons: variance = signal + dark + read^2 (the dark signal's mean is
    # subtracted, its shot noise stays), plus the 8-bit quantization's 1/12 code^2.
    full_well, read, dark = 2550.0, 4.0, 60.0
    profile = colour_profile(cfa, full_well_e=full_well, read_noise_e=read, dark_signal_e=dark)
    stages = tuple(s for s in STAGES if s != "demosaic")
    out = sensor_images(
        np.broadcast_to(COLOUR, (64, 64, 3)),
        profile,
        np.random.default_rng(4),
        12,
        (6, 10),
        1.0,
        stages,
    ).astype(float)
    e_per_code = full_well / 255.0
    ys, xs = np.mgrid[10:74, 6:70]
    if cfa == "none":
        planes = {"grey": (np.ones((64, 64), bool), float(COLOUR @ sensor.LUMINANCE_RGB))}
    else:
        channel = full_frame_channel(cfa, xs, ys)
        planes = {c: (channel == i, COLOUR[i]) for c, i in CHANNEL.items()}
    for name, (mask, level) in planes.items():
        values = out[:, mask]
        signal_e = level * full_well
        assert values.mean() * e_per_code == pytest.approx(signal_e, rel=0.01), name
        predicted = (signal_e + dark + read**2) / e_per_code**2 + 1.0 / 12.0
        assert values.var() == pytest.approx(predicted, rel=0.05), name


def test_noise_stage_off_is_deterministic_and_noise_on_is_not():
    profile = colour_profile("RGGB")
    irradiance = np.broadcast_to(COLOUR, (16, 16, 3))
    quiet = tuple(s for s in STAGES if s != "noise")
    a = sensor_images(irradiance, profile, np.random.default_rng(0), 3, stages=quiet)
    assert np.all(a == a[0])
    b = sensor_images(irradiance, profile, np.random.default_rng(0), 3)
    assert np.any(b[0] != b[1])


# --- ADC, transfer, sharpening ----------------------------------------------------------------


def test_adc_rounds_to_12_bits_and_clips():
    x = np.array([-0.2, 0.0, 0.4 / 4095, 0.6 / 4095, 0.5, 1.0, 1.7], np.float32)
    np.testing.assert_array_equal(sensor.adc(x), [0, 0, 0, 1, 2048, 4095, 4095])


@pytest.mark.parametrize("levels", [4096, 65536])
def test_srgb_table_follows_iec_61966_2_1(levels):
    lut = sensor.transfer_lut("srgb", levels).astype(int)
    for x in (0.0, 0.002, 0.0031308, 0.01, 0.18, 0.5, 1.0):
        i = round(x * (levels - 1))
        xi = i / (levels - 1)
        srgb = 12.92 * xi if xi <= 0.0031308 else 1.055 * xi ** (1 / 2.4) - 0.055
        assert lut[i] == round(255 * srgb)


@pytest.mark.parametrize(("amount", "sigma"), [(0.5, 1.0), (1.5, 2.0)])
def test_sharpening_is_an_unsharp_mask(amount, sigma):
    image = np.zeros((1, 40, 40, 3), np.uint8)
    image[:, :, 20:] = (200, 120, 60)
    image[:, :, :20] = (40, 30, 20)
    out = sensor.sharpen(image, amount, sigma).astype(float)
    x = image[0].astype(np.float64)
    size = 2 * math.ceil(4 * sigma) + 1
    blurred = cv2.GaussianBlur(x, (size, size), sigma, borderType=cv2.BORDER_REPLICATE)
    expected = np.clip(x + amount * (x - blurred), 0, 255)
    assert np.abs(out[0] - expected).max() <= 1.0
    assert out[0, :, 20:, 0].max() > 200  # overshoot on the bright side of the edge
