"""Tests of the edge-line corner refinement (pipeline.refine) and detect_markers' "lines" option:
accuracy on noise-free renders through the fisheye, exact recovery on a synthetic image, and the
fallback to the input corners when refinement fails."""

from __future__ import annotations

import dataclasses
import warnings

import cv2
import numpy as np
import pytest

from pipeline.detect import DetectorConfig, detect_markers
from pipeline.refine import FAILURES, refine_corners_by_edges
from scenes.camera import FisheyeCamera, default_camera
from scenes.conventions import marker_corners_marker, transform_points
from scenes.marker import get_dictionary
from scenes.materials import BLACK_ALBEDO, WHITE_ALBEDO
from scenes.study import study_pose

ALPHAS_DEG = (0.0, 20.0, 40.0, 60.0, 85.0)
PHIS_DEG = (0.0, 30.0, 60.0)
MODULES = 6  # 4x4 dictionary: 4 code bits + the black border on each side


# --- Renders through the fisheye (Mitsuba)


def _render_grid(size_mm: float) -> list[dict]:
    pytest.importorskip("mitsuba")
    from bench.study.cells import cell_images, study_renderer
    from bench.study.config import Cell, StudyConfig
    from renderers.variant import init_worker
    from scenes.profile import Sensor, load_profile

    init_worker(None)
    # The ideal, noise-free camera: these tests measure the refinement, not the camera.
    camera = dataclasses.replace(
        load_profile("ideal"), sensor=Sensor(read_noise_e=0.0, full_well_e=1e7)
    )
    config = StudyConfig(images=1, lightings=("lab",), spp=64, camera=camera)
    renderer = study_renderer(config)
    cells = []
    for alpha in ALPHAS_DEG:
        for phi in PHIS_DEG:
            cell = Cell("lab", size_mm, alpha, phi)
            images, window, T_cam_marker = cell_images(config, cell, renderer, 1)
            corners = marker_corners_marker(size_mm)
            gt = camera.lens.project(transform_points(T_cam_marker, corners))
            cells.append(
                {
                    "alpha": alpha,
                    "phi": phi,
                    "image": images[0],
                    "offset": (window.x0, window.y0),
                    "gt": gt,
                    "camera": camera.lens,
                }
            )
    return cells


@pytest.fixture(scope="module")
def renders() -> dict[float, list[dict]]:
    return {size: _render_grid(size) for size in (13.2, 8.8)}


def _corner_errors(cells: list[dict], refinement: str) -> tuple[np.ndarray, int]:
    """Corner errors (px) of marker 0 over the cells where it is found, and how many those are."""
    config = DetectorConfig(corner_refinement=refinement)
    errors = []
    for cell in cells:
        found = [
            d
            for d in detect_markers(cell["image"], config, cell["offset"], camera=cell["camera"])
            if d.marker_id == 0
        ]
        if found:
            errors.append(np.linalg.norm(found[0].corners_px - cell["gt"], axis=1))
    return np.concatenate(errors) if errors else np.empty(0), len(errors)


@pytest.mark.slow
@pytest.mark.parametrize("size_mm", [13.2, 8.8])
def test_lines_corners_match_ground_truth_over_the_grid(renders, size_mm):
    cells = renders[size_mm]
    lines, n_lines = _corner_errors(cells, "lines")
    subpix, n_subpix = _corner_errors(cells, "subpix")
    # OpenCV itself misses the most foreshortened cells (13.2 mm: alpha 85 with phi 60; 8.8 mm:
    # phi 60); the refinement cannot change which markers are found.
    assert n_lines == n_subpix >= (13 if size_mm == 13.2 else 10)
    assert np.median(lines) <= 0.1, f"median {np.median(lines):.3f} px"
    assert lines.max() <= 0.5, f"max {lines.max():.3f} px"
    assert np.median(lines) < np.median(subpix)


# --- A synthetic marker, no renderer


def _near_pinhole_camera(size_px: int = 200) -> FisheyeCamera:
    """A fisheye with a very long focal length: within a few hundred pixels of the centre it is a
    pinhole camera to ~1e-5 px, so straight edges drawn in its image are straight in 3D."""
    c = (size_px - 1) / 2.0
    return FisheyeCamera(
        width_px=size_px, height_px=size_px, fx_px=20000.0, fy_px=20000.0, cx_px=c, cy_px=c
    )


def _srgb(linear: np.ndarray) -> np.ndarray:
    c = np.where(linear <= 0.0031308, 12.92 * linear, 1.055 * linear ** (1 / 2.4) - 0.055)
    return np.clip(np.round(255.0 * c), 0, 255).astype(np.uint8)


def _draw_marker(corners: np.ndarray, size_px: int = 200, supersample: int = 16) -> np.ndarray:
    """Marker 0 of 4x4_50 with the given outer corners (TL, TR, BR, BL; pixels), on white:
    point-sampled on a 16x grid, averaged in linear light, sRGB-encoded to uint8.

    The outer black square is an exact inside test of each fine pixel's centre (cv2.fillPoly
    fills boundary pixels, which would grow it by ~0.03 px per edge); the white code bits
    inside it, whose edges the refinement does not use, are filled with cv2.fillPoly.
    """
    bits = get_dictionary("4x4_50").generateImageMarker(0, MODULES, borderBits=1) > 127
    square = np.array([[0, 0], [MODULES, 0], [MODULES, MODULES], [0, MODULES]], np.float32)
    H = cv2.getPerspectiveTransform(square, corners.astype(np.float32))
    canvas = np.full((size_px * supersample,) * 2, WHITE_ALBEDO, np.float32)
    lo = np.floor(corners.min(axis=0)).astype(int) * supersample  # fine pixels around the square
    hi = np.ceil(corners.max(axis=0) + 1).astype(int) * supersample
    x, y = np.meshgrid(
        (np.arange(lo[0], hi[0]) + 0.5) / supersample - 0.5,
        (np.arange(lo[1], hi[1]) + 0.5) / supersample - 0.5,
    )  # centres, pixels
    inside = np.ones(x.shape, bool)
    for a, b in zip(corners, np.roll(corners, -1, axis=0), strict=True):  # clockwise on screen
        inside &= (b[0] - a[0]) * (y - a[1]) - (b[1] - a[1]) * (x - a[0]) > 0
    canvas[lo[1] : hi[1], lo[0] : hi[0]][inside] = BLACK_ALBEDO
    shift = 4  # fillPoly's fractional bits
    for row, col in zip(*np.nonzero(bits), strict=True):
        cell = np.array([[col, row], [col + 1, row], [col + 1, row + 1], [col, row + 1]], float)
        xy = cv2.perspectiveTransform(cell.reshape(-1, 1, 2), H)[:, 0]
        fine = np.round((supersample * (xy + 0.5) - 0.5) * (1 << shift)).astype(np.int32)
        cv2.fillPoly(canvas, [fine], WHITE_ALBEDO, cv2.LINE_8, shift)
    linear = cv2.resize(canvas, (size_px, size_px), interpolation=cv2.INTER_AREA)
    return _srgb(linear)


TRUE_CORNERS = np.array([[60.3, 55.7], [140.1, 62.4], [133.8, 141.9], [57.2, 135.55]])


def test_synthetic_marker_recovers_known_corners():
    camera = _near_pinhole_camera()
    image = _draw_marker(TRUE_CORNERS)
    rng = np.random.default_rng(1)
    start = TRUE_CORNERS + rng.uniform(-0.8, 0.8, size=(4, 2))
    refined = refine_corners_by_edges(image, start, camera, MODULES).corners_px
    # The method is exact here up to sampling: errors are ~0.003 px (0.1 px is the spec).
    assert np.linalg.norm(refined - TRUE_CORNERS, axis=1).max() < 0.02
    # A crop gives the same corners, in full-image pixels.
    x0, y0 = 31, 24
    crop = image[y0 : y0 + 150, x0 : x0 + 140]
    refined_crop = refine_corners_by_edges(
        crop, start, camera, MODULES, offset_px=(x0, y0)
    ).corners_px
    np.testing.assert_allclose(refined_crop, refined, atol=1e-4)


def test_synthetic_marker_through_detect_markers():
    camera = _near_pinhole_camera()
    image = _draw_marker(TRUE_CORNERS)
    found = detect_markers(image, DetectorConfig(corner_refinement="lines"), camera=camera)
    assert [d.marker_id for d in found] == [0]
    assert np.linalg.norm(found[0].corners_px - TRUE_CORNERS, axis=1).max() < 0.1
    subpix = detect_markers(image, DetectorConfig(corner_refinement="subpix"))[0].corners_px
    assert (
        np.linalg.norm(found[0].corners_px - TRUE_CORNERS, axis=1).mean()
        < np.linalg.norm(subpix - TRUE_CORNERS, axis=1).mean()
    )


def test_lines_needs_the_camera():
    image = _draw_marker(TRUE_CORNERS)
    with pytest.raises(ValueError, match="corner_refinement"):
        detect_markers(image, DetectorConfig(corner_refinement="lines"))


def test_other_refinements_ignore_the_camera():
    image = _draw_marker(TRUE_CORNERS)
    config = DetectorConfig(corner_refinement="subpix")
    plain = detect_markers(image, config)
    with_camera = detect_markers(image, config, camera=_near_pinhole_camera())
    assert len(plain) == len(with_camera) == 1
    np.testing.assert_array_equal(plain[0].corners_px, with_camera[0].corners_px)


def _ray_cast_marker(
    camera: FisheyeCamera, T_cam_marker: np.ndarray, size_mm: float, supersample: int = 16
) -> tuple[np.ndarray, tuple[int, int], np.ndarray]:
    """Marker 0 of 4x4_50 seen through the fisheye, by casting supersample^2 stratified rays per
    pixel at the marker plane: (sRGB uint8 crop, its offset, true corners in full-image px)."""
    bits = get_dictionary("4x4_50").generateImageMarker(0, MODULES, borderBits=1) > 127
    truth = camera.project(transform_points(T_cam_marker, marker_corners_marker(size_mm)))
    lo = np.floor(truth.min(axis=0)).astype(int) - 12
    hi = np.ceil(truth.max(axis=0)).astype(int) + 13
    fine = (np.arange(supersample) + 0.5) / supersample - 0.5
    xs = (np.arange(lo[0], hi[0])[:, None] + fine).ravel()
    ys = (np.arange(lo[1], hi[1])[:, None] + fine).ravel()
    samples = np.stack(np.meshgrid(xs, ys), axis=-1)
    # jittered within each fine cell, so that edges along the grid are not quantized to it
    samples += np.random.default_rng(0).uniform(-0.5, 0.5, samples.shape) / supersample
    rays, _ = camera.unproject(samples)
    R, t = T_cam_marker[:3, :3], T_cam_marker[:3, 3]
    along = (t @ R[:, 2]) / (rays @ R[:, 2])  # distance to the marker plane along each ray
    p = (rays * along[..., None] - t) @ R  # hit points in the marker frame (mm)
    module = size_mm / MODULES
    col = np.floor((p[..., 0] + size_mm / 2) / module).astype(int)
    row = np.floor((size_mm / 2 - p[..., 1]) / module).astype(int)
    on_marker = (along > 0) & (col >= 0) & (col < MODULES) & (row >= 0) & (row < MODULES)
    white = ~on_marker | bits[np.clip(row, 0, MODULES - 1), np.clip(col, 0, MODULES - 1)]
    albedo = np.where(white, WHITE_ALBEDO, BLACK_ALBEDO).astype(np.float32)
    linear = cv2.resize(albedo, (hi[0] - lo[0], hi[1] - lo[1]), interpolation=cv2.INTER_AREA)
    return _srgb(linear), (int(lo[0]), int(lo[1])), truth


@pytest.mark.parametrize(("alpha_deg", "phi_deg"), [(0, 0), (60, 30), (85, 45), (92, 20)])
def test_ray_cast_fisheye_marker_recovers_known_corners(alpha_deg, phi_deg):
    """Through the real fisheye, far off-axis (past 90 degrees too): exact up to sampling."""
    camera = default_camera()
    T_cam_marker = study_pose(alpha_deg, phi_deg, 200.0)
    crop, offset, truth = _ray_cast_marker(camera, T_cam_marker, 13.2)
    start = truth + np.random.default_rng(2).uniform(-0.7, 0.7, size=(4, 2))
    refined = refine_corners_by_edges(crop, start, camera, MODULES, offset_px=offset).corners_px
    assert np.linalg.norm(refined - truth, axis=1).max() < 0.05


# --- Failure: the input corners come back unchanged


@pytest.mark.parametrize("kind", ["noise", "flat", "outside", "collinear", "twisted", "nan"])
def test_failure_returns_the_input_corners(kind):
    camera = _near_pinhole_camera()
    rng = np.random.default_rng(0)
    start = TRUE_CORNERS + rng.uniform(-0.5, 0.5, size=(4, 2))
    image = _draw_marker(TRUE_CORNERS)
    if kind == "noise":
        image = rng.integers(0, 256, size=(200, 200), dtype=np.uint8)
    elif kind == "flat":
        image = np.full((200, 200), 128, np.uint8)
    elif kind == "outside":  # the marker is off the crop given
        image = image[:80, :80]
    elif kind == "collinear":
        start = np.array([[60.0, 60.0], [80.0, 80.0], [100.0, 100.0], [120.0, 120.0]])
    elif kind == "twisted":  # corners out of order: a bow tie
        start = start[[0, 2, 1, 3]]
    else:
        start[2, 0] = np.nan
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no RuntimeWarning either
        refined, failure = refine_corners_by_edges(image, start, camera, MODULES)
    np.testing.assert_array_equal(refined, start)
    assert failure in FAILURES  # the fallback says why, in words callers can count
    assert refined is not start and refined.dtype == np.float64


def test_bad_arguments_raise():
    camera = _near_pinhole_camera()
    with pytest.raises(ValueError, match="8-bit grey"):
        refine_corners_by_edges(np.zeros((10, 10)), TRUE_CORNERS, camera, MODULES)
    with pytest.raises(ValueError, match="transfer"):
        refine_corners_by_edges(
            np.zeros((10, 10), np.uint8), TRUE_CORNERS, camera, MODULES, transfer="gamma22"
        )
