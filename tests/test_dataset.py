"""Dataset generation end to end: files, labels against pixels, resume, determinism, bad options."""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys

import numpy as np
import pandas as pd
import pytest

from bench.dataset.config import DatasetConfig, DatasetConfigError, SampleSpec
from bench.dataset.labels import corners_of_frame
from bench.dataset.sample import simulate_sample
from scenes.profile import (
    CameraProfile,
    LateralColour,
    PsfTable,
    RelativeIllumination,
    Sensor,
    Stream,
    load_profile,
)

#: The ideal camera: these tests check that 98% of the labeled markers are found, a check of the
#: renderer and labels that an optics-limited twin would turn into a finding about its optics
#: (the COLOUR twin below loses 5 of 13 markers in frame 0).
IDEAL = load_profile("ideal")
SMALL = {
    "foliage": ("soft",),
    "distances": ("intermediate",),
    "branches": ((0.0,),),
    "protocols": ("outdoor",),
    "lightings": ("lab",),
    "passes": 1,
    "frames_step": 4,
    "camera": IDEAL,
}
#: A colour twin with every stage on: field-dependent anisotropic PSF, lateral colour, fall-off,
#: RGGB mosaic and 4:2:0 MJPEG (a test profile, not a measured camera).
COLOUR = CameraProfile(
    name="test-colour",
    relative_illumination=RelativeIllumination((0.0, 90.0), (1.0, 0.5)),
    psf=PsfTable((0.0, 90.0), (0.6, 1.5), (0.5, 1.0)),
    lateral_colour=LateralColour((0.0, 90.0), (1.0, 1.002), (1.0, 0.998)),
    sensor=Sensor(cfa="RGGB", full_well_e=7100.0, read_noise_e=2.9),
    stream=Stream(codec="mjpeg", quality=80, chroma_subsampling="4:2:0"),
)


@pytest.fixture(scope="module")
def dataset(tmp_path_factory, variant):
    if variant.startswith("scalar"):
        pytest.skip("frame rendering needs a JIT variant")
    from bench.dataset.generate import run_dataset

    out = tmp_path_factory.mktemp("data")
    config = DatasetConfig(**SMALL)
    manifest = run_dataset(config, out, variant=variant, progress=False)
    return config, out, manifest


@pytest.mark.slow
def test_sample_files_and_manifest(dataset) -> None:
    from bench.common.manifest import sha256
    from bench.common.video import video_info

    config, out, manifest = dataset
    sample = config.samples()[0]
    folder = out / sample.sample_id
    record = json.loads((folder / "sample.json").read_text())
    labels = pd.read_parquet(folder / "labels.parquet")
    info = video_info(folder / "video.mp4")
    assert info.frame_count == labels["frame"].nunique() == record["frames"]
    assert (info.width, info.height, info.fps) == (2592, 1944, 15.0)
    assert video_info(folder / "preview.mp4").frame_count == record["frames"]
    assert len(labels) == 13 * record["frames"]
    assert record["branch_gaps"] == [[6, 7]] and record["branches_mm"] == [0.0]
    for name, digest in record["files"].items():
        assert sha256(folder / name) == digest == manifest["files"][f"{sample.sample_id}/{name}"]
    assert load_profile(folder / "camera.json") == config.camera
    assert manifest["camera_profile"] == config.camera.name == record["camera_profile"]
    assert manifest["config"]["camera"] == config.camera.to_json()
    assert manifest["variant"] and manifest["frames_per_s"] > 0
    assert record["layout_seed"] == sample.layout_seed(config.seed)
    assert manifest["foliage_groups"] == {record["foliage_group"]: [sample.sample_id]}
    stages = manifest["stage_s"]
    assert stages["render_s"] > 0 and stages["optics_s"] > 0 and stages["sensor_s"] > 0
    # the twin (optics, sensor) runs beside the render: the rest adds up to the total
    serial = ("simulate_s", "render_s", "encode_s", "other_s")
    assert sum(stages[k] for k in serial) == pytest.approx(record["timing_s"]["total_s"])
    assert min(stages.values()) >= 0


@pytest.mark.slow
def test_markers_are_detected_where_the_labels_say(dataset) -> None:
    """Median corner error <= 0.3 px on the decoded video, lab lighting, sub-pixel refinement."""
    from bench.common.video import read_video
    from pipeline.detect import DetectorConfig, detect_markers

    config, out, _ = dataset
    folder = out / config.samples()[0].sample_id
    labels = pd.read_parquet(folder / "labels.parquet")
    detector = DetectorConfig(corner_refinement="lines")
    errors, found, expected = [], 0, 0
    for f, frame in enumerate(read_video(folder / "video.mp4")):
        if f % 2:
            continue
        corners, ids, visible = corners_of_frame(labels, f)
        got = {
            d.marker_id: d.corners_px
            for d in detect_markers(frame, detector, camera=config.camera.lens)
        }
        assert set(got) <= set(ids.tolist())  # no wrong ids
        expected += int(visible.sum())
        for i, marker_id in enumerate(ids):
            if marker_id in got:
                found += 1
                errors.append(np.linalg.norm(got[marker_id] - corners[i], axis=1))
    assert found >= 0.98 * expected
    assert np.median(np.concatenate(errors)) <= 0.3


@pytest.mark.slow
def test_lead_in_has_no_contact_and_zero_deflection(dataset) -> None:
    config, out, _ = dataset
    labels = pd.read_parquet(out / config.samples()[0].sample_id / "labels.parquet")
    lead = labels[labels["time_s"] < config.motion("outdoor").lead_in_s]
    assert len(lead) >= 13 * 3
    assert (lead["deflection_mm"] == 0).all() and not lead["contact"].any()
    assert labels["deflection_mm"].max() > 2.0  # the branch does deflect a whisker later


@pytest.mark.slow
def test_rerun_skips_verified_samples_and_redoes_broken_ones(dataset) -> None:
    from bench.dataset.generate import run_dataset

    config, out, manifest = dataset
    again = run_dataset(config, out, progress=False)
    assert again["skipped"] == 1 and again["frames_rendered"] == 0
    assert again["files"] == manifest["files"]
    other = DatasetConfig(**{**SMALL, "exposure_ms": 4.0})
    with pytest.raises(DatasetConfigError, match="another configuration"):
        run_dataset(other, out, progress=False)


def test_the_settings_hash_follows_the_camera_profile() -> None:
    """A dataset made through one twin is never resumed with another."""
    base = DatasetConfig(**SMALL).settings_hash()
    reloaded = CameraProfile.from_json(json.loads(json.dumps(IDEAL.to_json())))
    assert DatasetConfig(**{**SMALL, "camera": reloaded}).settings_hash() == base
    cameras = [
        COLOUR,
        COLOUR.with_psf_scale(1.5),
        dataclasses.replace(COLOUR, stream=Stream(codec="mjpeg", quality=81)),
        IDEAL.with_lens(dataclasses.replace(IDEAL.lens, fx_px=IDEAL.lens.fx_px + 1.0)),
    ]
    hashes = {DatasetConfig(**{**SMALL, "camera": c}).settings_hash() for c in cameras}
    assert len(hashes | {base}) == len(cameras) + 1


def test_psf_scale_1_keeps_the_settings_hash_and_another_scale_changes_it() -> None:
    """Datasets made before ``--psf-scale`` resume (1 is not written); any other scale is
    another dataset: in its config JSON and its hash."""
    plain = DatasetConfig(**SMALL)
    assert "psf_scale" not in plain.to_json()
    assert DatasetConfig(**{**SMALL, "psf_scale": 1}).settings_hash() == plain.settings_hash()
    sharp = DatasetConfig(**{**SMALL, "psf_scale": 0.5})
    assert sharp.to_json()["psf_scale"] == 0.5
    assert sharp.settings_hash() != plain.settings_hash()
    assert plain.twin is plain.camera and sharp.twin == IDEAL.with_psf_scale(0.5)


def test_the_frames_are_sharper_at_the_bands_low_end_than_at_its_high_end() -> None:
    """The twin a dataset records through at --psf-scale at the profile's band ends, its optics
    alone on a vertical edge near the prototype's 60 deg field: the edge's 10-90 % rise is over
    twice as long at the blurry end (a Gaussian edge rises over 2.56 sigma; the pixel's own
    width, 0.74 px alone, adds to both)."""
    from renderers.camera_twin import optical_image

    origin, shape = (2100, 940), (32, 64)  # right of the centre, on the markers' row
    radiance = np.zeros((*shape, 3), np.float32)
    radiance[:, shape[1] // 2 :] = 0.5
    rises = []
    for scale in load_profile("prototype").band.psf_ends:
        twin = DatasetConfig(psf_scale=scale).twin
        assert twin.psf_scale == scale
        row = optical_image(radiance, twin, origin, ("psf",))[shape[0] // 2, :, 1]
        level = (row - row[0]) / (row[-1] - row[0])
        x = np.arange(shape[1])
        rises.append(np.interp(0.9, level, x) - np.interp(0.1, level, x))
    assert rises[1] > 2 * rises[0] and rises[0] > 0.74


@pytest.mark.slow
def test_psf_scale_reaches_camera_json_and_the_manifest_and_is_not_resumed_at_1(
    tmp_path, variant
) -> None:
    """``whiskerbench dataset --psf-scale 1.5``: the frames' profile (widths x 1.5, its
    ``psf_scale`` 1.5, the band as calibrated) in camera.json, the scale in the manifest's
    config; the same folder at the default scale is another dataset and is refused."""
    if variant.startswith("scalar"):
        pytest.skip("frame rendering needs a JIT variant")
    from bench.cli.main import main

    out = tmp_path / "data"
    argv = ["dataset", "--quick", "--branches", "0", "--lighting", "lab", "--frames-step", "40",
            "--out", str(out)]  # fmt: skip
    assert main([*argv, "--psf-scale", "1.5"]) == 0
    prototype = load_profile("prototype")
    (folder,) = [p for p in out.iterdir() if p.is_dir()]
    camera = load_profile(folder / "camera.json")
    assert camera == prototype.with_psf_scale(1.5) and camera.psf_scale == 1.5
    assert camera.band == prototype.band
    nominal = camera.at_psf_scale(1.0).psf
    assert np.allclose(nominal.sigma_radial_px, prototype.psf.sigma_radial_px, rtol=1e-12)
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["config"]["psf_scale"] == 1.5
    assert manifest["config"]["camera"] == prototype.to_json()  # the profile as calibrated
    record = json.loads((folder / "sample.json").read_text())
    before = sorted(p.name for p in folder.iterdir())
    assert main(argv) == 2  # the default scale: another configuration, nothing mixed in
    assert sorted(p.name for p in folder.iterdir()) == before
    assert json.loads((folder / "sample.json").read_text()) == record


@pytest.mark.slow
def test_same_seed_same_labels_other_seed_other_foliage() -> None:
    config = DatasetConfig(**SMALL)
    sample = config.samples()[0]
    a = simulate_sample(config, sample).labels
    b = simulate_sample(config, sample).labels
    pd.testing.assert_frame_equal(a, b)
    c = simulate_sample(DatasetConfig(**{**SMALL, "seed": 1}), sample).labels
    assert not np.allclose(a["deflection_mm"], c["deflection_mm"])


def test_a_branch_sample_and_its_twin_share_the_foliage_layout() -> None:
    """Part 1 of issue 13: one layout seed per foliage kind, whatever the distance, branches,
    protocol or lighting; render and noise seeds stay each sample's own."""
    samples = DatasetConfig().samples()
    twin = SampleSpec("soft", "far", (), "indoor", "sun")
    branch = SampleSpec("soft", "far", (0.0, 50.0), "indoor", "sun")
    seeds = twin.seeds(0), branch.seeds(0)
    assert seeds[0]["vegetation"] == seeds[1]["vegetation"] == twin.layout_seed(0)
    assert seeds[0]["render"] != seeds[1]["render"] and seeds[0]["noise"] != seeds[1]["noise"]
    by_kind: dict[str, set[str]] = {}
    for s in samples:
        by_kind.setdefault(s.foliage, set()).add(s.foliage_group(0))
    assert all(len(g) == 1 for g in by_kind.values()) and len(by_kind) == 4
    assert len({next(iter(g)) for g in by_kind.values()}) == 4  # kinds never share a layout
    assert twin.layout_seed(1) != twin.layout_seed(0)


@pytest.mark.slow
def test_the_twin_differs_from_its_branch_sample_only_in_the_branches() -> None:
    config = DatasetConfig(**{**SMALL, "branches": ((), (0.0,))})
    twin, branch = (simulate_sample(config, s).vegetation for s in config.samples())
    assert twin.contacts == branch.contacts and not twin.branches and branch.branches
    meshes = [{p.name: p.mesh for p in v.parts} for v in (twin, branch)]
    assert set(meshes[1]) - set(meshes[0]) == {"branches"}
    for name, mesh in meshes[0].items():
        assert np.array_equal(mesh.vertices, meshes[1][name].vertices)


@pytest.mark.slow
def test_the_mechanics_are_a_setting_and_only_dynamic_free_whiskers_swing() -> None:
    """Dynamic by default; quasi-static is a choice with its own settings hash. Past the
    branch the dynamic whiskers keep moving where the quasi-static ones sit still."""
    quasi = DatasetConfig(**{**SMALL, "mechanics": "quasi-static", "frames_step": 1})
    dynamic = dataclasses.replace(quasi, mechanics="dynamic")
    assert DatasetConfig(**SMALL).mechanics == "dynamic"
    assert quasi.settings_hash() != dynamic.settings_hash()
    sims = [simulate_sample(c, c.samples()[0]) for c in (quasi, dynamic)]
    lead_in = [s.labels[s.labels["time_s"] < 0.9]["deflection_mm"].to_numpy() for s in sims]
    assert np.array_equal(lead_in[0], lead_in[1]) and not lead_in[0].any()
    swing = []
    for sim in sims:  # the angle of whiskers touching nothing at a frame's time stamp
        free = ~sim.labels.pivot(index="frame", columns="whisker", values="contact").to_numpy()
        angle = np.abs(sim.angles_rad[:, -1, :, 0])  # (F, n)
        swing.append(angle[free & (sim.times_s > sim.motion.whisking_start_s)[:, None]].max())
    assert swing[0] == 0 and swing[1] > 1e-3


def test_sample_ids_are_unique_over_the_default_grid() -> None:
    samples = DatasetConfig().samples()
    assert len(samples) == 4 * 3 * 7 * 2
    assert len({s.sample_id for s in samples}) == len(samples)
    assert SampleSpec("soft", "far", (0.0, 50.0), "indoor", "sun").sample_id == (
        "soft-far-0+50-indoor-sun"
    )


def _bad_profile_files(folder) -> dict[str, str]:
    """Profile files a user could pass: a bad PSF width, a lens too narrow for the array."""
    bad_psf = IDEAL.to_json()
    bad_psf["psf"]["sigma_radial_px"] = [-1.0]
    narrow = IDEAL.with_lens(dataclasses.replace(IDEAL.lens, theta_max_deg=40.0)).to_json()
    paths = {}
    for name, data in (("bad_psf", bad_psf), ("narrow", narrow)):
        paths[name] = str(folder / f"{name}.json")
        (folder / f"{name}.json").write_text(json.dumps(data))
    return paths


@pytest.mark.parametrize(
    ("args", "option", "says"),
    [
        (["--foliage", "moss"], "--foliage", "moss"),
        (["--speed", "-4"], "--speed", "-4"),
        (["--branches", "400"], "--branches", "400"),
        (["--distance", "touching"], "--distance", "touching"),
        (["--out", "/proc/whiskerbench/x"], "--out", "not writable"),
        (["--exposure", "0"], "--exposure", "(0, 1e+06]"),
        (["--camera", "nosuch"], "--camera", "neither a shipped profile"),
        (["--camera", "bad_psf"], "--camera", "psf.sigma_radial_px"),
        (["--camera", "narrow"], "--camera", "image circle"),
        (["--psf-scale", "0"], "--psf-scale", "allowed range is (0, 10]"),
        (["--psf-scale", "-0.5"], "--psf-scale", "allowed range is (0, 10]"),
        (["--psf-scale", "10.5"], "--psf-scale", "allowed range is (0, 10]"),
        (["--psf-scale", "nan"], "--psf-scale", "allowed range is (0, 10]"),
        (["--psf-scale", "inf"], "--psf-scale", "allowed range is (0, 10]"),
        # the lead-in must hold a frame: --fps is named, not the lead-in it has no option for
        (["--fps", "0.5"], "--fps", "0.5: allowed range is 1..125 fps (at least one frame in"),
        (["--fps", "1e-320"], "--fps", "1e-320: allowed range is 1..125 fps"),
        (["--fps", "0.5", "--exposure-ms", "4"], "--fps", "allowed range is 1..250 fps"),
    ],
)
def test_bad_options_one_line_exit_2_nothing_written(tmp_path, capsys, args, option, says):
    from bench.cli.main import main

    files = _bad_profile_files(tmp_path)
    args = [files.get(a, a) for a in args]
    out = tmp_path / "never"
    argv = ["dataset", "--quick"] + ([] if "--out" in args else ["--out", str(out)]) + args
    assert main(argv) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and option in lines[0] and says in lines[0], lines
    assert not out.exists()


@pytest.mark.slow
def test_the_command_line_entry_point_exits_2(tmp_path) -> None:
    """The same through ``python -m bench.cli``: the exit code reaches the shell."""
    out = tmp_path / "never"
    cmd = [sys.executable, "-m", "bench.cli", "dataset", "--quick", "--camera", "nosuch"]
    proc = subprocess.run(cmd + ["--out", str(out)], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and "--camera" in proc.stderr and not out.exists()


def _srgb_decode(codes: np.ndarray) -> np.ndarray:
    """Linear signal of 8-bit sRGB codes (IEC 61966-2-1), to undo the transfer curve."""
    x = codes / 255.0
    return np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)


@pytest.mark.slow
def test_relative_illumination_darkens_the_frame_edges(variant) -> None:
    """The twin sees each pixel's field angle: with a fall-off to 0.4 at 90 degrees, the light
    across the band's row follows the table (the lens' own field angles, interpolated)."""
    if variant.startswith("scalar"):
        pytest.skip("frame rendering needs a JIT variant")
    from bench.dataset.sample import sample_recorder

    plain = DatasetConfig(**SMALL)
    falloff = RelativeIllumination((0.0, 90.0), (1.0, 0.4))
    dim = dataclasses.replace(
        plain, camera=dataclasses.replace(IDEAL, relative_illumination=falloff)
    )
    sample = plain.samples()[0]
    sim = simulate_sample(plain, sample)
    a = _srgb_decode(sample_recorder(plain, sample, sim).frame(0).astype(float))
    b = _srgb_decode(sample_recorder(dim, sample, sim).frame(0).astype(float))
    row = 971
    for cols in (slice(1200, 1400), slice(400, 600), slice(2000, 2200)):
        pixels = np.stack(np.meshgrid(np.arange(2592)[cols], [row]), axis=-1)
        theta = np.degrees(IDEAL.lens.theta_of_pixel(pixels))[0]
        expected = np.sum(falloff.at(theta) * a[row, cols]) / a[row, cols].sum()
        assert b[row, cols].sum() / a[row, cols].sum() == pytest.approx(expected, rel=0.05)
    assert expected < 0.7  # the edges do get darker


@pytest.mark.slow
def test_a_colour_twin_with_psf_and_mjpeg_runs_end_to_end(tmp_path, variant) -> None:
    """Bayer, PSF, lateral colour and MJPEG on a short sample: the band sits on the 16 px MCU
    grid, camera.json is the profile, and the markers found are where the labels say (the
    ``lines`` corners: OpenCV's ``subpix`` corners shift by about a PSF width under blur)."""
    if variant.startswith("scalar"):
        pytest.skip("frame rendering needs a JIT variant")
    from bench.common.video import read_video
    from bench.dataset.generate import run_dataset
    from pipeline.detect import DetectorConfig, detect_markers

    config = DatasetConfig(**{**SMALL, "camera": COLOUR, "frames_step": 12})
    manifest = run_dataset(config, tmp_path, variant=variant, progress=False)
    folder = tmp_path / config.samples()[0].sample_id
    record = json.loads((folder / "sample.json").read_text())
    assert load_profile(folder / "camera.json") == COLOUR
    assert manifest["camera_profile"] == record["camera_profile"] == "test-colour"
    region = record["region_px"]
    assert region["y0"] % 16 == 0 and region["height"] % 16 == 0
    assert record["timing_s"]["optics_s"] > 0 and record["timing_s"]["sensor_s"] > 0
    labels = pd.read_parquet(folder / "labels.parquet")
    frames = list(read_video(folder / "video.mp4"))
    assert len(frames) == record["frames"] == labels["frame"].nunique()
    rows = slice(region["y0"], region["y0"] + region["height"])
    assert not frames[0][: region["y0"]].any() and frames[0][rows].std() > 10
    detector = DetectorConfig(corner_refinement="lines")
    errors = []
    for f in (0, len(frames) - 1):
        corners, ids, _ = corners_of_frame(labels, f)
        got = {
            d.marker_id: d.corners_px
            for d in detect_markers(frames[f], detector, camera=COLOUR.lens)
        }
        assert set(got) <= set(ids.tolist()) and len(got) >= len(ids) / 2
        found = [i for i, m in enumerate(ids) if m in got]
        errors += [np.linalg.norm(got[ids[i]] - corners[i], axis=1) for i in found]
    assert np.median(np.concatenate(errors)) < 0.3
