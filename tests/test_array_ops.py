"""One camera model, two array namespaces: NumPy (labels) and Dr.Jit (the renderer's rays).

The same code runs over :data:`scenes.array_ops.NUMPY` and :class:`renderers.drjit_ops.DrJitOps`;
for every lens model the two give the same pixels and rays to 1e-6 px, and the sky terms agree.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from test_lens_models import model_cameras, random_directions

from renderers.sky_irradiance import irradiance
from scenes.camera import default_camera
from scenes.lighting import get_lighting

CAMERAS = {**model_cameras(), "default": default_camera()}


@pytest.fixture(scope="module")
def dj(variant):
    if variant.startswith("scalar"):
        pytest.skip("Dr.Jit array code needs a JIT variant")
    from renderers.drjit_ops import DrJitOps

    return DrJitOps()


def _np(a) -> np.ndarray:
    return np.asarray(a.numpy() if hasattr(a, "numpy") else a)


@pytest.mark.parametrize("name", list(CAMERAS))
def test_unproject_agrees_to_1e6_px(dj, name):
    """Random pixels over the image (inside and outside the circle): the rays NumPy and Dr.Jit
    give project back (by NumPy) to within 1e-6 px of each other, validity identical."""
    cam = CAMERAS[name]
    rng = np.random.default_rng(1)
    px = rng.uniform([-0.5, -0.5], [cam.width_px - 0.5, cam.height_px - 0.5], (20000, 2))
    ref, valid = cam.unproject(px)
    *d, valid_dj = cam.unproject_xy(dj.Float(px[:, 0]), dj.Float(px[:, 1]), dj)
    got = np.stack([_np(c) for c in d], axis=-1)
    np.testing.assert_array_equal(_np(valid_dj), valid)
    assert valid.sum() > 1000
    err = np.linalg.norm(cam.project(got[valid]) - cam.project(ref[valid]), axis=-1)
    assert np.nanmax(err) < 1e-6
    angle = np.arccos(np.clip(np.sum(got[valid] * ref[valid], axis=-1), -1, 1))
    assert angle.max() < 1e-9 * 1000  # radians: far below a pixel's 1e-3 rad


@pytest.mark.parametrize("name", list(CAMERAS))
def test_project_agrees_to_1e6_px(dj, name):
    cam = CAMERAS[name]
    dirs = random_directions(20000, math.radians(min(cam.theta_max_deg + 10, 179.0)))
    ref = cam.project(dirs)
    got = np.stack(
        [_np(c) for c in cam.project_xyz(*(dj.Float(dirs[:, i]) for i in range(3)), dj)], -1
    )
    np.testing.assert_array_equal(np.isnan(got), np.isnan(ref))
    assert np.isnan(ref[:, 0]).sum() > 0 or cam.theta_max_deg > 169
    assert np.nanmax(np.abs(got - ref)) < 1e-6


def test_dr_jit_table_lookups_match_numpy(dj):
    """searchsorted and interp, which the Newton inverses start from, agree with NumPy's."""
    rng = np.random.default_rng(2)
    fs = np.cumsum(rng.uniform(0.1, 1.0, 300))
    xs = np.linspace(0.0, 5.0, 300)
    y = rng.uniform(fs[0], fs[-1], 5000)
    np.testing.assert_array_equal(_np(dj.searchsorted(fs, dj.Float(y))), np.searchsorted(fs, y))
    np.testing.assert_allclose(_np(dj.interp(dj.Float(y), fs, xs)), np.interp(y, fs, xs), 1e-12)


@pytest.mark.parametrize("preset", ["sun", "backlit"])
def test_sky_terms_agree(dj, preset):
    """The sky's radiance along rays and its irradiance on normals: NumPy and Dr.Jit agree."""
    sky = get_lighting(preset).sky
    dirs = random_directions(5000, math.pi, seed=3)
    cols = [dj.Float(dirs[:, i]) for i in range(3)]
    np.testing.assert_allclose(_np(sky.radiance_xyz(*cols, dj)), sky.radiance(dirs), 1e-12)
    np.testing.assert_allclose(_np(irradiance(sky, cols, dj)), irradiance(sky, dirs), 1e-10)
