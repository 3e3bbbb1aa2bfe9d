"""The fisheye camera model against independent computations."""

import dataclasses
import math

import cv2
import numpy as np
import pytest

from scenes.camera import FisheyeCamera, default_camera

KB = dict(model="kannala_brandt", params=(0.03, -0.004, 0.0006, -0.00004))


def cameras():
    base = default_camera()
    return [base, dataclasses.replace(base, **KB)]


def random_directions(n, theta_max_rad, seed=0):
    """Unit directions uniform in solid angle up to theta_max (independent of the model)."""
    rng = np.random.default_rng(seed)
    cos_t = rng.uniform(math.cos(theta_max_rad), 1.0, n)
    phi = rng.uniform(0, 2 * math.pi, n)
    sin_t = np.sqrt(1 - cos_t**2)
    return np.stack([sin_t * np.cos(phi), sin_t * np.sin(phi), cos_t], axis=-1)


@pytest.mark.parametrize("camera", cameras(), ids=["equidistant", "kannala_brandt"])
def test_project_unproject_round_trip_whole_field_of_view(camera):
    dirs = random_directions(20000, camera.theta_max_rad)
    dirs = np.concatenate([dirs, [[0, 0, 1.0], [1.0, 0, 0], [0, -1.0, 0]]])  # axis and 90 deg
    px = camera.project(dirs * 173.0)
    back, valid = camera.unproject(px)
    assert valid.all()
    assert np.abs(back - dirs).max() < 1e-9


@pytest.mark.parametrize("camera", cameras(), ids=["equidistant", "kannala_brandt"])
def test_unproject_project_round_trip_on_pixels(camera):
    rng = np.random.default_rng(1)
    px = rng.uniform([0, 0], [camera.width_px, camera.height_px], (20000, 2)) - 0.5
    dirs, valid = camera.unproject(px)
    assert 0.3 < valid.mean() < 1.0  # the image circle is cropped by the frame
    assert np.abs(camera.project(dirs[valid]) - px[valid]).max() < 1e-9


def test_equidistant_radius_is_f_theta_including_beyond_90_degrees():
    cam = default_camera()
    for theta_deg in (0.0, 10.0, 45.0, 89.0, 90.0, 93.0, 95.0):
        t = math.radians(theta_deg)
        px = cam.project(np.array([math.sin(t), 0.0, math.cos(t)]))
        assert px[0] - cam.cx_px == pytest.approx(cam.fx_px * t, abs=1e-9)
        assert px[1] == pytest.approx(cam.cy_px, abs=1e-9)


def test_default_camera_spans_180_degrees_over_the_image_height():
    cam = default_camera()
    assert (cam.width_px, cam.height_px) == (2592, 1944)
    assert (cam.cx_px, cam.cy_px) == (1295.5, 971.5)  # centre of the top-left pixel is (0, 0)
    top_edge = np.array([cam.cx_px, -0.5])  # the outer edge of the first row
    assert math.degrees(cam.theta_of_pixel(top_edge)) == pytest.approx(90.0, abs=1e-9)
    bottom_edge = np.array([cam.cx_px, cam.height_px - 0.5])
    assert math.degrees(cam.theta_of_pixel(bottom_edge)) == pytest.approx(90.0, abs=1e-9)


def test_beyond_theta_max_is_nan_and_outside_the_circle_is_invalid():
    cam = default_camera()
    t = math.radians(96.0)
    assert np.isnan(cam.project(np.array([math.sin(t), 0.0, math.cos(t)]))).all()
    _, valid = cam.unproject(np.array([[0.0, cam.cy_px], [cam.cx_px, cam.cy_px]]))
    assert valid.tolist() == [False, True]


def test_matches_opencv_fisheye_below_90_degrees():
    cam = cameras()[1]
    dirs = random_directions(5000, math.radians(85), seed=2)
    cv = cam.to_opencv()
    ref, _ = cv2.fisheye.projectPoints(
        (dirs * 250.0).reshape(-1, 1, 3), np.zeros(3), np.zeros(3), cv["K"], cv["D"]
    )
    assert np.abs(ref.reshape(-1, 2) - cam.project(dirs * 250.0)).max() < 1e-6


@pytest.mark.parametrize("camera", cameras(), ids=["equidistant", "kannala_brandt"])
def test_interchange_round_trips(camera):
    cv = camera.to_opencv()
    assert FisheyeCamera.from_opencv(cv["K"], cv["D"], cv["size"], camera.theta_max_deg) == camera
    assert FisheyeCamera.from_dict(camera.to_dict()) == camera


def test_camera_file_missing_fields_are_named():
    data = default_camera().to_dict()
    del data["model"]["fx_px"]
    with pytest.raises(ValueError, match="fx_px"):
        FisheyeCamera.from_dict(data)
    with pytest.raises(ValueError, match="model"):
        FisheyeCamera.from_dict({"opencv_fisheye": {}})


@pytest.mark.parametrize(
    "change, field",
    [
        (dict(width_px=0), "width_px"),
        (dict(fx_px=-1.0), "fx_px"),
        (dict(theta_max_deg=180.0), "theta_max_deg"),
        (dict(model="pinhole"), "model"),
        (dict(params=(0.1, 0.0, 0.0, 0.0)), "params"),  # parameters on the equidistant model
        (dict(model="kannala_brandt", params=(0.1,)), "params"),  # KB takes 4
        (dict(model="kannala_brandt", params=(-0.5, 0.0, 0.0, 0.0)), "theta_max_deg"),  # folds
        (dict(shear=(1.0,)), "shear"),
        (dict(cx_px=float("nan")), "cx_px"),
    ],
)
def test_bad_camera_fields_raise(change, field):
    with pytest.raises(ValueError, match=field):
        dataclasses.replace(default_camera(), **change)


@pytest.mark.slow
@pytest.mark.parametrize(
    "k, shear",
    [
        ((0.0, 0.0, 0.0, 0.0), (0.0, 0.0)),
        ((0.02, -0.01, 0.0, 0.0), (0.0, 0.0)),
        ((0.02, -0.01, 0.0, 0.0), (25.0, -40.0)),
    ],
)
def test_image_circle_box_holds_every_visible_pixel_and_little_else(k, shear):
    camera = FisheyeCamera(1200, 900, 300.0, 310.0, 611.3, 447.8, 95.0, "kannala_brandt", k, shear)
    x0, y0, x1, y1 = camera.image_circle_box(margin_px=0)
    # independent: project rays at theta_max all around the circle
    phi = np.linspace(0, 2 * np.pi, 3601)
    t = np.radians(95.0)
    edge = camera.project(
        np.stack(
            [np.sin(t) * np.cos(phi), np.sin(t) * np.sin(phi), np.cos(t) * np.ones_like(phi)], -1
        )
        * 0.999999
    )
    assert x0 <= edge[:, 0].min() < x0 + 1 and x1 - 2 < edge[:, 0].max() <= x1
    assert y0 <= max(edge[:, 1].min(), 0) and min(edge[:, 1].max(), camera.height_px) <= y1
    ys, xs = np.mgrid[0 : camera.height_px, 0 : camera.width_px]
    _, valid = camera.unproject(np.stack([xs, ys], -1).astype(float))
    outside = np.ones_like(valid)
    outside[y0:y1, x0:x1] = False
    assert not (valid & outside).any()
    assert camera.image_circle_box() == (x0 - 8, max(y0 - 8, 0), x1 + 8, min(y1 + 8, 900))


def test_older_camera_files_with_k_still_load():
    legacy = default_camera().to_dict()
    model = legacy["model"]
    del model["params"], model["shear"]
    model["k"] = [0.0, 0.0, 0.0, 0.0]
    assert FisheyeCamera.from_dict(legacy) == default_camera()
    model.update(model="kannala_brandt", k=list(KB["params"]))
    assert FisheyeCamera.from_dict(legacy) == cameras()[1]
    model["params"] = list(KB["params"])
    with pytest.raises(ValueError, match="'params' or the older 'k'"):
        FisheyeCamera.from_dict(legacy)


def test_unknown_camera_file_field_is_named():
    data = default_camera().to_dict()
    data["model"]["focal"] = 3.0
    with pytest.raises(ValueError, match="focal"):
        FisheyeCamera.from_dict(data)


def test_opencv_form_of_kannala_brandt_is_exact_and_skew_is_refused():
    cv = cameras()[1].to_opencv()
    assert cv["fit_max_err_px"] < 1e-9
    assert cv["D"].tolist() == list(KB["params"])
    K = cv["K"].copy()
    K[0, 1] = 5.0  # cv2.fisheye ignores skew: a K with one would not mean what it says
    with pytest.raises(ValueError, match="skew"):
        FisheyeCamera.from_opencv(K, cv["D"], cv["size"])
