"""The frame renderer: the band bounds every marker, band and full frames agree where it matters."""

from __future__ import annotations

import numpy as np
import pytest

from bench.labels import corners_px
from renderers.frames import FrameSampling, marker_region
from scenes.array import ArraySpec, T_cam_marker
from scenes.camera import default_camera
from scenes.lighting import get_lighting
from scenes.vegetation import VegetationSpec, build_vegetation

SPEC = ArraySpec()


def test_band_holds_every_marker_at_any_deflection() -> None:
    camera = default_camera()
    band, zone = marker_region(camera, SPEC, margin_px=0)
    rng = np.random.default_rng(3)
    angles = rng.uniform(-1.4, 1.4, (500, 13, 2))  # up to 80 degrees either way
    # the white carrier, the largest part of a marker, as a "marker" of its own size
    big = ArraySpec(marker_size_mm=2 * SPEC.marker_spec(0).carrier_half_mm)
    px = corners_px(camera, big, T_cam_marker(big, angles))
    assert not np.isnan(px).any()
    assert px[..., 1].min() >= zone.y0 and px[..., 1].max() <= zone.y0 + zone.height - 1
    assert px[..., 0].min() >= zone.x0 and px[..., 0].max() <= zone.x0 + zone.width - 1
    assert (band.x0, band.width) == (0, camera.width_px)
    assert band.height < camera.height_px / 8  # the shortcut is worth having


def test_sampling_rejects_bad_counts() -> None:
    with pytest.raises(ValueError, match="subframes"):
        FrameSampling(subframes=0)
    with pytest.raises(ValueError, match="marker_spp"):
        FrameSampling(marker_spp=1.5)


@pytest.fixture(scope="module")
def renderers(variant):
    if variant.startswith("scalar"):
        pytest.skip("frame rendering needs a JIT variant")
    from renderers.frames import FrameRenderer

    camera = default_camera()
    veg = build_vegetation(VegetationSpec("soft", "intermediate", (0.0,), seed=1), SPEC)
    parts = [(p.name, p.mesh, p.albedo_rgb) for p in veg.parts]
    return {
        full: FrameRenderer(
            camera, SPEC, parts, get_lighting("canopy"), FrameSampling(full_frame=full), seed=5
        )
        for full in (False, True)
    }


def test_band_and_full_frame_agree_inside_the_zone(renderers) -> None:
    band, full = renderers[False], renderers[True]
    angles = np.zeros((4, 13, 2))
    angles[:, 6, 0] = np.linspace(0.3, 0.35, 4)
    offsets = np.tile([10.0, 0.0], (4, 1))
    a = band.render(angles, offsets)
    b = full.render(angles, offsets)
    z = band.zone
    rows = slice(z.y0 - band.region.y0, z.y0 - band.region.y0 + z.height)
    cols = slice(z.x0, z.x0 + z.width)
    zone_band = a[rows, cols]
    zone_full = b[z.y0 : z.y0 + z.height, cols]
    np.testing.assert_allclose(zone_band, zone_full, rtol=1e-6, atol=1e-7)
    assert zone_band.std() > 0.01  # markers and foliage, not an empty picture
    assert b[: z.y0].any() and not np.isnan(b).any()  # the full frame renders above the band


def test_render_checks_shapes(renderers) -> None:
    with pytest.raises(ValueError, match="angles"):
        renderers[False].render(np.zeros((3, 13, 2)), np.zeros((4, 2)))
