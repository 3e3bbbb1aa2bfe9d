"""Observations of the real sensor and ``whiskerbench camera calibrate`` (issue 22).

The bisection is checked twice: on a pure function whose answer is known exactly, and on real
renders: a profile's PSF set to a known scale, what the twin then does observed, and the
interval recovered from those observations must contain the scale.
"""

from __future__ import annotations

import copy
import dataclasses
import json
import re
from pathlib import Path

import pytest

from bench.cli.main import main
from bench.twin.calibrate import (
    CalibrationInputError,
    Interval,
    bisect_interval,
    calibrate,
    calibrated_profile,
    check_param,
    diffraction_scale,
)
from scenes.observations import (
    ObservationError,
    check_against_lens,
    load_observations,
    parse_observations,
)
from scenes.profile import load_profile

SHIPPED = "scenes/observations/prototype.json"


def marker(oid: str, size_mm: float, min_rate: float, max_rate: float = 1.0, **extra) -> dict:
    return {
        "id": oid,
        "kind": "marker",
        "source": "test",
        "detector": "paper",
        "size_mm": size_mm,
        "distance_mm": 200.0,
        "lighting": "lab",
        "alpha_deg": [0],
        "phi_deg": [0],
        "min_rate": min_rate,
        "max_rate": max_rate,
        **extra,
    }


def observations_file(tmp_path, *items: dict):
    path = tmp_path / "obs.json"
    data = {"format": "whiskerbench-observations", "version": 1, "sensor": "t", "description": ""}
    path.write_text(json.dumps({**data, "observations": list(items)}))
    return path


# --- the format -------------------------------------------------------------------------------


def test_shipped_observations_state_sources_and_assumptions():
    observations = load_observations("prototype")
    kinds = {o.kind for o in observations.observations}
    assert kinds == {"marker", "array_rest", "array_sampling"}
    facing = observations.observations[0]
    assert facing.size_mm == 13.2 and facing.alpha_deg == (0, 20, 40) and facing.phi_deg == (0,)
    assert facing.min_rate == 0.95 and facing.detector == "paper"
    for o in observations.observations:
        assert "SPEC" in o.source
        assert {a.field for a in o.assumptions} and all(a.why for a in o.assumptions)
    check_against_lens(observations, load_profile("prototype").lens)
    again = parse_observations(observations.to_json())  # the JSON round trip
    assert again == observations


def test_an_alternative_is_validated_like_the_file():
    data = json.loads(Path(SHIPPED).read_text())
    data["observations"][0]["assumptions"][1]["alternatives"] = [-5]
    with pytest.raises(ObservationError, match=r"alternatives.*distance_mm.*allowed range"):
        parse_observations(data)


BAD = [
    (lambda o: o.update(colour="red"), r"observations\[0\]\.colour: unknown field"),
    (lambda o: o.update(phi_deg=[95]), r"phi_deg: 95: allowed range is \[0, 89\]"),
    (lambda o: o.update(size_mm=0), r"size_mm: 0: allowed range is \(0, 200\]"),
    (lambda o: o.update(size_mm=300.0), r"size_mm: 300.0: allowed range is \(0, 200\]"),
    (lambda o: o.update(min_rate=1.5), r"min_rate: 1.5: allowed range is \(0, 1\]"),
    (lambda o: o.update(min_rate=0), r"min_rate: 0: allowed range"),
    (lambda o: o.update(min_rate=0.9, max_rate=0.5), r"max_rate: 0.5: below min_rate"),
    (lambda o: o.update(lighting="moon"), r"lighting: lighting='moon': unknown"),
    (lambda o: o.update(kind="photo"), r"kind: 'photo': must be one of"),
    (lambda o: o.pop("source"), r"source: missing"),
    (lambda o: o.update(detector="best"), r"detector: pipeline 'best': unknown preset"),
    (lambda o: o.update(alpha_deg=[120]), r"alpha_deg: \[120.0\]: allowed range is 0..92.5"),
]


@pytest.mark.parametrize(("spoil", "message"), BAD)
def test_bad_observations_are_refused_in_one_line_and_nothing_is_written(
    tmp_path, capsys, spoil, message
):
    item = marker("a", 13.2, 0.95)
    spoil(item)
    path = observations_file(tmp_path, item)
    out = tmp_path / "out.json"
    argv = ["camera", "calibrate", "prototype", "--observations", str(path), "--out", str(out)]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--observations" in err
    assert re.search(message, err), err
    assert not out.exists() and not list(tmp_path.glob("out*"))


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--param", "read_noise_e"], r"--param: 'read_noise_e'.*not mark sensor.read_noise_e"),
        (["--f-number", "0.5"], r"--f-number: 0.5: allowed range is 1..32"),
        (["--tolerance", "nan"], r"--tolerance: nan: allowed range"),
    ],
)
def test_bad_options_are_refused(tmp_path, capsys, argv, message):
    out = tmp_path / "out.json"
    base = ["camera", "calibrate", "prototype", "--observations", SHIPPED, "--out", str(out)]
    assert main(base + argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and re.search(message, err), err
    assert not out.exists()


def test_only_estimates_can_be_calibrated():
    prototype = load_profile("prototype")
    assert check_param(prototype, "psf_scale").source_key == "psf"
    assert check_param(prototype, "dark_signal_e")  # "Estimate: the datasheet gives no ..."
    for sourced in ("read_noise_e",):  # derived from the datasheet
        with pytest.raises(CalibrationInputError, match="only estimates are calibrated"):
            check_param(prototype, sourced)
    with pytest.raises(CalibrationInputError, match="does not mark psf"):
        check_param(load_profile("ideal"), "psf_scale")  # no sources at all


# --- the bisection ----------------------------------------------------------------------------


def test_bisection_finds_a_known_edge_and_says_which_end_is_open():
    got = bisect_interval(lambda v: (v <= 0.7, ""), 0.2, 3.0, tolerance=0.01)
    assert got.low == 0.2 and got.low_open and not got.high_open
    assert 0.69 <= got.high <= 0.7
    two_sided = bisect_interval(lambda v: (0.4 <= v <= 1.3, ""), 0.0, 3.0, tolerance=0.01)
    assert 0.4 <= two_sided.low <= 0.41 and 1.29 <= two_sided.high <= 1.3
    assert not (two_sided.low_open or two_sided.high_open)
    assert bisect_interval(lambda v: (False, ""), 0.0, 1.0).empty
    dip = bisect_interval(lambda v: (not 0.4 < v < 0.6, ""), 0.0, 1.0)  # rejected at 0.5 only
    assert "not monotone" in dip.notes[0]


def test_intersection_is_empty_when_observations_disagree():
    both = Interval(0.2, 0.7, True, False) & Interval(0.5, 3.0, False, True)
    assert (both.low, both.high, both.low_open, both.high_open) == (0.5, 0.7, False, False)
    assert (Interval(0.2, 0.4) & Interval(0.5, 1.0)).empty


def test_diffraction_limit_at_the_lens_f_number():
    prototype = load_profile("prototype")
    axis = prototype.psf.sigma_radial_px[0]  # the table's sharpest width
    # 0.42 x 0.55 um x F/2 over 2.2 um pixels, against the table's width on the axis
    assert diffraction_scale(prototype, 2.0) == pytest.approx(0.42 * 0.55 * 2 / 2.2 / axis)
    assert diffraction_scale(prototype, 2.8) == pytest.approx(1.4 * diffraction_scale(prototype, 2))


def literature_base():
    """The prototype with the literature-derived table (1.12 px on the axis) its calibration
    started from, so the known-answer test does not move when the shipped profile is refitted."""
    prototype = load_profile("prototype")
    scaled = prototype.with_psf_scale(1.12 / prototype.psf.sigma_radial_px[0])
    return dataclasses.replace(scaled, psf_scale=1.0)


# --- on renders: a known answer ---------------------------------------------------------------


@pytest.fixture(scope="module")
def twin_checkers():
    from bench.twin.run import Checkers
    from renderers.variant import init_worker

    init_worker(None)
    return Checkers(literature_base(), "psf_scale")


@pytest.mark.slow
def test_calibration_recovers_the_psf_scale_it_observed(twin_checkers):
    """The twin at PSF scale 0.5 reads the 13.2 mm marker and loses a 6 mm one; observations
    saying so give an interval, bounded on both sides by them, that holds 0.5."""
    true_scale = 0.5
    seen = parse_observations(
        {
            "format": "whiskerbench-observations",
            "version": 1,
            "sensor": "twin at 0.5",
            "observations": [
                marker("reads-13.2", 13.2, 0.95),
                marker("loses-6", 6.0, 0.0001, 0.05),
            ],
        }
    )
    for o in seen.observations:  # the observation step: this is what the twin does at 0.5
        assert twin_checkers(o)(true_scale)[0], o.id
    base = literature_base()
    result = calibrate(base, seen, "psf_scale", twin_checkers, tolerance=0.02)
    got = result.interval
    assert got.low < true_scale < got.high
    assert not (got.low_open or got.high_open)  # both ends are the observations'
    assert result.nominal == pytest.approx((got.low + got.high) / 2)
    profile = calibrated_profile(base, result, "test")
    low, high = profile.band.psf_scale
    assert low * result.nominal == pytest.approx(got.low, abs=2e-3)
    assert high * result.nominal == pytest.approx(got.high, abs=2e-3)
    assert profile.psf.sigma_radial_px[0] == pytest.approx(1.12 * result.nominal)
    assert profile.sources["psf"].startswith("Calibrated against test")
    check_param(profile, "psf_scale")  # a calibrated number can be calibrated again


@pytest.mark.slow
def test_contradicting_observations_exit_1_and_write_nothing(tmp_path, capsys):
    path = observations_file(
        tmp_path, marker("reads", 13.2, 0.95), marker("loses", 13.2, 0.0001, max_rate=0.05)
    )
    out = tmp_path / "p.json"
    argv = ["camera", "calibrate", "prototype", "--observations", str(path), "--out", str(out)]
    assert main(argv + ["--tolerance", "0.05"]) == 1
    captured = capsys.readouterr()
    assert "consistent with every observation: empty" in captured.out
    assert "contradict" in captured.err
    assert not list(tmp_path.glob("p*"))


@pytest.mark.slow
def test_calibrate_writes_a_profile_whose_band_is_the_interval(tmp_path, capsys):
    one = marker("reads", 13.2, 0.95)
    one["assumptions"] = [{"field": "lighting", "why": "test", "alternatives": ["sun"]}]
    path = observations_file(tmp_path, one)
    out = tmp_path / "twin.json"
    argv = ["camera", "calibrate", "prototype", "--observations", str(path), "--out", str(out)]
    assert main(argv + ["--tolerance", "0.05"]) == 0
    shown = capsys.readouterr().out
    assert "if reads.lighting = sun (assumed lab)" in shown
    report = json.loads((tmp_path / "twin.calibration.json").read_text())
    profile = load_profile(out)
    assert profile.name == "twin"
    interval, nominal = report["interval"], report["nominal"]
    assert interval["low_open"] and not interval["high_open"]  # success bounds only from above
    assert profile.band.psf_scale[1] * nominal == pytest.approx(interval["high"], abs=2e-3)
    assert [a["alternative"] for a in report["assumptions"]] == ["sun"]
    original = copy.deepcopy(load_profile("prototype").psf.sigma_radial_px)
    assert profile.psf.sigma_radial_px == pytest.approx([s * nominal for s in original])


def test_out_may_not_be_an_input(tmp_path, capsys):
    shipped = "scenes/profiles/prototype.json"
    argv = ["camera", "calibrate", "prototype", "--observations", SHIPPED, "--out", shipped]
    assert main(argv) == 2
    assert "--out: scenes/profiles/prototype.json: is one of the command's inputs" in (
        capsys.readouterr().err
    )


@pytest.mark.slow  # over a second of CPU: out of `make test-fast`
def test_check_prints_each_unit_at_each_band_level(tmp_path, capsys):
    path = observations_file(tmp_path, marker("reads", 13.2, 0.95))
    assert main(["camera", "check", "prototype", "--observations", str(path)]) == 0
    lines = capsys.readouterr().out.splitlines()
    levels = load_profile("prototype").band.psf_levels()
    assert [line.split(":")[0] for line in lines] == [f"reads at PSF scale {s:g}" for s in levels]
    nominal = lines[levels.index(1.0)]
    assert "agrees: alpha 0 phi 0 " in nominal  # the calibrated twin reads the chosen size
    k, n = map(int, nominal.rsplit(" ", 1)[1].split("/"))
    assert n >= 10 and k / n >= 0.95


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("[" * 30 + "]" * 30, "nested deeper than 8 levels"),
        ("{not json", "not valid JSON"),
        (" " * (2 << 20), "larger than 1048576 bytes"),
    ],
)
def test_hostile_observation_files_are_bounded(tmp_path, capsys, text, message):
    path = tmp_path / "obs.json"
    path.write_text(text)
    argv = ["camera", "check", "prototype", "--observations", str(path)]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and message in err and str(path) in err
