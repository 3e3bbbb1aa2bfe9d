"""Tests of the optics stages against independent computations: an edge's spread equals the set
anisotropic PSF, a varying PSF equals each pixel's own kernel, relative illumination follows its
table, the image circle is dark beyond theta_max, lateral colour moves a point by its scale."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from renderers.camera_twin import optical_image
from renderers.optics import (
    anchor_axis,
    anchor_spacing,
    covariance,
    covariance_kernel,
    gaussian_kernel,
    lens_psf_field,
    lens_psf_plan,
)
from scenes.camera import default_camera
from scenes.profile import CameraProfile, LateralColour, PsfTable, RelativeIllumination

LENS = default_camera()  # equidistant: theta = r / f, so field positions have a closed form
F_PX = LENS.fx_px
CENTRE = np.array([LENS.cx_px, LENS.cy_px])
AZIMUTH = math.radians(20.0)  # keeps edge normals off the pixel axes
PSF = PsfTable(
    theta_deg=(0.0, 45.0, 90.0),
    sigma_radial_px=(1.0, 1.6, 2.4),
    sigma_tangential_px=(1.0, 1.2, 1.5),
)
erf = np.vectorize(math.erf)


def field_point(theta_deg: float, azimuth_rad: float = AZIMUTH) -> np.ndarray:
    """Full-frame pixel at field angle theta along an azimuth (equidistant lens)."""
    r = F_PX * math.radians(theta_deg)
    return CENTRE + r * np.array([math.cos(azimuth_rad), math.sin(azimuth_rad)])


def crop_around(point: np.ndarray, size: int) -> tuple[tuple[int, int], np.ndarray]:
    """Origin of a size x size crop centred near ``point`` and its pixel centres (H, W, 2)."""
    x0, y0 = (int(v) for v in np.floor(point) - size // 2)
    ys, xs = np.mgrid[y0 : y0 + size, x0 : x0 + size]
    return (x0, y0), np.stack([xs, ys], axis=-1).astype(float)


def area_fraction(d: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """Fraction of a unit pixel on the positive side of a line at signed distance ``d`` from its
    centre: the CDF of the sum of two uniforms of widths |n_x| and |n_y| (closed form)."""
    a, b = abs(normal[0]), abs(normal[1])
    s, t = (a + b) / 2.0, (a - b) / 2.0
    ramp = lambda x: np.maximum(x, 0.0) ** 2 / 2.0  # noqa: E731
    return (ramp(d + s) - ramp(d + t) - ramp(d - t) + ramp(d - s)) / (a * b)


def fit_erf_sigma(d: np.ndarray, v: np.ndarray) -> float:
    """Least-squares fit of v = lo + (hi - lo) Phi((d - d0) / s) by Gauss-Newton; returns s."""
    p = np.array([v.min(), v.max(), 0.0, 1.0])
    for _ in range(50):
        lo, hi, d0, s = p
        z = (d - d0) / s
        phi = 0.5 * (1.0 + erf(z / math.sqrt(2.0)))
        pdf = np.exp(-0.5 * z * z) / math.sqrt(2.0 * math.pi)
        r = v - (lo + (hi - lo) * phi)
        jac = np.column_stack([1.0 - phi, phi, -(hi - lo) * pdf / s, -(hi - lo) * pdf * z / s])
        step = np.linalg.lstsq(jac, r, rcond=None)[0]
        p = p + step
        if np.abs(step).max() < 1e-10:
            break
    return float(abs(p[3]))


# --- PSF --------------------------------------------------------------------------------------


@pytest.mark.parametrize("theta_deg", [30.0, 75.0])
@pytest.mark.parametrize("psi_deg", [0.0, 45.0, 90.0])
def test_edge_spread_equals_the_set_psf(theta_deg, psi_deg):
    # A straight edge through a field point, its normal at psi to the radial direction, rendered
    # by exact pixel area; after the PSF its ESF is an erf of variance n^T Sigma n + 1/12.
    point = field_point(theta_deg)
    origin, pixels = crop_around(point, 96)
    radial = np.array([math.cos(AZIMUTH), math.sin(AZIMUTH)])
    psi = math.radians(psi_deg)
    rot = np.array([[math.cos(psi), -math.sin(psi)], [math.sin(psi), math.cos(psi)]])
    normal = rot @ radial
    d = (pixels - point) @ normal
    along = (pixels - point) @ np.array([-normal[1], normal[0]])
    lo, hi = 0.1, 0.7
    radiance = lo + (hi - lo) * area_fraction(d, normal)
    radiance = np.repeat(radiance[..., None], 3, axis=-1).astype(np.float32)

    profile = CameraProfile(psf=PSF)
    out = optical_image(radiance, profile, origin, stages=("psf",))[..., 1].astype(float)
    band = (np.abs(along) <= 24) & (np.abs(d) <= 12)
    sigma = fit_erf_sigma(d[band], out[band])

    sr = np.interp(theta_deg, PSF.theta_deg, PSF.sigma_radial_px)
    st = np.interp(theta_deg, PSF.theta_deg, PSF.sigma_tangential_px)
    expected = sr**2 * math.cos(psi) ** 2 + st**2 * math.sin(psi) ** 2 + 1.0 / 12.0
    assert sigma**2 == pytest.approx(expected, rel=0.03)


@pytest.mark.parametrize(("sr", "st", "angle"), [(1.0, 1.0, 0.0), (2.0, 1.0, 0.6), (0.8, 2.5, 2.0)])
def test_kernel_covariance_is_the_set_one(sr, st, angle):
    k = gaussian_kernel(sr, st, angle).astype(float)
    ry, rx = k.shape[0] // 2, k.shape[1] // 2
    dy, dx = np.mgrid[-ry : ry + 1, -rx : rx + 1]
    assert k.sum() == pytest.approx(1.0, abs=1e-6)
    cov = np.array(
        [[np.sum(k * dx * dx), np.sum(k * dx * dy)], [np.sum(k * dx * dy), np.sum(k * dy * dy)]]
    )
    rot = np.array([[math.cos(angle), -math.sin(angle)], [math.sin(angle), math.cos(angle)]])
    expected = rot @ np.diag([sr**2, st**2]) @ rot.T
    np.testing.assert_allclose(cov, expected, atol=0.01 * max(sr, st) ** 2)


def test_uniform_psf_is_one_gaussian():
    sigma = 1.3
    profile = CameraProfile(
        psf=PsfTable(theta_deg=(0.0,), sigma_radial_px=(sigma,), sigma_tangential_px=(sigma,))
    )
    rng = np.random.default_rng(1)
    radiance = rng.uniform(0.0, 1.0, (80, 90, 3)).astype(np.float32)
    out = optical_image(radiance, profile, (900, 700), stages=("psf",))
    size = 2 * math.ceil(4 * sigma) + 1
    ref = cv2.GaussianBlur(radiance, (size, size), sigma, borderType=cv2.BORDER_REPLICATE)
    np.testing.assert_allclose(out, ref, atol=2e-5)


def test_varying_psf_equals_each_pixels_own_kernel():
    # A steep field (sigma_r 0.5 -> 3 px over the crop) on random texture: the result at
    # scattered pixels equals the direct sum with that pixel's own anisotropic kernel.
    psf = PsfTable(
        theta_deg=(40.0, 60.0), sigma_radial_px=(0.5, 3.0), sigma_tangential_px=(1.5, 1.0)
    )
    profile = CameraProfile(psf=psf)
    origin, pixels = crop_around(field_point(50.0), 200)
    rng = np.random.default_rng(2)
    radiance = cv2.GaussianBlur(rng.uniform(0.0, 1.0, (200, 200)), (0, 0), 1.0).astype(np.float32)
    out = optical_image(np.repeat(radiance[..., None], 3, -1), profile, origin, ("psf",))[..., 0]
    padded = np.pad(radiance.astype(float), 20, mode="edge")
    errors = []
    for y, x in rng.integers(20, 180, (40, 2)):
        offset = pixels[y, x] - CENTRE
        theta_deg = math.degrees(np.hypot(*offset) / F_PX)
        sr = np.interp(theta_deg, psf.theta_deg, psf.sigma_radial_px)
        st = np.interp(theta_deg, psf.theta_deg, psf.sigma_tangential_px)
        u = offset / np.hypot(*offset)
        dy, dx = np.mgrid[-20:21, -20:21]
        along, across = dx * u[0] + dy * u[1], -dx * u[1] + dy * u[0]
        k = np.exp(-0.5 * (along**2 / sr**2 + across**2 / st**2))
        patch = padded[y : y + 41, x : x + 41]  # centred on (y, x) of the crop
        errors.append(out[y, x] - np.sum(k * patch) / k.sum())
    assert np.max(np.abs(errors)) < 0.005 * np.ptp(radiance)


def test_profile_without_optics_returns_the_radiance():
    radiance = np.random.default_rng(3).uniform(0.0, 2.0, (2, 40, 50, 3)).astype(np.float32)
    out = optical_image(radiance, CameraProfile(), (1000, 800))  # inside the image circle
    np.testing.assert_array_equal(out, radiance)


# --- Relative illumination, image circle, lateral colour --------------------------------------


def test_relative_illumination_multiplies_by_the_table():
    ri = RelativeIllumination(theta_deg=(0.0, 45.0, 80.0, 95.0), value=(1.0, 0.8, 0.45, 0.3))
    origin, pixels = crop_around(field_point(60.0), 120)
    radiance = np.full((120, 120, 3), 0.5, np.float32)
    out = optical_image(
        radiance, CameraProfile(relative_illumination=ri), origin, ("relative_illumination",)
    )
    theta_deg = np.degrees(np.hypot(*(pixels - CENTRE).transpose(2, 0, 1)) / F_PX)
    expected = 0.5 * np.interp(theta_deg, ri.theta_deg, ri.value)
    np.testing.assert_allclose(out, np.repeat(expected[..., None], 3, -1), rtol=1e-5)


def test_image_circle_is_dark_beyond_theta_max():
    # 95 degrees is 1026 px from the centre: this crop on the horizontal axis straddles it.
    size = 128
    origin = (208, 908)
    ys, xs = np.mgrid[908 : 908 + size, 208 : 208 + size]
    theta_deg = np.degrees(np.hypot(xs - CENTRE[0], ys - CENTRE[1]) / F_PX)
    radiance = np.full((size, size, 3), 0.7, np.float32)
    out = optical_image(radiance, CameraProfile(), origin, ("image_circle",))
    outside = theta_deg > LENS.theta_max_deg + 1e-6
    inside = theta_deg < LENS.theta_max_deg - 1e-6
    assert outside.any() and inside.any()
    assert np.all(out[outside] == 0.0)
    assert np.all(out[inside] == np.float32(0.7))


def spot(pixels: np.ndarray, at: np.ndarray, sigma: float = 1.5) -> np.ndarray:
    return np.exp(-0.5 * np.sum((pixels - at) ** 2, axis=-1) / sigma**2)


def centroid(image: np.ndarray, pixels: np.ndarray) -> np.ndarray:
    w = image / image.sum()
    return np.array([np.sum(w * pixels[..., 0]), np.sum(w * pixels[..., 1])])


@pytest.mark.parametrize(
    ("table", "red", "blue"),
    [((0.0,), (1.004,), (0.996,)), ((0.0, 90.0), (1.0, 1.012), (1.0, 0.99))],
)
def test_lateral_colour_moves_a_point_by_its_scale(table, red, blue):
    colour = LateralColour(theta_deg=table, red_scale=red, blue_scale=blue)
    p0 = field_point(50.0)
    origin, pixels = crop_around(p0, 64)
    white = spot(pixels, p0)
    radiance = np.repeat(white[..., None], 3, -1).astype(np.float32)
    out = optical_image(radiance, CameraProfile(lateral_colour=colour), origin, ("lateral_colour",))
    for channel, scales in ((0, red), (2, blue)):
        # Light from p0 lands at q with q = c + s(theta(q)) (p0 - c): solved by iteration.
        q = p0.copy()
        for _ in range(20):
            s = np.interp(math.degrees(np.hypot(*(q - CENTRE)) / F_PX), table, scales)
            q = CENTRE + s * (p0 - CENTRE)
        # OpenCV's bicubic (a = -0.75) does not keep first moments: up to 0.05 px of bias.
        np.testing.assert_allclose(centroid(out[..., channel], pixels), q, atol=0.06)
        assert np.hypot(*(q - p0)) > 1.0  # the test moves the point by more than a pixel
    np.testing.assert_array_equal(out[..., 1], radiance[..., 1])


def per_cell_psf(image: np.ndarray, psf: PsfTable, origin: tuple[int, int]) -> np.ndarray:
    """The varying PSF as the module docstring states it, cell by cell, from scratch: each cell
    blurred by its mean covariance's kernel, then each pixel moved to its own (bilinear)
    covariance by the heat-equation stencil. (H, W) float64 image, float64 result."""
    field = lens_psf_field(psf.at, LENS, origin)
    height, width = image.shape
    spacing = anchor_spacing(image.shape, field)
    xs, ys = anchor_axis(width, spacing), anchor_axis(height, spacing)
    cov = covariance(*field(*np.meshgrid(xs, ys)))
    blur_pad = max(32, spacing)
    padded = np.pad(image, blur_pad, mode="edge")
    out = np.empty_like(image)
    for i in range(len(ys) - 1):
        y_hi = ys[i + 1] if i < len(ys) - 2 else height
        for j in range(len(xs) - 1):
            x_hi = xs[j + 1] if j < len(xs) - 2 else width
            corners = cov[i : i + 2, j : j + 2]
            kernel = covariance_kernel(corners.mean(axis=(0, 1))).astype(float)
            b = cv2.filter2D(padded, -1, kernel, borderType=cv2.BORDER_REPLICATE)
            for y in range(ys[i], y_hi):
                for x in range(xs[j], x_hi):
                    v, u = (y - ys[i]) / (ys[i + 1] - ys[i]), (x - xs[j]) / (xs[j + 1] - xs[j])
                    own = (1 - v) * ((1 - u) * corners[0, 0] + u * corners[0, 1]) + v * (
                        (1 - u) * corners[1, 0] + u * corners[1, 1]
                    )
                    hx, hy, q = (own - corners.mean(axis=(0, 1))) * [0.5, 0.5, 0.25]
                    # the blur at the crop's edge pixels continues the replicated image
                    n = b[blur_pad + y - 1 : blur_pad + y + 2, blur_pad + x - 1 : blur_pad + x + 2]
                    out[y, x] = (
                        n[1, 1]
                        + hx * (n[1, 2] + n[1, 0] - 2 * n[1, 1])
                        + hy * (n[2, 1] + n[0, 1] - 2 * n[1, 1])
                        + q * (n[2, 2] - n[2, 0] - n[0, 2] + n[0, 0])
                    )
    return np.maximum(out, 0.0)


@pytest.mark.parametrize(
    ("origin", "shape"),
    [((1400, 1000), (70, 90)), ((40, 900), (48, 130)), ((2500, 1850), (94, 92))],
)
def test_psf_plan_equals_the_per_cell_sum(origin, shape):
    # The plan (built once, reused) gives each pixel the per-cell first-order result, here
    # recomputed from scratch; the third crop touches the frame's corner, where pixels lie
    # beyond the image circle. Two images through one cached plan: the second is not stale.
    psf = PsfTable(
        theta_deg=(0.0, 50.0, 90.0),
        sigma_radial_px=(0.6, 1.4, 2.6),
        sigma_tangential_px=(0.6, 1.1, 1.4),
    )
    rng = np.random.default_rng(4)
    images = rng.uniform(0.0, 1.0, (2, *shape)).astype(np.float32)
    plan = lens_psf_plan(psf, LENS, origin, shape)
    assert len(plan.cells) > 1 and lens_psf_plan(psf, LENS, origin, shape) is plan
    for image in images:
        out = plan.apply(np.repeat(image[None, ..., None], 3, -1))[0]
        ref = per_cell_psf(image.astype(float), psf, origin)
        assert np.abs(out - ref[..., None]).max() <= 1e-6 * np.abs(ref).max()


def test_psf_plan_rejects_another_crop_size():
    plan = lens_psf_plan(PSF, LENS, (1000, 900), (40, 60))
    with pytest.raises(ValueError, match="plan is for"):
        plan.apply(np.zeros((1, 40, 61, 3), np.float32))
