"""Video writing/reading round trips, marker-corner fidelity, atomicity, damaged files, previews."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from bench.common.video import (
    VideoInfo,
    draw_preview,
    read_video,
    video_info,
    write_preview,
    write_video,
)

H, W = 240, 320
DICTIONARY = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50)


def smooth_frame(phase: float = 0.0) -> np.ndarray:
    """Gradients and a wide blob spanning 0-255: no edges for the codec to ring on."""
    y, x = np.mgrid[0:H, 0:W]
    blob = np.exp(-((x - 160 - 40 * phase) ** 2 + (y - 120) ** 2) / (2 * 50.0**2))
    return np.clip(0.4 * x + 0.3 * y + 150 * blob, 0, 255).astype(np.uint8)


def marker_frame(rng: np.random.Generator) -> np.ndarray:
    """Four 40-px markers with a white quiet zone at sub-pixel positions on a grey background.

    Drawn at 8x and area-averaged down, so edges are exact partial-pixel coverages; sensor-like
    noise (sigma 2 levels) on top.
    """
    ss, side, quiet = 8, 40, 8
    big = np.full((H * ss, W * ss), 90, np.uint8)
    for marker_id, (x, y) in enumerate(
        [(30.375, 40.625), (150.75, 30.25), (60.5, 150.875), (220.125, 140.5)]
    ):
        tile = cv2.copyMakeBorder(
            cv2.aruco.generateImageMarker(DICTIONARY, marker_id, side * ss),
            *[quiet * ss] * 4,
            cv2.BORDER_CONSTANT,
            value=255,
        )
        x0, y0 = round(x * ss), round(y * ss)
        big[y0 : y0 + tile.shape[0], x0 : x0 + tile.shape[1]] = tile
    small = cv2.resize(big, (W, H), interpolation=cv2.INTER_AREA).astype(float)
    return np.clip(small + rng.normal(0, 2, small.shape), 0, 255).astype(np.uint8)


def detect(image: np.ndarray) -> dict[int, np.ndarray]:
    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    corners, ids, _ = cv2.aruco.ArucoDetector(DICTIONARY, params).detectMarkers(image)
    assert ids is not None
    return {int(i): c.reshape(4, 2) for i, c in zip(ids.ravel(), corners, strict=True)}


def test_round_trip_count_size_and_fps(tmp_path):
    path = tmp_path / "v.mp4"
    assert write_video(path, (smooth_frame(i / 10) for i in range(12)), 15) == 12
    assert video_info(path) == VideoInfo(frame_count=12, fps=15.0, width=W, height=H)
    frames = list(read_video(path))
    assert len(frames) == 12
    assert all(f.shape == (H, W) and f.dtype == np.uint8 for f in frames)


def test_bgr_frames_are_read_back_as_grey(tmp_path):
    path = tmp_path / "v.mp4"
    grey = smooth_frame()
    write_video(path, [cv2.cvtColor(grey, cv2.COLOR_GRAY2BGR)] * 3, 10)
    frames = list(read_video(path))
    assert len(frames) == 3
    # Measured: max 3, mean 1.0 levels (rounding through BGR -> YCbCr -> BGR).
    error = np.abs(frames[0].astype(int) - grey)
    assert error.max() <= 4 and error.mean() < 1.5


def test_grey_values_preserved(tmp_path):
    frames = [smooth_frame(i / 5) for i in range(5)]
    write_video(tmp_path / "near.mp4", frames, 15)
    write_video(tmp_path / "lossless.mp4", frames, 15, qp=0)
    near = np.stack(list(read_video(tmp_path / "near.mp4"))).astype(int)
    lossless = np.stack(list(read_video(tmp_path / "lossless.mp4")))
    # Measured: max 2, mean 0.3 levels at the default qp 12; exact at qp 0 (full-range luma).
    assert np.abs(near - frames).max() <= 3
    assert np.abs(near - frames).mean() < 0.6
    np.testing.assert_array_equal(lossless, frames)


def test_marker_corners_survive_encoding(tmp_path):
    rng = np.random.default_rng(3)
    frames = [marker_frame(rng) for _ in range(4)]
    write_video(tmp_path / "m.mp4", frames, 15)
    shifts = []
    for original, decoded in zip(frames, read_video(tmp_path / "m.mp4"), strict=True):
        before, after = detect(original), detect(decoded)
        assert before.keys() == after.keys() == {0, 1, 2, 3}
        shifts += [np.linalg.norm(before[k] - after[k], axis=1) for k in before]
    shifts = np.concatenate(shifts)
    # Measured over 8 seeds: median 0.006-0.008 px, max 0.020-0.032 px.
    assert np.median(shifts) < 0.02
    assert shifts.max() < 0.08


@pytest.mark.slow
def test_full_size_mostly_black_frames(tmp_path):
    rng = np.random.default_rng(0)
    frames = []
    for _ in range(3):
        frame = np.zeros((1944, 2592), np.uint8)
        frame[850:1100] = rng.integers(60, 120, (250, 2592), dtype=np.uint8)
        frames.append(frame)
    path = tmp_path / "full.mp4"
    assert write_video(path, frames, 15) == 3
    assert video_info(path) == VideoInfo(3, 15.0, 2592, 1944)
    decoded = list(read_video(path))
    assert np.abs(decoded[1].astype(int) - frames[1]).mean() < 1.0
    assert not decoded[1][:800].any()


def test_failed_write_leaves_nothing_and_keeps_old_file(tmp_path):
    path = tmp_path / "v.mp4"
    write_video(path, [smooth_frame()] * 2, 15)
    old = path.read_bytes()

    def crashing():
        yield smooth_frame()
        yield smooth_frame()
        raise RuntimeError("renderer crashed")

    with pytest.raises(RuntimeError, match="renderer crashed"):
        write_video(path, crashing(), 15)
    with pytest.raises(RuntimeError, match="renderer crashed"):
        write_video(tmp_path / "new.mp4", crashing(), 15)
    assert [p.name for p in tmp_path.iterdir()] == ["v.mp4"]
    assert path.read_bytes() == old


@pytest.mark.parametrize(
    "frames",
    [
        [],
        [np.zeros((H, W), np.uint8), np.zeros((H, W, 3), np.uint8)],
        [np.zeros((H, W), np.float32)],
        [np.zeros((H, W + 1), np.uint8)],
    ],
    ids=["empty", "mixed-shapes", "float", "odd-width"],
)
def test_bad_frames_raise_and_leave_nothing(tmp_path, frames):
    with pytest.raises(ValueError):
        write_video(tmp_path / "v.mp4", frames, 15)
    assert list(tmp_path.iterdir()) == []


def test_random_bytes_are_not_a_video(tmp_path):
    path = tmp_path / "junk.mp4"
    path.write_bytes(np.random.default_rng(0).bytes(20_000))
    with pytest.raises(ValueError, match="not a readable video"):
        video_info(path)
    with pytest.raises(ValueError):
        list(read_video(path))


def test_truncated_file_is_detected(tmp_path):
    rng = np.random.default_rng(1)
    path = tmp_path / "v.mp4"
    write_video(path, (rng.integers(0, 256, (H, W), dtype=np.uint8) for _ in range(20)), 15)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(ValueError, match="truncated"):
        video_info(path)
    with pytest.raises(ValueError, match="truncated"):
        list(read_video(path))


def test_missing_file(tmp_path):
    with pytest.raises(FileNotFoundError):
        video_info(tmp_path / "nope.mp4")


SQUARE = np.array([[[40.25, 30.25], [80.25, 30.25], [80.25, 70.25], [40.25, 70.25]]])


def is_green(bgr: np.ndarray) -> bool:
    b, g, r = bgr.astype(int)
    return g > r + 40 and g > b + 40


def is_magenta(bgr: np.ndarray) -> bool:
    b, g, r = bgr.astype(int)
    return r > g + 40 and b > g + 40


def test_draw_preview_draws_at_the_corners_only():
    frame = np.full((120, 160), 100, np.uint8)
    out = draw_preview(frame, SQUARE, np.array([7]))
    assert out.shape == (120, 160, 3) and out.dtype == np.uint8
    assert (frame == 100).all()  # input untouched
    for x, y in SQUARE[0]:
        assert is_green(out[round(y), round(x)])
    assert is_green(out[30, 60])  # middle of the top edge
    np.testing.assert_array_equal(out[50, 60], [100, 100, 100])  # inside the square
    np.testing.assert_array_equal(out[110, 10], [100, 100, 100])  # far away


def test_draw_preview_hidden_markers_caption_and_missing_corners():
    frame = np.full((120, 160), 100, np.uint8)
    corners = np.concatenate([SQUARE, np.full((1, 4, 2), np.nan)])
    out = draw_preview(frame, corners, np.array([7, 8]), np.array([False, True]), "frame 3")
    assert is_magenta(out[30, 60])
    assert (out[:14, :60] != 100).any()  # caption box at the top left
    np.testing.assert_array_equal(out[110, 10], [100, 100, 100])
    with pytest.raises(ValueError):
        draw_preview(frame, SQUARE, np.array([1, 2]))


def test_write_preview_scales_frames_and_corners(tmp_path):
    n = 4
    full_res = np.array([[[100.5, 60.5], [180.5, 60.5], [180.5, 140.5], [100.5, 140.5]]])
    path = tmp_path / "preview.mp4"
    written = write_preview(
        path,
        (np.full((H, W), 100, np.uint8) for _ in range(n)),
        [full_res] * n,
        [np.array([3])] * n,
        [None] * n,
        [f"frame {i}" for i in range(n)],
        fps=15,
    )
    assert written == n
    assert video_info(path) == VideoInfo(n, 15.0, W // 2, H // 2)
    cap = cv2.VideoCapture(str(path))
    ok, bgr = cap.read()
    cap.release()
    assert ok
    # (x + 0.5) * 0.5 - 0.5: full-res (100.5, 60.5) -> preview (50, 30); edge midpoint (70, 30).
    assert is_green(bgr[30, 70])
    assert abs(int(bgr[100, 150, 1]) - 100) <= 3  # far from the drawing: still the grey frame


def test_write_preview_length_mismatch(tmp_path):
    with pytest.raises(ValueError):
        write_preview(
            tmp_path / "p.mp4",
            [np.zeros((H, W), np.uint8)] * 3,
            [SQUARE] * 2,
            [np.array([1])] * 3,
            [None] * 3,
            [None] * 3,
            fps=15,
        )
    assert list(tmp_path.iterdir()) == []
