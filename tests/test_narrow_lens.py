"""A lens whose image circle is under 90 deg can be studied and swept: the built-in alphas end
at its theta_max, and only an alpha the user gave past it is refused, naming --alphas and the
camera's limit."""

from __future__ import annotations

import dataclasses
import json

import pytest

from bench.cli.main import _parser, main, study_config
from bench.evaluate.sweep_config import QUICK_SWEEP, SweepConfig
from bench.study.config import DEFAULT_ALPHAS_DEG, StudyConfig, alphas_within
from scenes.camera import default_camera
from scenes.profile import CameraProfile

NARROW = CameraProfile(
    name="narrow", lens=dataclasses.replace(default_camera(), theta_max_deg=60.0)
)


@pytest.fixture
def narrow_json(tmp_path):
    path = tmp_path / "narrow.json"
    path.write_text(json.dumps(NARROW.to_json()))
    return path


def test_alphas_within_keeps_a_grid_that_fits_and_ends_one_that_does_not_at_the_edge():
    assert alphas_within(DEFAULT_ALPHAS_DEG, StudyConfig().camera) == DEFAULT_ALPHAS_DEG
    assert alphas_within(DEFAULT_ALPHAS_DEG, NARROW) == (0.0, 20.0, 40.0, 60.0)
    assert alphas_within((0.0, 50.0, 85.0), NARROW) == (0.0, 50.0, 60.0)


@pytest.mark.parametrize("quick", [[], ["--quick"]])
def test_the_default_study_of_a_narrow_lens_is_not_refused(narrow_json, quick):
    args = _parser().parse_args(["detectability", "--camera", str(narrow_json), *quick])
    config = study_config(args)
    assert max(config.alphas_deg) == 60.0
    assert config.alphas_deg == ((0.0, 60.0) if quick else (0.0, 20.0, 40.0, 60.0))


def test_an_alpha_past_the_lens_is_refused_naming_alphas_and_the_limit(
    narrow_json, tmp_path, capsys, monkeypatch
):
    monkeypatch.chdir(tmp_path)
    before = sorted(tmp_path.rglob("*"))
    assert main(["detectability", "--camera", str(narrow_json), "--alphas", "80"]) == 2
    err = capsys.readouterr().err.strip().split("\n")
    assert len(err) == 1 and "--alphas" in err[0] and "0..60 deg" in err[0], err
    assert sorted(tmp_path.rglob("*")) == before, "something was written"


@pytest.mark.parametrize("sweep", [SweepConfig(), QUICK_SWEEP], ids=["full", "quick"])
def test_the_sweeps_built_in_alphas_fit_a_narrow_lens(sweep):
    fitted = dataclasses.replace(
        sweep, camera=NARROW, alphas_deg=alphas_within(sweep.alphas_deg, NARROW)
    )
    assert max(fitted.alphas_deg) == 60.0


@pytest.mark.parametrize("quick", [[], ["--quick"]])
def test_the_run_limits_measure_a_narrow_lens_against_its_own_default_grid(narrow_json, quick):
    """The limits compare a run with the default grid on its camera: built with every default
    alpha, it refused `detectability --quick` on a 60-degree lens blaming --alphas."""
    from bench.cli import limits

    args = _parser().parse_args(["detectability", "--camera", str(narrow_json), *quick])
    limits.check_study(study_config(args), 1)


@pytest.mark.parametrize("quick", [[], ["--quick"]])
def test_the_command_passes_every_check_on_a_narrow_lens(
    narrow_json, quick, tmp_path, capsys, monkeypatch
):
    """Through main, up to the study itself (stopped there as by Ctrl-C): not refused."""

    def stop(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr("bench.study.run.run_study", stop)
    argv = ["detectability", "--camera", str(narrow_json), *quick, "--out", str(tmp_path / "r")]
    assert main(argv) == 130, capsys.readouterr().err
