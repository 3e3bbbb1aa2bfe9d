"""Tests of the stream stage: a block-aligned crop decodes to exactly the full frame's pixels, a
misaligned one is refused, the chroma subsampling reaches the file, raw grey is Rec. 601."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from renderers.camera_twin import STAGES, sensor_images
from renderers.stream import decode_grey, encode_frame, grey_images
from scenes.camera import default_camera
from scenes.profile import CameraProfile, Sensor, Stream

WIDTH, HEIGHT = 2592, 1944


@pytest.fixture(scope="module")
def frame() -> np.ndarray:
    """A full colour frame: smooth colour gradients, noise and hard edges, (1, H, W, 3) RGB."""
    rng = np.random.default_rng(11)
    ys = np.arange(HEIGHT, dtype=np.float32)[:, None]
    xs = np.arange(WIDTH, dtype=np.float32)[None, :]
    edges = np.where((xs // 41 + ys // 29) % 2 == 0, 0.3, 1.0)  # a checkerboard across every grid
    rgb = np.empty((HEIGHT, WIDTH, 3), np.float32)
    rgb[..., 0] = 200 * edges * xs / WIDTH
    rgb[..., 1] = 200 * edges * ys / HEIGHT
    rgb[..., 2] = 100 * edges * (1 + np.sin(xs / 37.0 + ys / 23.0))
    rgb += rng.integers(-12, 13, rgb.shape, dtype=np.int8)
    return np.clip(rgb, 0, 255).astype(np.uint8)[None]


def sof_sampling(jpeg: bytes) -> tuple[int, int]:
    """(horizontal, vertical) sampling factors of the first (luma) component in SOF0."""
    i = jpeg.index(b"\xff\xc0")
    return jpeg[i + 11] >> 4, jpeg[i + 11] & 0x0F


@pytest.mark.parametrize(
    ("subsampling", "origin", "size"),
    [
        ("4:2:0", (1056, 768), (208, 160)),
        ("4:2:2", (32, 1776), (96, 160)),
        ("4:4:4", (8, 40), (72, 56)),
    ],
)
def test_aligned_crop_equals_the_full_frame_decode(frame, subsampling, origin, size):
    stream = Stream(codec="mjpeg", quality=75, chroma_subsampling=subsampling)
    assert origin[0] % stream.block_px == 0 and origin[1] % stream.block_px == 0
    full = grey_images(frame, stream)[0]
    (x0, y0), (w, h) = origin, size
    crop = grey_images(frame[:, y0 : y0 + h, x0 : x0 + w], stream, origin)[0]
    np.testing.assert_array_equal(crop, full[y0 : y0 + h, x0 : x0 + w])
    # Not a lossless coincidence: a crop encoded on a grid 4 px off decodes differently.
    x1 = x0 + 4
    off = decode_grey(
        encode_frame(np.ascontiguousarray(frame[0, y0 : y0 + h, x1 : x1 + w, ::-1]), stream)
    )
    assert np.any(off != full[y0 : y0 + h, x1 : x1 + w])


@pytest.mark.parametrize(
    ("subsampling", "origin"), [("4:2:0", (8, 0)), ("4:2:2", (0, 24)), ("4:4:4", (4, 8))]
)
def test_misaligned_crop_is_refused(subsampling, origin):
    stream = Stream(codec="mjpeg", chroma_subsampling=subsampling)
    images = np.zeros((1, 32, 32, 3), np.uint8)
    with pytest.raises(ValueError, match="origin_px"):
        grey_images(images, stream, origin)
    profile = CameraProfile(sensor=Sensor(cfa="RGGB"), stream=stream)
    with pytest.raises(ValueError, match="block grid"):
        sensor_images(np.zeros((32, 32, 3)), profile, np.random.default_rng(0), 1, origin)


@pytest.mark.parametrize(
    ("subsampling", "factors"), [("4:4:4", (1, 1)), ("4:2:2", (2, 1)), ("4:2:0", (2, 2))]
)
def test_chroma_subsampling_reaches_the_file(frame, subsampling, factors):
    jpeg = encode_frame(
        frame[0, :64, :64, ::-1], Stream(codec="mjpeg", chroma_subsampling=subsampling)
    )
    assert jpeg[:2] == b"\xff\xd8"
    assert sof_sampling(jpeg) == factors


def test_lower_quality_is_smaller_and_coarser(frame):
    bgr = np.ascontiguousarray(frame[0, :256, :256, ::-1])
    sizes = [len(encode_frame(bgr, Stream(codec="mjpeg", quality=q))) for q in (30, 60, 95)]
    assert sizes[0] < sizes[1] < sizes[2]


def test_without_mjpeg_grey_is_rec601_of_the_colour(frame):
    rgb = frame[:, :100, :120].astype(float)
    expected = 0.299 * rgb[..., 0] + 0.587 * rgb[..., 1] + 0.114 * rgb[..., 2]
    out = grey_images(frame[:, :100, :120], Stream(codec="none"), (3, 5))
    assert np.abs(out - expected).max() <= 0.55  # rounding, and OpenCV's 14-bit fixed-point weights


def test_mjpeg_grey_is_close_to_the_raw_grey(frame):
    stream = Stream(codec="mjpeg", quality=90, chroma_subsampling="4:2:0")
    crop = cv2.GaussianBlur(frame[0, :256, :256], (0, 0), 1.5)[None]
    diff = grey_images(crop, stream).astype(float) - grey_images(crop, Stream()).astype(float)
    assert 0.0 < np.abs(diff).mean() < 2.0


def test_stream_stage_off_skips_mjpeg():
    # With the stage switched off a misaligned crop is fine and the grey is the raw conversion.
    profile = CameraProfile(
        lens=default_camera(), sensor=Sensor(cfa="RGGB"), stream=Stream(codec="mjpeg", quality=20)
    )
    plain = CameraProfile(sensor=Sensor(cfa="RGGB"))
    irradiance = np.random.default_rng(5).uniform(0, 1, (40, 48, 3))
    no_stream = tuple(s for s in STAGES if s != "stream")
    a = sensor_images(irradiance, profile, np.random.default_rng(1), 2, (3, 7), stages=no_stream)
    b = sensor_images(irradiance, plain, np.random.default_rng(1), 2, (3, 7))
    np.testing.assert_array_equal(a, b)
