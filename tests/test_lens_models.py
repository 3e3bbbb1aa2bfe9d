"""The lens models beyond equidistant: exact inverses, their valid limits, a real 195 deg lens."""

import dataclasses
import math

import cv2
import numpy as np
import pytest

from scenes.camera import FisheyeCamera
from scenes.lens_models import valid_limit_rad

# TUM-VI cam0, 512 x 512, a 195 deg lens calibrated in three models (facts, as published):
# Basalt data/tumvi_512_ds_calib.json and tumvi_512_eucm_calib.json; ORB_SLAM3
# Examples/Monocular/TUM-VI.yaml (Kannala-Brandt). See ../shared/CAMERA_NOTES.md.
TUM_DS = dict(
    fx_px=158.28600034966977,
    fy_px=158.2743455478755,
    cx_px=254.96116578191653,
    cy_px=256.8894394501779,
    model="double_sphere",
    params=(-0.17213086034353243, 0.5931177593944744),
)
TUM_EUCM = dict(
    fx_px=191.14799836282189,
    fy_px=191.13150963902818,
    cx_px=254.9585771534443,
    cy_px=256.88154645599448,
    model="eucm",
    params=(0.6291060881178562, 1.0418067381860868),
)
TUM_KB4 = dict(
    fx_px=190.978477,
    fy_px=190.973307,
    cx_px=254.931706,
    cy_px=256.897442,
    model="kannala_brandt",
    params=(
        0.0034823894022493434,
        0.0007150348452162257,
        -0.0020532361418706202,
        0.00020293673591811182,
    ),
)
TUM_SIZE = dict(width_px=512, height_px=512)


def tum(lens: dict, theta_max_deg: float = 95.0) -> FisheyeCamera:
    return FisheyeCamera(**TUM_SIZE, **lens, theta_max_deg=theta_max_deg)


def rays(theta_rad: np.ndarray, azimuth_rad: np.ndarray) -> np.ndarray:
    st = np.sin(theta_rad)
    return np.stack(
        [st * np.cos(azimuth_rad), st * np.sin(azimuth_rad), np.cos(theta_rad) + 0 * st], axis=-1
    )


def random_directions(n: int, theta_max_rad: float, seed: int = 0) -> np.ndarray:
    """Uniform in solid angle up to theta_max (independent of any model)."""
    rng = np.random.default_rng(seed)
    cos_t = rng.uniform(math.cos(theta_max_rad), 1.0, n)
    return rays(np.arccos(cos_t), rng.uniform(0.0, 2.0 * math.pi, n))


def numeric_limit_deg(camera: FisheyeCamera, step_deg: float = 1e-3) -> float:
    """First angle where d(theta) stops increasing or is no longer finite and positive,
    found on a dense grid of the forward map alone (no inverse, no closed form)."""
    theta = np.radians(np.arange(step_deg, 180.0, step_deg))
    with np.errstate(all="ignore"):
        d = camera.distort(theta)
    good = np.isfinite(d[1:]) & (d[1:] > 0) & (np.diff(d) > 0)
    return 180.0 if good.all() else float(np.degrees(theta[np.argmin(good)]))


# An OCamCalib camera with a real-looking polynomial and affine (a0 < 0; c, d, e near 1, 0, 0).
OCAM_POL = (-206.517, 0.0, 2.207161e-03, -4.879622e-06, 1.865656e-08)
OCAM_AFFINE = (1.000330, 0.000219, 0.000257)  # c, d, e
OCAM_CENTRE = (241.800066, 394.552874)  # row, column


def ocam_camera(theta_max_deg: float = 110.0) -> FisheyeCamera:
    """Built as the scenes.camera docstring states: fx = S, fy = c S, shear = (e S, d S)."""
    c, d, e = OCAM_AFFINE
    s = -OCAM_POL[0]
    return FisheyeCamera(
        752, 480, s, c * s, OCAM_CENTRE[1], OCAM_CENTRE[0], theta_max_deg, "ocamcalib",
        OCAM_POL, (e * s, d * s),
    )  # fmt: skip


def ocam_cam2world(row, col, pol, xc, yc, c, d, e):
    """OCamCalib's cam2world from its published formulas: unit rays in OCamCalib's frame."""
    inv_det = 1.0 / (c - d * e)
    xp = inv_det * ((row - xc) - d * (col - yc))
    yp = inv_det * (-e * (row - xc) + c * (col - yc))
    r = np.hypot(xp, yp)
    zp = sum(a * r**i for i, a in enumerate(pol))
    n = np.sqrt(xp**2 + yp**2 + zp**2)
    return np.stack([xp / n, yp / n, zp / n], axis=-1)


def model_cameras() -> dict[str, FisheyeCamera]:
    """One camera per model, image circle close to the model's own limit."""
    cams = {
        "double_sphere": tum(TUM_DS, 126.0),
        "double_sphere_pole": dataclasses.replace(
            tum(TUM_DS), params=(-0.6, 0.1), theta_max_deg=59.7
        ),
        "eucm": tum(TUM_EUCM, 126.6),
        "ucm_fold": dataclasses.replace(
            tum(TUM_EUCM), model="ucm", params=(1.7,), theta_max_deg=126
        ),
        "ucm_pole": dataclasses.replace(
            tum(TUM_EUCM), model="ucm", params=(0.8,), theta_max_deg=143
        ),
        "kannala_brandt": tum(TUM_KB4, 170.0),
        "ocamcalib": ocam_camera(150.0),
    }
    sheared = dataclasses.replace(cams["eucm"], shear=(12.0, -7.0))
    return {**cams, "eucm_sheared": sheared}


@pytest.mark.parametrize("name", list(model_cameras()))
def test_round_trips_to_1e9_over_the_whole_image_circle(name):
    camera = model_cameras()[name]
    assert camera.theta_max_deg <= camera.theta_valid_max_deg
    dirs = random_directions(20000, camera.theta_max_rad)
    edge = rays(np.full(8, camera.theta_max_rad), np.linspace(0, 2 * np.pi, 8, endpoint=False))
    dirs = np.concatenate([dirs, edge, [[0.0, 0.0, 1.0]]])
    px = camera.project(dirs * 37.0)
    back, valid = camera.unproject(px)
    assert valid.all()
    assert np.abs(back - dirs).max() < 1e-9
    theta_back = camera.theta_of_pixel(px)
    assert np.abs(theta_back - np.arccos(np.clip(dirs[:, 2], -1, 1))).max() < 1e-9
    rng = np.random.default_rng(3)
    pixels = rng.uniform(-0.5, [camera.width_px - 0.5, camera.height_px - 0.5], (20000, 2))
    d, valid = camera.unproject(pixels)
    assert valid.any()
    assert np.abs(camera.project(d[valid]) - pixels[valid]).max() < 1e-9


def test_tum_vi_lens_in_three_models_agrees_within_a_pixel():
    cams = [tum(TUM_DS), tum(TUM_EUCM), tum(TUM_KB4)]
    theta = np.radians(np.arange(0.0, 95.5, 0.5))
    for azimuth_deg in (0.0, 45.0, 90.0, 180.0):
        r = rays(theta, np.full_like(theta, math.radians(azimuth_deg)))
        px = [c.project(r) for c in cams]
        for i in range(3):
            for j in range(i + 1, 3):
                assert np.abs(px[i] - px[j]).max() < 1.0, (azimuth_deg, i, j)


@pytest.mark.parametrize(
    "lens",
    [
        dict(model="double_sphere", params=(-0.17213086034353243, 0.5931177593944744)),
        dict(model="double_sphere", params=(0.5, 0.2)),
        dict(model="double_sphere", params=(-0.6, 0.1)),  # pole of the denominator
        dict(model="eucm", params=(0.6291060881178562, 1.0418067381860868)),
        dict(model="eucm", params=(0.3, 2.0)),
        dict(model="ucm", params=(1.7,)),
        dict(model="ucm", params=(0.8,)),
        dict(model="kannala_brandt", params=(-0.5, 0.0, 0.0, 0.0)),  # folds at sqrt(2/3) rad
        dict(model="kannala_brandt", params=TUM_KB4["params"]),  # increases up to 180
    ],
    ids=lambda lens: f"{lens['model']}{lens['params'][:2]}",
)
def test_valid_limit_is_where_the_forward_map_stops_increasing(lens):
    limit = math.degrees(valid_limit_rad(lens["model"], lens["params"]))
    probe = FisheyeCamera(**TUM_SIZE, fx_px=150.0, fy_px=150.0, cx_px=255.5, cy_px=255.5,
                          theta_max_deg=min(limit, 30.0), **lens)  # fmt: skip
    assert probe.theta_valid_max_deg == pytest.approx(limit, abs=1e-12)
    assert limit == pytest.approx(numeric_limit_deg(probe), abs=2e-3)
    if limit < 180.0:  # no longer increasing just past it, still increasing just before
        t, h = math.radians(limit), 1e-7
        d0, d_before, d_after = probe.distort(np.array([t, t - h, t + h]))
        assert d_before < d0 and not (d_after > d0)


def test_kannala_brandt_fold_is_the_root_of_the_derivative():
    # d = theta - 0.5 theta^3: d' = 1 - 1.5 theta^2 = 0 at sqrt(2/3), to 1e-9 rad
    assert valid_limit_rad("kannala_brandt", (-0.5, 0.0, 0.0, 0.0)) == pytest.approx(
        math.sqrt(2.0 / 3.0), abs=1e-12
    )


def test_double_sphere_above_alpha_half_has_a_limit_below_180_that_is_enforced():
    limit = tum(TUM_DS).theta_valid_max_deg
    assert 120.0 < limit < 180.0
    # the paper's own unprojection domain r^2 <= 1 / (2 alpha - 1) ends exactly at this limit
    edge = tum(TUM_DS, limit).distort(np.array(math.radians(limit)))
    assert edge**2 == pytest.approx(1.0 / (2 * TUM_DS["params"][1] - 1.0), rel=1e-9)
    camera = tum(TUM_DS, limit)
    beyond = rays(np.radians([limit + 0.5, 150.0]), np.zeros(2))
    assert np.isnan(camera.project(beyond)).all()
    with pytest.raises(ValueError, match=r"theta_max_deg=127.*valid limit of 126\.12"):
        tum(TUM_DS, 127.0)


def test_double_sphere_with_alpha_zero_is_the_unified_model():
    # alpha = 0 leaves s / (xi + c): Mei's unified model with the same xi and focal
    xi = 0.4
    ds = dataclasses.replace(tum(TUM_DS), params=(xi, 0.0), theta_max_deg=110.0)
    ucm = dataclasses.replace(ds, model="ucm", params=(xi,))
    dirs = random_directions(5000, math.radians(110.0), seed=4)
    assert np.abs(ds.project(dirs) - ucm.project(dirs)).max() < 1e-9


def test_ocamcalib_unprojection_matches_its_own_cam2world():
    camera = ocam_camera(170.0)
    rng = np.random.default_rng(5)
    pixels = rng.uniform(-0.5, [751.5, 479.5], (5000, 2))  # (x, y) = (column, row)
    dirs, valid = camera.unproject(pixels)
    assert valid.all()
    ref = ocam_cam2world(pixels[:, 1], pixels[:, 0], OCAM_POL, *OCAM_CENTRE, *OCAM_AFFINE)
    # OCamCalib's frame: x along rows (down), y along columns (right), z backwards
    ref_cam = np.stack([ref[:, 1], ref[:, 0], -ref[:, 2]], axis=-1)
    assert np.abs(dirs - ref_cam).max() < 1e-12


def test_ocamcalib_fold_of_the_polynomial_limits_the_field():
    pol = (-200.0, 0.0, 1e-3, -4e-6)  # theta(rho) turns back where rho P' - P = 0
    limit = valid_limit_rad("ocamcalib", pol)
    q = np.polynomial.Polynomial([-pol[0], 0.0, pol[2], 2 * pol[3]])
    rho = min(r.real for r in q.roots() if abs(r.imag) < 1e-12 and r.real > 0)
    assert limit == pytest.approx(math.atan2(rho, -np.polyval(pol[::-1], rho)), abs=1e-12)
    with pytest.raises(ValueError, match="valid limit"):
        dataclasses.replace(ocam_camera(), params=pol, theta_max_deg=math.degrees(limit) + 0.1)


@pytest.mark.parametrize("name", ["double_sphere", "eucm", "ocamcalib"])
def test_opencv_fit_reports_its_own_error(name):
    camera = model_cameras()[name]
    cv = camera.to_opencv()
    dirs = random_directions(5000, math.radians(89.0), seed=6)
    ref, _ = cv2.fisheye.projectPoints(dirs.reshape(-1, 1, 3), np.zeros(3), np.zeros(3),
                                       cv["K"], cv["D"])  # fmt: skip
    err = np.linalg.norm(ref.reshape(-1, 2) - camera.project(dirs), axis=-1).max()
    assert err <= cv["fit_max_err_px"] * 1.05 + 1e-6
    assert cv["fit_max_err_px"] < 1.0  # the Kannala-Brandt form follows these lenses to 89 deg
    assert FisheyeCamera.from_dict(camera.to_dict()) == camera


def test_field_of_view_in_the_image_of_the_equidistant_default():
    camera = FisheyeCamera(2592, 1944, 618.8, 618.8, 1295.5, 971.5, 95.0)
    h, v, diag = camera.fov_in_image_deg()
    half_v = math.degrees(972.0 / 618.8)  # equidistant: theta = r / f, below theta_max
    assert v == pytest.approx(2 * half_v, abs=1e-9)
    assert h == pytest.approx(190.0, abs=1e-9) and diag == pytest.approx(190.0, abs=1e-9)


@pytest.mark.parametrize(
    "model, params, field",
    [
        ("double_sphere", (1.2, 0.5), "xi"),
        ("double_sphere", (0.0, 1.5), "alpha"),
        ("eucm", (0.5, -1.0), "beta"),
        ("ucm", (-0.1,), "xi"),
        ("ocamcalib", (150.0, 0.0, 1e-3), "a0 < 0"),
        ("eucm", (0.5,), "alpha, beta"),
    ],
)
def test_bad_model_parameters_are_named(model, params, field):
    with pytest.raises(ValueError, match=field):
        dataclasses.replace(tum(TUM_DS), model=model, params=params, theta_max_deg=30.0)
