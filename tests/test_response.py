"""Tests of the camera response: shapes, determinism, saturation, noise statistics, exposure,
vignetting, lens blur, JPEG and parameter validation."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from renderers.response import CameraResponse, apply_response, exposure_for

THETA_MAX = math.radians(95.0)
# Noise-free and linear: shot noise ~1e-6 of full scale, no read noise, code = round(255 x).
CLEAN = {"full_well_e": 1e12, "read_noise_e": 0.0, "gamma": "linear"}


def fisheye_maps(size: int) -> tuple[np.ndarray, np.ndarray]:
    """Equidistant theta map of a square image whose circle touches the edges, and its mask."""
    c = (size - 1) / 2.0
    y, x = np.mgrid[0:size, 0:size]
    theta = np.hypot(x - c, y - c) / (size / 2.0) * THETA_MAX
    return theta, theta <= THETA_MAX


def stripes(size: int, period: int = 8, lo: float = 0.2, hi: float = 0.8) -> np.ndarray:
    """Vertical stripes, a sharp edge every period / 2 columns."""
    cols = np.where((np.arange(size) // (period // 2)) % 2 == 0, lo, hi)
    return np.tile(cols, (size, 1)).astype(np.float32)


# --- Shapes and determinism -----------------------------------------------------------------


@pytest.mark.parametrize(
    ("shape", "n_images", "expected"),
    [
        ((32, 48), 1, (1, 32, 48)),
        ((32, 48), 7, (7, 32, 48)),
        ((3, 32, 48), 1, (3, 32, 48)),
        ((3, 32, 48), 3, (3, 32, 48)),
    ],
)
def test_output_dtype_and_shape(shape, n_images, expected):
    radiance = np.full(shape, 0.3, np.float32)
    out = apply_response(radiance, CameraResponse(), np.random.default_rng(0), n_images)
    assert out.dtype == np.uint8
    assert out.shape == expected


def test_stack_keeps_images_apart():
    levels = np.array([0.05, 0.31, 0.93], np.float32)  # no ties at .5 codes
    radiance = levels[:, None, None] * np.ones((3, 16, 16), np.float32)
    out = apply_response(radiance, CameraResponse(**CLEAN), np.random.default_rng(0))
    np.testing.assert_array_equal(out.mean(axis=(1, 2)), np.rint(255 * levels))


@pytest.mark.parametrize(("shape", "n_images"), [((3, 8, 8), 2), ((8, 8), 0), ((8, 8), 1.5)])
def test_bad_n_images_raises(shape, n_images):
    with pytest.raises(ValueError, match="n_images"):
        apply_response(np.ones(shape), CameraResponse(), np.random.default_rng(0), n_images)


@pytest.mark.parametrize(
    "radiance", [np.ones(5), np.ones((2, 2, 2, 2)), np.full((4, 4), np.nan)], ids=str
)
def test_bad_radiance_raises(radiance):
    with pytest.raises(ValueError, match="radiance"):
        apply_response(radiance, CameraResponse(), np.random.default_rng(0))


@pytest.mark.parametrize("jpeg_quality", [None, 80])
def test_same_seed_same_images_different_seed_different(jpeg_quality):
    theta, valid = fisheye_maps(64)
    response = CameraResponse(
        exposure="auto",
        vignetting=0.3,
        blur_sigma_centre_px=0.5,
        blur_sigma_edge_px=1.5,
        jpeg_quality=jpeg_quality,
    )
    radiance = stripes(64)

    def render(seed: int) -> np.ndarray:
        return apply_response(
            radiance, response, np.random.default_rng(seed), 4, theta, THETA_MAX, valid
        )

    np.testing.assert_array_equal(render(1), render(1))
    assert np.any(render(1) != render(2))


def test_noise_differs_between_images_of_a_batch():
    out = apply_response(np.full((32, 32), 0.3), CameraResponse(), np.random.default_rng(0), 2)
    assert np.any(out[0] != out[1])


# --- Saturation and black -------------------------------------------------------------------


@pytest.mark.parametrize("full_well_e", [100.0, 6000.0])
@pytest.mark.parametrize(
    ("gamma", "read_noise_e", "lowest", "fraction_below_255"),
    [
        ("srgb", 3.0, 255, 0.0),
        ("linear", 0.0, 255, 0.0),
        ("linear", 3.0, 254, 0.0),  # 0.13 codes rms: below 254.5 only beyond 3.9 sigma
        ("linear", 30.0, 249, 0.35),  # 1.3 codes rms: P(z < -0.39)
    ],
)
def test_saturation_clips_the_well(full_well_e, gamma, read_noise_e, lowest, fraction_below_255):
    # A full well reads full scale minus read noise (given per 6000 e- of well). In sRGB (slope
    # 0.45 at the top) the default 3 e- never leave code 255; linear codes show larger noise.
    read = read_noise_e * full_well_e / 6000.0
    response = CameraResponse(full_well_e=full_well_e, read_noise_e=read, gamma=gamma)
    out = apply_response(np.full((64, 64), 50.0), response, np.random.default_rng(0), 10)
    assert out.min() >= lowest
    assert np.mean(out < 255) == pytest.approx(fraction_below_255, abs=0.02)


def test_black_with_read_noise_is_near_zero_and_outside_valid_is_zero():
    _, valid = fisheye_maps(96)
    response = CameraResponse(read_noise_e=3.0)
    out = apply_response(np.zeros((96, 96)), response, np.random.default_rng(0), 8, valid=valid)
    inside = out[:, valid].astype(float)
    assert inside.mean() < 1.0
    assert inside.max() > 0  # read noise is there
    assert np.all(out[:, ~valid] == 0)


@pytest.mark.parametrize("jpeg_quality", [None, 50])
def test_outside_valid_is_black_even_if_lit(jpeg_quality):
    theta, valid = fisheye_maps(64)
    response = CameraResponse(
        blur_sigma_centre_px=1.0, blur_sigma_edge_px=3.0, jpeg_quality=jpeg_quality
    )
    out = apply_response(
        np.full((64, 64), 0.8), response, np.random.default_rng(0), 3, theta, THETA_MAX, valid
    )
    assert np.all(out[:, ~valid] == 0)
    assert out[:, valid].mean() > 200


# --- Noise statistics -----------------------------------------------------------------------


@pytest.mark.parametrize(
    ("full_well_e", "read_noise_e", "level"),
    [(6000.0, 3.0, 0.5), (1000.0, 10.0, 0.5), (2000.0, 20.0, 0.3), (1000.0, 3.0, 0.02)],
)
def test_flat_field_noise_matches_shot_plus_read(full_well_e, read_noise_e, level):
    response = CameraResponse(full_well_e=full_well_e, read_noise_e=read_noise_e, gamma="linear")
    out = apply_response(np.full((256, 256), level), response, np.random.default_rng(3), 4)
    electrons = out.astype(float) / 255.0 * full_well_e
    signal_e = level * full_well_e
    assert electrons.mean() == pytest.approx(signal_e, rel=0.02)
    assert electrons.std() == pytest.approx(math.sqrt(signal_e + read_noise_e**2), rel=0.1)


@pytest.mark.parametrize("mean_e", [0.5, 3.0, 20.0])
def test_few_electrons_are_poisson(mean_e):
    # One code per electron: the output is the photo-electron count itself.
    response = CameraResponse(full_well_e=255.0, read_noise_e=0.0, gamma="linear")
    out = apply_response(
        np.full((128, 128), mean_e / 255.0), response, np.random.default_rng(5), 4
    ).astype(float)
    assert out.mean() == pytest.approx(mean_e, rel=0.03)
    assert out.var() == pytest.approx(mean_e, rel=0.05)
    assert np.mean(out == 0) == pytest.approx(math.exp(-mean_e), abs=0.01)


# --- Exposure -------------------------------------------------------------------------------


@pytest.mark.parametrize("target", [0.18, 0.5])
@pytest.mark.parametrize("stack", [False, True])
def test_auto_exposure_meters_the_valid_clean_pixels(target, stack):
    _, valid = fisheye_maps(64)
    rng = np.random.default_rng(7)
    radiance = rng.uniform(0.0, 3.0, (3, 64, 64) if stack else (64, 64)).astype(np.float32)
    radiance[..., ~valid] = 100.0  # must not be metered
    response = CameraResponse(exposure="auto", auto_target=target)
    exposure = exposure_for(radiance, response, valid)
    metered = np.mean(radiance[..., valid].astype(np.float64) * exposure)
    assert metered == pytest.approx(target, rel=1e-6)

    noise_free = CameraResponse(exposure="auto", auto_target=target, **CLEAN)
    out = apply_response(radiance, noise_free, np.random.default_rng(0), valid=valid)
    assert out[:, valid].mean() == pytest.approx(255.0 * target, abs=0.6)


def test_fixed_exposure_is_reported_and_applied():
    assert exposure_for(np.ones((4, 4)), CameraResponse(exposure=2.5)) == 2.5
    out = apply_response(
        np.full((8, 8), 0.1), CameraResponse(exposure=2.5, **CLEAN), np.random.default_rng(0)
    )
    assert np.all(out == round(255 * 0.25))


def test_auto_exposure_of_black_image_raises():
    with pytest.raises(ValueError, match="exposure"):
        exposure_for(np.zeros((8, 8)), CameraResponse(exposure="auto"))


# --- Vignetting and blur --------------------------------------------------------------------


@pytest.mark.parametrize("vignetting", [0.3, 0.6, 1.5])
def test_vignetting_follows_the_stated_falloff(vignetting):
    theta, valid = fisheye_maps(128)
    response = CameraResponse(vignetting=vignetting, **CLEAN)
    out = apply_response(
        np.full((128, 128), 0.8),
        response,
        np.random.default_rng(0),
        theta_rad=theta,
        theta_max_rad=THETA_MAX,
        valid=valid,
    )[0]
    relative = np.clip(1.0 - vignetting * (theta / THETA_MAX) ** 2, 0.0, None)
    expected = np.rint(255 * 0.8 * relative)
    assert np.abs(out[valid].astype(float) - expected[valid]).max() <= 1
    rim = valid & (theta > 0.97 * THETA_MAX)
    assert out[rim].mean() / out[63:65, 63:65].mean() == pytest.approx(
        max(0.0, 1.0 - vignetting), abs=0.05 if vignetting < 1 else 0.01
    )


@pytest.mark.parametrize(
    "fields", [{"vignetting": 0.2}, {"blur_sigma_centre_px": 0.5, "blur_sigma_edge_px": 2.0}]
)
def test_theta_required_when_it_matters(fields):
    with pytest.raises(ValueError, match="theta"):
        apply_response(np.ones((8, 8)), CameraResponse(**fields), np.random.default_rng(0))


def test_blur_grows_toward_the_edge():
    size = 256
    theta, valid = fisheye_maps(size)
    response = CameraResponse(blur_sigma_centre_px=0.5, blur_sigma_edge_px=3.0, **CLEAN)
    radiance = stripes(size)
    out = apply_response(
        radiance,
        response,
        np.random.default_rng(0),
        theta_rad=theta,
        theta_max_rad=THETA_MAX,
        valid=valid,
    )[0].astype(float)
    c = size // 2
    centre = out[c - 4 : c + 4, c - 16 : c + 16]  # theta/theta_max < 0.15
    edge = out[c - 4 : c + 4, 4:36]  # theta/theta_max ~ 0.8
    steepest = lambda patch: np.abs(np.diff(patch, axis=1)).max()  # noqa: E731
    assert steepest(centre) > 2.0 * steepest(edge)
    assert np.ptp(centre) > np.ptp(edge) + 20

    # Locally the result is the Gaussian blur of the pixel's own sigma: checked along rows of
    # 16 pixels around the vertical axis, where each row's sigma is nearly constant.
    cols = slice(c - 8, c + 8)
    for row in (c, c - 20, c - 64, c - 100, 10):
        sigma = float(np.mean(0.5 + 2.5 * (theta[row, cols] / THETA_MAX) ** 2))
        reference = cv2.GaussianBlur(radiance, (0, 0), sigma)[row, cols] * 255.0
        assert np.abs(out[row, cols] - reference).max() <= 2.0, sigma


def test_uniform_blur_is_one_gaussian_and_needs_no_theta():
    radiance = stripes(64)
    response = CameraResponse(blur_sigma_centre_px=1.5, blur_sigma_edge_px=1.5, **CLEAN)
    out = apply_response(radiance, response, np.random.default_rng(0))[0].astype(float)
    # The blur repeats the crop's edge pixels beyond it (a crop's outside is unknown).
    reference = cv2.GaussianBlur(radiance, (0, 0), 1.5, borderType=cv2.BORDER_REPLICATE)
    reference = np.rint(reference * 255.0)
    assert np.abs(out - reference).max() <= 1


# --- JPEG -----------------------------------------------------------------------------------


@pytest.mark.parametrize("quality", [95, 75])
def test_jpeg_changes_the_image_slightly(quality):
    radiance = cv2.GaussianBlur(stripes(128, period=16), (0, 0), 1.0)
    plain = apply_response(radiance, CameraResponse(), np.random.default_rng(9), 3)
    jpeg = apply_response(
        radiance, CameraResponse(jpeg_quality=quality), np.random.default_rng(9), 3
    )
    assert jpeg.shape == plain.shape and jpeg.dtype == np.uint8
    diff = np.abs(jpeg.astype(float) - plain.astype(float)).mean()
    assert 0.0 < diff < 3.0


# --- Validation and speed -------------------------------------------------------------------


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("exposure", -1.0),
        ("exposure", 0.0),
        ("exposure", float("nan")),
        ("exposure", float("inf")),
        ("exposure", "bright"),
        ("exposure", True),
        ("auto_target", 0.0),
        ("auto_target", 1.5),
        ("full_well_e", 0.0),
        ("full_well_e", float("inf")),
        ("read_noise_e", -1.0),
        ("read_noise_e", float("nan")),
        ("vignetting", -0.1),
        ("blur_sigma_centre_px", -1.0),
        ("blur_sigma_edge_px", float("inf")),
        ("gamma", "log"),
        ("jpeg_quality", 0),
        ("jpeg_quality", 101),
        ("jpeg_quality", 50.5),
        ("jpeg_quality", True),
    ],
)
def test_bad_field_raises_naming_field_and_value(field, value):
    with pytest.raises(ValueError, match=field) as info:
        CameraResponse(**{field: value})
    assert repr(value) in str(info.value)
