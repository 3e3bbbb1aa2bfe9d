"""The frame renderer: the band bounds every marker, band and full frames agree where it matters."""

from __future__ import annotations

import numpy as np
import pytest

from bench.dataset.labels import corners_px
from renderers.frame_sampling import FrameSampling, marker_region
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


@pytest.mark.parametrize("block_px", [8, 16])
def test_band_and_zone_start_and_end_on_the_block_grid(block_px) -> None:
    """An MJPEG crop must start on the frame's block grid; the aligned boxes hold the exact ones."""
    camera = default_camera()
    exact = marker_region(camera, SPEC, margin_px=16)
    aligned = marker_region(camera, SPEC, margin_px=16, block_px=block_px)
    for a, e in zip(aligned, exact, strict=True):
        for start, length, full in ((a.x0, a.width, 2592), (a.y0, a.height, 1944)):
            assert start % block_px == 0
            assert (start + length) % block_px == 0 or start + length == full
        assert a.x0 <= e.x0 and a.x0 + a.width >= e.x0 + e.width
        assert a.y0 <= e.y0 and a.y0 + a.height >= e.y0 + e.height
        assert a.height - e.height < 2 * block_px  # grown by less than a block at each end
    assert aligned[0].width == 2592 and aligned[0].y0 == aligned[1].y0


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


ANGLES = np.zeros((4, 13, 2))
ANGLES[:, 6, 0] = np.linspace(0.3, 0.35, 4)
OFFSETS = np.tile([10.0, 0.0], (4, 1))


@pytest.mark.slow
def test_band_and_full_frame_agree_inside_the_zone(renderers) -> None:
    band, full = renderers[False], renderers[True]
    a = band.render(ANGLES, OFFSETS)
    b = full.render(ANGLES, OFFSETS)
    z = band.zone
    rows = slice(z.y0 - band.region.y0, z.y0 - band.region.y0 + z.height)
    cols = slice(z.x0, z.x0 + z.width)
    zone_band = a[rows, cols]
    zone_full = b[z.y0 : z.y0 + z.height, cols]
    np.testing.assert_allclose(zone_band, zone_full, rtol=1e-6, atol=1e-7)
    assert zone_band.std() > 0.01  # markers and foliage, not an empty picture
    assert b[: z.y0].any() and not np.isnan(b).any()  # the full frame renders above the band


@pytest.mark.slow
def test_render_checks_shapes(renderers) -> None:
    with pytest.raises(ValueError, match="angles"):
        renderers[False].render(np.zeros((3, 13, 2)), np.zeros((4, 2)))


@pytest.mark.slow
def test_frames_are_rgb_and_the_sky_has_its_colour(renderers) -> None:
    """Where rays escape, a pixel holds the sky's radiance in the sky's colour, channel by
    channel (computed here from the lighting preset and the camera's own rays)."""
    from renderers.window import Window

    full = renderers[True]
    rgb = full.render(ANGLES, OFFSETS)
    assert rgb.shape == (1944, 2592, 3) and rgb.dtype == np.float32
    top = Window(0, 0, 2592, 150)  # looking up, above the array and the foliage
    dirs, valid = full.camera.unproject(top.pixel_centres())
    sky = full.lighting.sky
    expected = sky.radiance(dirs.reshape(-1, 3)).reshape(top.shape)[..., None] * sky.color
    matches = np.isclose(rgb[:150], expected, rtol=1e-3).all(axis=-1)
    assert matches[valid].mean() > 0.99
    assert np.ptp(np.asarray(sky.color)) > 0.1  # a test that could tell channels apart


@pytest.mark.slow  # over a second of CPU: out of `make test-fast`
def test_pixel_gain_is_applied_per_pixel_on_the_drjit_side(variant) -> None:
    """A renderer given a per-pixel gain returns its plain frame times that gain, to float32
    rounding (the recorder folds the twin's relative illumination and image circle in so)."""
    if variant.startswith("scalar"):
        pytest.skip("frame rendering needs a JIT variant")
    from renderers.frames import FrameRenderer

    veg = build_vegetation(VegetationSpec("soft", "intermediate", (0.0,), seed=1), SPEC)
    parts = [(p.name, p.mesh, p.albedo_rgb) for p in veg.parts]
    sampling = FrameSampling(subframes=1, marker_spp=1, background_spp=1)
    rng = np.random.default_rng(6)
    gains = {}

    def gain_of(region):
        gains[region] = rng.uniform(0.0, 2.0, region.shape).astype(np.float32)
        gains[region][:, :7] = 0.0  # an edge off, as beyond the image circle
        return gains[region]

    args = (default_camera(), SPEC, parts, get_lighting("canopy"), sampling, 5)
    plain = FrameRenderer(*args).render(ANGLES[:1], OFFSETS[:1])
    scaled_renderer = FrameRenderer(*args, pixel_gain=gain_of)
    scaled = scaled_renderer.render(ANGLES[:1], OFFSETS[:1])
    gain = gains[scaled_renderer.region][..., None]
    np.testing.assert_allclose(scaled, plain * gain, rtol=2e-7, atol=0)
    assert plain.std() > 0.01 and not scaled[:, :7].any()
