"""Path tracing ("path") against direct light: equal where nothing occludes or reflects the sky,
darker beside an occluder, brighter beside a white wall."""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh

from renderers.frame_sampling import FrameSampling
from scenes.array import ArraySpec
from scenes.camera import FisheyeCamera
from scenes.lighting import Lighting, Sky, get_lighting
from scenes.validation import FieldError

SPEC = ArraySpec()
OFFSET = np.array([300.0, 0.0])  # the array's (x, z) in the vegetation frame: tests the shift
ANGLES = np.zeros((1, SPEC.n_whiskers, 2))
# Camera frame, mm. A white panel facing the camera in front of the array (z < 138 mm), above
# it: its hemisphere (z < 100) holds nothing of the array. A wall at its right edge faces it.
PANEL = ((-80.0, -200.0, 100.0), (0.0, 150.0, 0.0), (160.0, 0.0, 0.0))  # corner, u, v: n = -z
WALL = ((80.0, -200.0, 0.0), (0.0, 0.0, 100.0), (0.0, 150.0, 0.0))  # n = -x


def small_camera() -> FisheyeCamera:
    """The default camera's lens at an eighth of its resolution: tiny frames, same geometry."""
    width, height = 324, 243
    f = (height / 2.0) / (math.pi / 2.0)
    return FisheyeCamera(width, height, f, f, (width - 1) / 2.0, (height - 1) / 2.0)


def quad(name: str, corner, u, v, albedo: float) -> tuple[str, trimesh.Trimesh, tuple]:
    """A rectangle facing u x v, in the vegetation frame (camera frame + the array's offset)."""
    c = np.asarray(corner) + [OFFSET[0], 0.0, OFFSET[1]]
    u, v = np.asarray(u), np.asarray(v)
    mesh = trimesh.Trimesh([c, c + u, c + u + v, c + v], [[0, 1, 2], [0, 2, 3]], process=False)
    return name, mesh, (albedo,) * 3


def panel_pixels(camera: FisheyeCamera, x_mm: tuple[float, float]) -> tuple[np.ndarray, ...]:
    """(rows, cols) of pixels that see the panel between ``x_mm`` (away from its other edges)."""
    x, y = np.meshgrid(np.linspace(*x_mm, 40), np.linspace(-185.0, -65.0, 60))
    points = np.stack([x.ravel(), y.ravel(), np.full(x.size, 100.0)], axis=-1)
    px = np.unique(np.round(camera.project(points)).astype(int), axis=0)
    return px[:, 1], px[:, 0]


@pytest.fixture(scope="module")
def frame(variant):
    """frame(lighting, integrator, wall albedo or None, seed=3, depth=3) -> (H, W, 3) radiance."""
    if variant.startswith("scalar"):
        pytest.skip("frame rendering needs a JIT variant")
    from renderers.frames import FrameRenderer

    def render(lighting, integrator, wall=None, seed=3, depth=3):
        parts = [quad("panel", *PANEL, albedo=0.9)]
        if wall is not None:
            parts.append(quad("wall", *WALL, albedo=wall))
        sampling = FrameSampling(
            marker_spp=1,
            background_spp=4,
            subframes=1,
            full_frame=True,
            integrator=integrator,
            path_depth=depth,
        )
        renderer = FrameRenderer(small_camera(), SPEC, parts, lighting, sampling, seed)
        return renderer.render(ANGLES, OFFSET[None])

    return render


@pytest.mark.parametrize(
    ("field", "kwargs"),
    [
        ("integrator", {"integrator": "bidir"}),
        ("path_depth", {"path_depth": 0}),
        ("path_depth", {"path_depth": 9}),
        ("path_depth", {"path_depth": 2.0}),
        ("path_depth", {"path_depth": True}),
    ],
)
def test_sampling_rejects_bad_light_paths(field, kwargs) -> None:
    with pytest.raises(FieldError, match=field):
        FrameSampling(**kwargs)


def test_marker_renderer_rejects_bad_light_paths() -> None:
    from renderers.marker_renderer import MarkerRenderer

    with pytest.raises(FieldError, match="integrator"):
        MarkerRenderer(small_camera(), "4x4_50", 0, integrator="photon")
    with pytest.raises(FieldError, match="path_depth"):
        MarkerRenderer(small_camera(), "4x4_50", 0, integrator="path", path_depth=0)


def test_open_panel_under_a_uniform_sky_is_the_same_in_path_and_direct(frame) -> None:
    """A uniform sky makes every escaping bounce carry the same radiance: path tracing has no
    Monte Carlo noise there and must equal the tabulated E(n) / pi of direct light."""
    lighting = Lighting("uniform", Sky(1.0, 1.0, 1.0, color=(0.8, 1.0, 1.2)))
    rows, cols = panel_pixels(small_camera(), (-70.0, 70.0))
    direct = frame(lighting, "direct")[rows, cols]
    path = frame(lighting, "path")[rows, cols]
    assert len(rows) > 300 and direct.min() > 0.5  # the panel is in view and lit
    np.testing.assert_allclose(path, direct, rtol=2e-3)


@pytest.mark.parametrize("name", ["lab", "sun"])
def test_open_panel_agrees_within_monte_carlo_error(frame, name) -> None:
    """A non-uniform sky (and the sun): path's mean over the panel equals direct's within its
    Monte Carlo error, and the pixels do carry that noise."""
    rows, cols = panel_pixels(small_camera(), (-70.0, 70.0))
    direct = frame(get_lighting(name), "direct")[rows, cols]
    path = frame(get_lighting(name), "path")[rows, cols]
    error = (path - direct).mean(axis=-1)
    assert abs(error.mean()) < 3 * error.std() / math.sqrt(len(error)) + 1e-4
    assert error.std() > 1e-3


def test_a_wall_occludes_and_reflects_the_sky_only_in_path(frame) -> None:
    lab = get_lighting("lab")
    rows, cols = panel_pixels(small_camera(), (55.0, 75.0))  # beside the wall
    open_direct = frame(lab, "direct")[rows, cols]
    np.testing.assert_array_equal(frame(lab, "direct", wall=0.0)[rows, cols], open_direct)
    open_path, black, white = (
        frame(lab, "path", wall=albedo)[rows, cols].mean() for albedo in (None, 0.0, 0.9)
    )
    assert black < 0.85 * open_path  # the wall hides much of the panel's sky
    assert white > black + 0.5 * (open_path - black)  # and a white one sends much of it back


def test_path_frames_are_deterministic_per_seed(frame) -> None:
    lab = get_lighting("lab")
    a, b = frame(lab, "path", wall=0.9), frame(lab, "path", wall=0.9)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, frame(lab, "path", wall=0.9, seed=4))


def test_study_marker_path_agrees_with_direct(variant) -> None:
    """A lone marker has nothing to bounce from: Mitsuba's path tracer over the sky equals the
    exact sky term on average over the crop (the sun is exact in both)."""
    from renderers.marker_renderer import MarkerRenderer
    from scenes.camera import default_camera
    from scenes.study import study_pose

    T = study_pose(30.0, 40.0, 200.0)
    means = []
    for integrator in ("direct", "path"):
        renderer = MarkerRenderer(default_camera(), "4x4_50", 0, spp=16, integrator=integrator)
        window = renderer.crop(T, 13.2, 8)
        means.append(renderer.render("sun", T, 13.2, window, seed=1).radiance().mean(axis=(0, 1)))
    np.testing.assert_allclose(means[1], means[0], rtol=0.02)
