"""A lone marker's full frame from its crop and the open sky (renderers/sky_frame.py): the sky
part against the sky's formula along independently computed rays, the frame against the frame
with every pixel traced, within that frame's own spread over seeds."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from renderers.sky_frame import sky_background
from renderers.window import ADAPTIVE_TOLERANCE
from scenes.camera import FisheyeCamera
from scenes.lighting import get_lighting

#: The prototype lens at half its size: the properties below do not depend on size (at a quarter
#: the marker is too small to be detected in every render).
SMALL = FisheyeCamera(1296, 972, 723.266 / 2, 723.266 / 2, 647.5, 485.5, theta_max_deg=92.5)


def _rays(lens: FisheyeCamera, px: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Equidistant rays through pixels, written out here (theta = r / f): unit directions and
    whether they lie inside the image circle."""
    dx, dy = (px[:, 0] - lens.cx_px) / lens.fx_px, (px[:, 1] - lens.cy_px) / lens.fy_px
    theta, phi = np.hypot(dx, dy), np.arctan2(dy, dx)
    dirs = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], -1)
    return dirs, theta <= np.radians(lens.theta_max_deg)


@pytest.mark.parametrize("lighting", ["sun", "backlit"])
def test_the_open_sky_is_the_sky_along_each_pixels_rays_and_black_outside_the_circle(lighting):
    """At the pixel centre; where the light changes across a pixel's 3 x 3 neighbourhood of
    centres by more than the adaptive tolerance (the circle's rim, the horizon), the mean of its
    2 x 2 sub-cells: every pixel the circle cuts among them."""
    lens = dataclasses.replace(SMALL, width_px=324, height_px=244, fx_px=SMALL.fx_px / 4,
                               fy_px=SMALL.fy_px / 4, cx_px=161.5, cy_px=121.5)  # fmt: skip
    preset = get_lighting(lighting)
    sky = sky_background(lens, preset, spp=4)
    assert sky.dtype == np.float32 and sky.shape == (lens.height_px, lens.width_px, 3)
    ys, xs = np.mgrid[0 : lens.height_px, 0 : lens.width_px]
    px = np.stack([xs, ys], -1).astype(float)

    def light(points):
        dirs, inside = _rays(lens, points.reshape(-1, 2))
        shape = points.shape[:-1]
        return np.where(inside, preset.sky.radiance(dirs), 0.0).reshape(shape), inside.reshape(
            shape
        )

    centre, _ = light(px)
    subs = [light(px + (ox, oy)) for oy in (-0.25, 0.25) for ox in (-0.25, 0.25)]
    inside = np.array([s[1] for s in subs])
    cut = inside.any(0) & ~inside.all(0)
    padded = np.pad(centre, 1, mode="edge")
    around = np.array([padded[dy : dy + lens.height_px, dx : dx + lens.width_px]
                       for dy in range(3) for dx in range(3)])  # fmt: skip
    hi, lo = around.max(0), around.min(0)
    near_edge = hi - lo > ADAPTIVE_TOLERANCE * (hi + 1e-12)
    assert cut.sum() > 100 and (cut <= near_edge).all()  # the rim crosses; each cut pixel is seen
    expected = np.where(near_edge, np.mean([s[0] for s in subs], axis=0), centre)
    np.testing.assert_allclose(
        sky, expected[..., None] * np.asarray(preset.sky.color), rtol=1e-5, atol=1e-7
    )
    assert (sky[~inside.any(0)] == 0).all() and (~inside.any(0)).sum() > 1000


def test_a_canopy_needs_every_pixel_traced():
    with pytest.raises(ValueError, match="lighting 'canopy': a canopy"):
        sky_background(SMALL, get_lighting("canopy"), spp=4)


@pytest.mark.slow
def test_a_frame_from_its_crop_is_within_the_traced_frames_seed_spread(variant):
    from renderers.marker_renderer import MarkerRenderer
    from renderers.window import Window
    from scenes.study import study_pose

    renderer = MarkerRenderer(SMALL, "4x4_50", 0, spp=4)
    T = study_pose(30.0, 20.0, 200.0)
    crop = renderer.crop(T, 13.2, 8)
    frame = renderer.render_frame("sun", T, 13.2, 8, seed=2)
    # the crop is the crop's own render, the rest the open sky, bit for bit
    inside = np.zeros(frame.shape[:2], bool)
    inside[crop.y0 : crop.y0 + crop.height, crop.x0 : crop.x0 + crop.width] = True
    own = renderer.render("sun", T, 13.2, crop, seed=2).radiance()
    assert np.array_equal(frame[inside].reshape(own.shape), own)
    assert np.array_equal(frame[~inside], sky_background(SMALL, get_lighting("sun"), 4)[~inside])
    traced = [
        renderer.render("sun", T, 13.2, Window.full(SMALL), seed).radiance() for seed in (1, 2)
    ]

    def apart(a, b):
        d = np.abs(a - b).sum(-1)
        return (d[~inside] > 1e-6).mean(), d[inside].mean()

    fast, spread = apart(frame, traced[1]), apart(traced[0], traced[1])
    assert spread[0] > 0 and spread[1] > 0  # the traced frame's own seeds differ
    assert fast[0] <= 1.5 * spread[0] and fast[1] <= 1.5 * spread[1], (fast, spread)


@pytest.mark.slow
def test_the_benchmarks_full_frame_is_checked_against_the_traced_frame(monkeypatch, capsys):
    import bench.benchmarks.cycles_scene as cycles_scene
    import bench.benchmarks.render as render

    real = render.profile_from_option
    monkeypatch.setattr(cycles_scene, "import_bpy", lambda: None)
    monkeypatch.setattr(
        render, "profile_from_option", lambda name: dataclasses.replace(real(name), lens=SMALL)
    )
    figures = render.bench_render(spp=4)
    printed = capsys.readouterr().out
    assert "crop + sky against every pixel traced" in printed
    assert {"project", "traced"} <= figures.keys()  # detection at this size: seed luck
    assert figures["within_seed_spread"], printed
    assert 0 < figures["against_traced"]["outside_differ"] < 0.01
