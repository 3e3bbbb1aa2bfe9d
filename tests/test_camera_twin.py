"""Tests of the camera twin's API: the ideal profile is the pre-twin camera response exactly, each
stage switches off, shapes and bad input, and the per-stage cost helper."""

from __future__ import annotations

import dataclasses
import hashlib
import math

import numpy as np
import pytest

from renderers.camera_twin import STAGES, optical_image, record, sensor_images, stage_costs
from scenes.profile import (
    CameraProfile,
    LateralColour,
    Processing,
    PsfTable,
    RelativeIllumination,
    Sensor,
    Stream,
)

IDEAL = CameraProfile()
LENS = IDEAL.lens
#: A twin with every stage on (numbers chosen to exercise the stages, not a real camera).
BUSY = CameraProfile(
    relative_illumination=RelativeIllumination(theta_deg=(0.0, 90.0), value=(1.0, 0.5)),
    psf=PsfTable(theta_deg=(0.0, 90.0), sigma_radial_px=(0.8, 1.8), sigma_tangential_px=(0.8, 1.3)),
    lateral_colour=LateralColour(
        theta_deg=(0.0, 90.0), red_scale=(1.0, 1.004), blue_scale=(1.0, 0.997)
    ),
    sensor=Sensor(cfa="GRBG", full_well_e=7000.0, read_noise_e=2.9, dark_signal_e=5.0),
    processing=Processing(demosaic="edge_aware", sharpen_amount=0.4),
    stream=Stream(codec="mjpeg", quality=85, chroma_subsampling="4:2:0"),
)


def texture(shape: tuple[int, ...], seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).uniform(0.02, 0.9, (*shape, 3)).astype(np.float32)


def theta_deg_of(origin: tuple[int, int], shape: tuple[int, int]) -> np.ndarray:
    """Field angle of each pixel of a crop: r / f for the ideal (equidistant) lens."""
    ys, xs = np.mgrid[origin[1] : origin[1] + shape[0], origin[0] : origin[0] + shape[1]]
    return np.degrees(np.hypot(xs - LENS.cx_px, ys - LENS.cy_px) / LENS.fx_px)


# --- The ideal profile is the pre-twin camera response ---------------------------------------

#: SHA-256 prefixes of the images the pre-twin grey camera response (``renderers/response.py`` of
#: commit 38b9535, ``apply_response(luminance, CameraResponse(exposure=...), rng, n)``) made of
#: these inputs, the luminance masked to the image circle; computed once with that module.
PRE_TWIN_DIGESTS = {
    ((48, 64), 5, (1200, 900), 1.0, 8): "11286c8305ae0d1a",
    ((3, 48, 64), 1, (1200, 900), 1.0, 8): "b6e2005a5f679d1b",
    ((96, 80), 4, (200, 920), 1.0, 8): "feefdaa3594ecf00",  # straddles the image circle
    ((32, 40), 3, (1000, 800), 2.5, 1): "d93b65d37c953d65",
}


@pytest.mark.parametrize("case", list(PRE_TWIN_DIGESTS))
def test_ideal_profile_is_the_pre_twin_response_exactly(case):
    radiance_shape, n_images, origin, exposure, seed = case
    radiance = texture(radiance_shape, seed=3 if exposure == 1.0 else 4)
    out = record(radiance, IDEAL, np.random.default_rng(seed), n_images, origin, exposure=exposure)
    assert out.dtype == np.uint8 and out.shape == (n_images if len(radiance_shape) == 2 else 3,
                                                   *radiance_shape[-2:])  # fmt: skip
    assert hashlib.sha256(out.tobytes()).hexdigest()[:16] == PRE_TWIN_DIGESTS[case]


# --- Switches ---------------------------------------------------------------------------------


def without(*names: str) -> tuple[str, ...]:
    return tuple(s for s in STAGES if s not in names)


@pytest.mark.parametrize(
    ("stage", "off"),
    [
        ("relative_illumination", {"relative_illumination": RelativeIllumination()}),
        ("psf", {"psf": PsfTable()}),
        ("lateral_colour", {"lateral_colour": LateralColour()}),
        ("mosaic", {"sensor": dataclasses.replace(BUSY.sensor, cfa="none")}),
        ("transfer", {"processing": dataclasses.replace(BUSY.processing, transfer="linear")}),
        ("sharpen", {"processing": dataclasses.replace(BUSY.processing, sharpen_amount=0.0)}),
        ("stream", {"stream": Stream(codec="none")}),
    ],
)
def test_a_stage_switched_off_is_the_profile_without_it(stage, off):
    radiance = texture((64, 80), seed=5)
    origin = (1856, 1104)  # about 55 degrees off axis, on the 16-px grid
    skipped = record(radiance, BUSY, np.random.default_rng(2), 2, origin, stages=without(stage))
    plain = record(radiance, dataclasses.replace(BUSY, **off), np.random.default_rng(2), 2, origin)
    np.testing.assert_array_equal(skipped, plain)
    full = record(radiance, BUSY, np.random.default_rng(2), 2, origin)
    assert np.any(full != plain)  # the stage does something here


def test_image_circle_switch():
    origin, shape = (200, 920), (40, 120)
    radiance = np.full((*shape, 3), 0.6, np.float32)
    outside = theta_deg_of(origin, shape) > LENS.theta_max_deg
    assert outside.any()
    dark = optical_image(radiance, IDEAL, origin)
    lit = optical_image(radiance, IDEAL, origin, stages=without("image_circle"))
    assert np.all(dark[outside] == 0) and np.all(lit == radiance)


def test_optics_run_once_for_many_draws():
    # record() on one clean image equals optical_image once then the draws from it.
    radiance = texture((48, 48), seed=6)
    origin = (1504, 1024)
    irradiance = optical_image(radiance, BUSY, origin)
    a = sensor_images(irradiance, BUSY, np.random.default_rng(3), 6, origin)
    b = record(radiance, BUSY, np.random.default_rng(3), 6, origin)
    np.testing.assert_array_equal(a, b)
    assert len({im.tobytes() for im in a}) == 6


def test_exposure_scales_the_signal():
    radiance = np.full((16, 16, 3), 0.2, np.float32)
    quiet = without("noise")
    profile = dataclasses.replace(IDEAL, processing=Processing(transfer="linear"))
    a = sensor_images(radiance, profile, np.random.default_rng(0), 1, (1000, 900), 2.0, quiet)
    b = sensor_images(2 * radiance, profile, np.random.default_rng(0), 1, (1000, 900), 1.0, quiet)
    np.testing.assert_array_equal(a, b)
    assert a.mean() == pytest.approx(255 * 0.4, abs=0.51)


# --- Shapes and bad input ---------------------------------------------------------------------


@pytest.mark.parametrize(
    ("shape", "n_images", "expected"),
    [
        ((20, 24, 3), 1, (1, 20, 24)),
        ((20, 24, 3), 7, (7, 20, 24)),
        ((3, 20, 24, 3), 3, (3, 20, 24)),
    ],
)
def test_output_shapes(shape, n_images, expected):
    out = record(texture(shape[:-1]), BUSY, np.random.default_rng(0), n_images, (1600, 960))
    assert out.shape == expected and out.dtype == np.uint8
    assert optical_image(texture(shape[:-1]), BUSY, (1600, 960)).shape == shape


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"radiance": np.ones((8, 8))}, "radiance"),
        ({"radiance": np.full((8, 8, 3), np.nan)}, "radiance"),
        ({"n_images": 0}, "n_images"),
        ({"n_images": 2.0}, "n_images"),
        ({"radiance": np.ones((3, 8, 8, 3)), "n_images": 2}, "n_images"),
        ({"origin_px": (-1, 0)}, "origin_px"),
        ({"origin_px": (2590, 0)}, "origin_px"),
        ({"origin_px": (1.5, 0)}, "origin_px"),
        ({"exposure": 0.0}, "exposure"),
        ({"exposure": math.inf}, "exposure"),
        ({"stages": ("psf", "bloom")}, "stages"),
    ],
)
def test_bad_input_raises_naming_the_argument(kwargs, match):
    args = {"radiance": np.ones((8, 8, 3)), "n_images": 1, "origin_px": (0, 0), "exposure": 1.0}
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        record(args.pop("radiance"), IDEAL, np.random.default_rng(0), **args)


# --- Cost per stage ---------------------------------------------------------------------------


def test_stage_costs_names_the_stages_that_run():
    costs = stage_costs(BUSY, shape=(64, 64), n_images=4)
    assert set(costs) <= set(STAGES)
    assert {"psf", "lateral_colour", "mosaic", "noise", "demosaic", "sharpen", "stream"} <= set(
        costs
    )
    assert all(v > 0 for v in costs.values())
    ideal = stage_costs(IDEAL, shape=(64, 64), n_images=4)
    assert not {"psf", "lateral_colour", "relative_illumination", "demosaic", "sharpen"} & set(
        ideal
    )


def test_pixel_gain_stands_in_for_its_stages():
    # What the frame renderer does: the per-pixel stages as one factor, then the other stages;
    # on a crop straddling the image circle, bit for bit what optical_image does alone.
    from renderers.camera_twin import PIXEL_GAIN_STAGES, pixel_gain

    origin, shape = (200, 920), (96, 80)
    radiance = texture((2, *shape), seed=3)
    gain = pixel_gain(BUSY, origin, shape)
    rest = [s for s in STAGES if s not in PIXEL_GAIN_STAGES]
    assert gain.min() == 0.0 and 0.0 < gain.max() < 1.0  # both stages act here
    np.testing.assert_array_equal(
        optical_image(radiance * gain[..., None], BUSY, origin, rest),
        optical_image(radiance, BUSY, origin),
    )
