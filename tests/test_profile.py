"""The camera profile format: validation at load, JSON round trips, sources of shipped numbers."""

import dataclasses
import json

import numpy as np
import pytest

from scenes.profile import (
    CameraProfile,
    ProfileError,
    PsfTable,
    load_profile,
    shipped_profiles,
)


def test_ideal_and_prototype_are_shipped_and_ideal_is_todays_camera():
    assert {"ideal", "prototype"} <= set(shipped_profiles())
    ideal = load_profile("ideal")
    assert dataclasses.replace(ideal, sources={}, description="") == CameraProfile()
    assert ideal.sensor.cfa == "none" and not ideal.lateral_colour.on
    assert not ideal.psf.on and ideal.stream.codec == "none" and ideal.crop_grid_px == 1


@pytest.mark.parametrize("name", ["ideal", "prototype"])
def test_shipped_profile_round_trips_through_json(name, tmp_path):
    profile = load_profile(name)
    path = tmp_path / "p.json"
    path.write_text(json.dumps(profile.to_json()))
    assert load_profile(path) == profile


def _numbers(section) -> list[str]:
    return [f.name for f in dataclasses.fields(section)]


@pytest.mark.parametrize("name", ["ideal", "prototype"])
def test_every_number_of_a_shipped_profile_has_a_source(name):
    profile = load_profile(name)
    covered = set(profile.sources)
    missing = []
    for key in ("lens", "relative_illumination", "psf", "lateral_colour", "sensor",
                "processing", "stream"):  # fmt: skip
        if key in covered:
            continue
        section = getattr(profile, key)
        for field in _numbers(section):
            if f"{key}.{field}" not in covered:
                missing.append(f"{key}.{field}")
    assert not missing, f"{name}: no source for {missing}"
    assert all(len(text) > 10 for text in profile.sources.values())


def test_prototype_is_the_seed_systems_camera_class():
    p = load_profile("prototype")
    assert (p.lens.width_px, p.lens.height_px) == (2592, 1944)
    assert p.sensor.pixel_pitch_um == 2.2 and p.sensor.cfa != "none"
    assert p.stream.codec == "mjpeg" and p.psf.on
    assert p.lens.theta_max_deg > 90.0  # a >180 degree fisheye
    # the rim is blurrier than the axis (published fisheye MTF over field)
    r0, t0 = p.psf.at(np.array([0.0]))
    r90, t90 = p.psf.at(np.array([90.0]))
    assert r90[0] > r0[0] and t90[0] > t0[0]


def test_psf_scale_multiplies_every_width():
    p = load_profile("prototype")
    s = p.with_psf_scale(1.5)
    assert np.allclose(np.array(s.psf.sigma_radial_px), 1.5 * np.array(p.psf.sigma_radial_px))
    assert s.psf.theta_deg == p.psf.theta_deg and s.lens == p.lens


def test_a_scaled_profile_records_its_scale_and_finds_the_band_levels_from_it(tmp_path):
    """A profile written after scaling (a dataset's camera.json) says by how much, so the band
    (stated around the table as calibrated) still lands where the calibrated profile puts it."""
    p = load_profile("prototype")
    assert p.psf_scale == 1.0 and "psf_scale" not in p.to_json()  # files as before at 1
    s = p.with_psf_scale(1.5).with_psf_scale(0.5)
    assert s.psf_scale == pytest.approx(0.75) and s.band == p.band
    path = tmp_path / "scaled.json"
    path.write_text(json.dumps(s.to_json()))
    again = load_profile(path)
    assert again == s and again.to_json()["psf_scale"] == pytest.approx(0.75)
    low = again.at_psf_scale(p.band.psf_ends[0])
    assert low.psf_scale == p.band.psf_ends[0]
    expected = np.array(p.with_psf_scale(p.band.psf_ends[0]).psf.sigma_radial_px)
    assert np.allclose(low.psf.sigma_radial_px, expected, rtol=1e-12)
    assert p.at_psf_scale(1.0) is p
    with pytest.raises(ProfileError, match="psf_scale"):
        p.with_psf_scale(0.0).at_psf_scale(1.0)  # nothing left to scale back


def test_table_interpolates_and_holds_past_the_ends():
    t = PsfTable(theta_deg=(0.0, 90.0), sigma_radial_px=(0.5, 1.5), sigma_tangential_px=(0.5, 1.0))
    r, tg = t.at(np.array([45.0, 120.0]))
    assert np.allclose(r, [1.0, 1.5]) and np.allclose(tg, [0.75, 1.0])


def _good() -> dict:
    return load_profile("prototype").to_json()


@pytest.mark.parametrize(
    "edit, field",
    [
        (lambda d: d.update(version=99), "version"),
        (lambda d: d.update(format="other"), "format"),
        (lambda d: d.pop("lens"), "lens"),
        (lambda d: d.update(extra=1), "extra"),
        (lambda d: d["psf"].update(theta_deg=[0, 50, 40]), "psf.theta_deg"),
        (lambda d: d["psf"].update(sigma_radial_px=[1.0]), "psf.sigma_radial_px"),
        (lambda d: d["psf"].update(sigma_tangential_px=[-1] * len(d["psf"]["theta_deg"])),
         "psf.sigma_tangential_px"),
        (lambda d: d["relative_illumination"].update(value=[float("nan")] * len(
            d["relative_illumination"]["theta_deg"])), "relative_illumination.value"),
        (lambda d: d["lateral_colour"].update(red_scale=[2.0] * len(
            d["lateral_colour"]["theta_deg"])), "lateral_colour.red_scale"),
        (lambda d: d["sensor"].update(cfa="XYZW"), "sensor.cfa"),
        (lambda d: d["sensor"].update(full_well_e=0), "sensor.full_well_e"),
        (lambda d: d["sensor"].update(read_noise_e="3"), "sensor.read_noise_e"),
        (lambda d: d["sensor"].update(gain=2), "sensor.gain"),
        (lambda d: d["processing"].update(demosaic="magic"), "processing.demosaic"),
        (lambda d: d["processing"].update(sharpen_amount=True), "processing.sharpen_amount"),
        (lambda d: d["stream"].update(quality=101), "stream.quality"),
        (lambda d: d["stream"].update(quality=80.5), "stream.quality"),
        (lambda d: d["stream"].update(chroma_subsampling="4:1:1"), "stream.chroma_subsampling"),
        (lambda d: d["lens"]["model"].update(fx_px=-1), "lens"),
        (lambda d: d.update(sources=["x"]), "sources"),
        (lambda d: d.update(psf_scale=-1), "psf_scale"),
        (lambda d: d.update(psf_scale="2"), "psf_scale"),
    ],
)  # fmt: skip
def test_a_bad_field_is_named(edit, field, tmp_path):
    data = _good()
    edit(data)
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(data))
    with pytest.raises(ProfileError) as info:
        load_profile(path)
    assert info.value.field == field


def test_unreadable_inputs_are_refused_in_one_line(tmp_path):
    with pytest.raises(ProfileError, match="neither a shipped profile"):
        load_profile("no-such-camera")
    bad = tmp_path / "x.json"
    bad.write_text("{not json")
    with pytest.raises(ProfileError, match="not valid JSON"):
        load_profile(bad)
    bad.write_text("[1, 2]")
    with pytest.raises(ProfileError, match="JSON object"):
        load_profile(bad)
    big = tmp_path / "big.json"
    big.write_text(" " * (2 << 20))
    with pytest.raises(ProfileError, match="larger than"):
        load_profile(big)


def test_a_bare_camera_file_is_a_profile_with_ideal_stages(tmp_path):
    lens = load_profile("prototype").lens
    path = tmp_path / "camera.json"
    path.write_text(json.dumps(lens.to_dict()))
    profile = load_profile(path)
    assert profile.lens == lens and not profile.psf.on and profile.sensor.cfa == "none"
