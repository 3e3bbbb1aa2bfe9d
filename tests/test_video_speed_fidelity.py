"""The video speed-ups change nothing they claim to keep: the threaded writers leave the same
files (or none on failure), and adaptive sampling stays within the reference's own seed spread."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from bench.common.video import BackgroundWriter, read_video, write_video
from renderers.frame_sampling import FrameSampling
from scenes.array import ArraySpec
from scenes.camera import default_camera
from scenes.lighting import get_lighting
from scenes.vegetation import VegetationSpec, build_vegetation

SPEC = ArraySpec()


def _frames(n: int) -> list[np.ndarray]:
    rng = np.random.default_rng(4)
    return [rng.integers(0, 256, (64, 96), dtype=np.uint8) for _ in range(n)]


def test_background_writer_writes_the_same_file_as_a_direct_write(tmp_path) -> None:
    frames = _frames(5)
    write_video(tmp_path / "direct.mp4", frames, 15.0)
    with BackgroundWriter(lambda it: write_video(tmp_path / "thread.mp4", it, 15.0)) as w:
        for f in frames:
            w.put(f)
    assert w.count == 5
    assert (tmp_path / "thread.mp4").read_bytes() == (tmp_path / "direct.mp4").read_bytes()
    assert len(list(read_video(tmp_path / "thread.mp4"))) == 5


def test_background_writer_leaves_no_file_when_the_producer_fails(tmp_path) -> None:
    writer = BackgroundWriter(lambda it: write_video(tmp_path / "v.mp4", it, 15.0))
    with pytest.raises(KeyError), writer:
        writer.put(_frames(1)[0])
        raise KeyError("render failed")
    assert list(tmp_path.iterdir()) == []


def test_background_writer_hands_the_writers_error_to_the_producer(tmp_path) -> None:
    bad = np.zeros((63, 96), np.uint8)  # odd height: the writer refuses it
    writer = BackgroundWriter(lambda it: write_video(tmp_path / "v.mp4", it, 15.0))
    with pytest.raises(ValueError, match="even"), writer:
        for _ in range(6):
            writer.put(bad)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.slow
def test_adaptive_frames_are_within_the_seed_spread(variant) -> None:
    """Against an all-samples reference: pixels that got every sample are bit-identical, and
    the pixels that differ are fewer and differ less than between two seeds of the reference."""
    if variant.startswith("scalar"):
        pytest.skip("frame rendering needs a JIT variant")
    from renderers.frames import FrameRenderer

    veg = build_vegetation(VegetationSpec("soft", "intermediate", (0.0,), seed=1), SPEC)
    parts = [(p.name, p.mesh, p.albedo_rgb) for p in veg.parts]
    angles = np.zeros((4, 13, 2))
    angles[:, 6, 0] = np.linspace(0.3, 0.35, 4)  # a whisker moving within the exposure
    offsets = np.tile([10.0, 0.0], (4, 1))
    base = (default_camera(), SPEC, parts, get_lighting("sun"))

    def render(adaptive: bool, seed: int) -> tuple[np.ndarray, FrameRenderer]:
        r = FrameRenderer(*base, FrameSampling(adaptive=adaptive), seed=seed)
        return r.render(angles, offsets), r

    ref1, _ = render(False, 5)
    ref2, _ = render(False, 6)
    fast, renderer = render(True, 5)
    assert renderer.rays_traced < 0.8 * renderer.rays_per_frame  # the shortcut saves rays
    lum = np.array([0.2126, 0.7152, 0.0722], np.float32)
    d_fast, d_seed = np.abs((fast - ref1) @ lum), np.abs((ref2 - ref1) @ lum)
    assert (d_fast > 1e-4).mean() < 0.5 * (d_seed > 1e-4).mean()
    assert d_fast.mean() < 0.5 * d_seed.mean()
    assert np.percentile(d_fast, 99.9) <= np.percentile(d_seed, 99.9)
    same = (fast == ref1).all(axis=2)
    assert same.mean() > 0.8 and d_seed.max() > 0.1  # a test that could tell


def test_adaptive_is_off_by_default_and_leaves_the_settings_hash() -> None:
    from bench.dataset.config import DatasetConfig

    plain = DatasetConfig()
    assert not plain.sampling.adaptive and "adaptive" not in plain.to_json()["sampling"]
    fast = dataclasses.replace(plain, sampling=FrameSampling(adaptive=True))
    assert fast.settings_hash() != plain.settings_hash()


@pytest.mark.slow
def test_still_frames_reuse_the_optical_image_and_match_a_fresh_render(variant, pair_config):
    """A frame whose array and path equal the previous frame's (the still lead-in) is recorded
    from that frame's optical image, and comes out byte for byte as rendering it again would."""
    from bench.dataset.config import default_profile
    from bench.dataset.sample import sample_recorder, simulate_sample

    if variant.startswith("scalar"):
        pytest.skip("frame rendering needs a JIT variant")
    config = dataclasses.replace(  # the pair's setting through the camera twin's optics
        pair_config,
        camera=default_profile(),
        branches=((0.0,),),
        frames_step=6,
        sampling=FrameSampling(marker_spp=1),
    )
    sample = config.samples()[0]
    sim = simulate_sample(config, sample)
    reusing, fresh = (sample_recorder(config, sample, sim) for _ in range(2))
    still = [f for f in range(1, 5) if reusing.still_as(f, f - 1)]
    assert still and not reusing.still_as(4, 3)  # a lead-in, then motion
    for f in range(5):
        expected = fresh.twin.record(fresh.radiance(f))
        np.testing.assert_array_equal(reusing.frame(f), expected, err_msg=f"frame {f}")
    assert reusing.frames_reused == len(still)
    # rendered only the frames that moved (rays counted, not timed: timing is the benchmark's)
    assert reusing.renderer.rays_traced == fresh.renderer.rays_traced * (5 - len(still)) // 5


@pytest.mark.slow
def test_the_twin_beside_the_render_writes_the_serial_frames(variant, pair_config, tmp_path):
    """run_sample records frame f in the twin's thread while f + 1 renders: its video is byte
    for byte the video of the same frames rendered and recorded one after another (the still
    lead-in's reuse included)."""
    from bench.dataset.config import default_profile
    from bench.dataset.sample import run_sample, sample_recorder, simulate_sample

    if variant.startswith("scalar"):
        pytest.skip("frame rendering needs a JIT variant")
    config = dataclasses.replace(
        pair_config, camera=default_profile(), branches=((0.0,),), frames_step=6,
        sampling=FrameSampling(marker_spp=1),
    )  # fmt: skip
    sample = config.samples()[0]
    record = run_sample(config, sample, tmp_path / "data")
    assert record["timing_s"]["frames_reused"] > 0  # a still lead-in, reused in the thread
    sim = simulate_sample(config, sample)
    serial = sample_recorder(config, sample, sim)
    frames = [serial.frame(f) for f in range(len(sim.times_s))]
    write_video(tmp_path / "serial.mp4", frames, sim.motion.fps)
    video = tmp_path / "data" / sample.sample_id / "video.mp4"
    assert video.read_bytes() == (tmp_path / "serial.mp4").read_bytes()
