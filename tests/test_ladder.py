"""The fidelity ladder: match and knee logic on hand-made numbers, rungs, clip, end to end."""

import pandas as pd
import pytest

from bench.ladder.config import LadderConfig, LadderConfigError
from bench.ladder.match import knee, rung_matches, within
from bench.ladder.rungs import (
    STAGE_RUNGS,
    project_defaults,
    stage_is_on,
    stage_off,
    study_rungs,
    video_rungs,
)
from scenes.profile import load_profile


def _cells(rate_lo, rate_hi, corner=0.2, rot=0.5, trans=0.5):
    return pd.DataFrame(
        {
            "cell": ["a"],
            "rate_lo": [rate_lo],
            "rate_hi": [rate_hi],
            "corner_err_px": [corner],
            "rot_err_deg": [rot],
            "trans_err_mm": [trans],
        }
    )


@pytest.mark.parametrize(
    ("rung", "expected"),
    [
        (_cells(0.90, 0.97), True),  # overlapping intervals, same errors
        (_cells(0.70, 0.85), False),  # interval below the reference's
        (_cells(0.90, 0.97, corner=0.3), False),  # corner error 50 % off
        (_cells(0.90, 0.97, corner=0.24), True),  # within 25 %
        (_cells(0.90, 0.97, rot=0.58), True),  # within the 0.1 deg floor
        (_cells(0.90, 0.97, trans=0.9), False),
    ],
)
def test_rung_matches(rung, expected):
    assert rung_matches(rung, _cells(0.93, 0.99)) is expected


def test_within_nan_matches_only_nan():
    assert within(float("nan"), float("nan"), "corner_err_px")
    assert not within(0.1, float("nan"), "corner_err_px")


def test_knee_is_the_cheapest_matching_rung():
    rungs = pd.DataFrame(
        {
            "rung": ["1", "4", "16", "reference"],
            "s_per_image": [0.1, 0.3, 1.0, 4.0],
            "matches_reference": [False, True, True, True],
        }
    )
    assert knee(rungs) == "4"
    assert knee(rungs.assign(matches_reference=False)) is None
    noisy = rungs.assign(s_per_image=[0.1, 1.1, 1.0, 4.0])  # the load swapped 4 and 16
    assert knee(noisy) == "4"


def test_stage_off_changes_only_that_stage():
    profile = load_profile("prototype")
    for stage in STAGE_RUNGS:
        assert stage_is_on(profile, stage)
        assert not stage_is_on(stage_off(profile, stage), stage)
    assert stage_off(profile, "psf").sensor == profile.sensor
    with pytest.raises(ValueError, match="stage"):
        stage_off(profile, "image_circle")


@pytest.mark.parametrize("make", [study_rungs, video_rungs])
def test_rungs_vary_one_choice_at_a_time(make):
    rungs = make(LadderConfig(), load_profile("prototype"))
    ref = rungs[0].options
    assert ref["full_frame"] and ref["integrator"] == "path" and ref["path_depth"] == 2
    for rung in rungs[1:]:
        changed = {k for k, v in rung.options.items() if v != ref[k]}
        if rung.axis == "control":  # the reference drawn again: only the seed moves
            assert changed == {"seed_offset"}
        elif rung.axis == "defaults":  # the project's choices all at once, same draws
            assert rung.options["integrator"] == "direct" and rung.options["seed_offset"] == 0
            assert project_defaults(rung.part).items() <= rung.options.items()
            assert not rung.options["full_frame"]  # the study's crop, the dataset's band
        else:
            assert changed and len(changed - {"path_depth"}) <= 1, rung  # direct: depth 0 too
    assert len({r.key for r in rungs}) == len(rungs)
    axes = {r.axis for r in rungs}
    assert {"spp", "integrator", "region", "stage"} <= axes


def test_video_reference_and_its_render_groups():
    rungs = video_rungs(LadderConfig(), load_profile("prototype"))
    ref = rungs[0].options
    assert (ref["marker_spp"], ref["background_spp"], ref["foliage_detail"]) == (64, 4, "fine")
    assert {r.name for r in rungs if r.axis == "foliage_detail"} == {"coarse", "default"}
    # the stage rungs share the reference's render: one render records all of them
    shared = [r for r in rungs if r.render_key() == rungs[0].render_key()]
    assert {r.axis for r in shared} == {"reference", "stage"} and len(shared) == 1 + 7


def test_a_stage_already_off_has_no_rung():
    ideal = load_profile("ideal")
    rungs = video_rungs(LadderConfig.quick(), ideal)
    stages = {r.name for r in rungs if r.axis == "stage"}
    assert stages == {s for s in STAGE_RUNGS if stage_is_on(ideal, s)}


@pytest.mark.parametrize(
    ("change", "field"),
    [
        ({"images": 0}, "images"),
        ({"frames_step": 31}, "frames_step"),
        ({"parts": ("x",)}, "parts"),
        ({"profile": "nope"}, "profile"),
    ],
)
def test_config_refuses(change, field):
    with pytest.raises(LadderConfigError, match=field):
        LadderConfig(**change)


@pytest.mark.start_early
@pytest.mark.slow
@pytest.mark.usefixtures("figures_not_drawn")  # laid out and drawn on the canvas, not saved
def test_quick_ladder_end_to_end_and_resumes(tmp_path):
    from bench.ladder.run import run_ladder

    first = run_ladder(LadderConfig.quick(), tmp_path, progress=False)
    assert first["tasks_computed"] > 0
    table = pd.read_csv(tmp_path / "rungs.csv")
    ref = table[table["axis"] == "reference"]
    assert set(ref["part"]) == {"study", "video"} and ref["matches_reference"].all()
    assert {"spp", "stage"} <= set(table[table["part"] == "study"]["axis"])
    assert "stage" in set(table[table["part"] == "video"]["axis"])
    video = table[table["part"] == "video"]
    assert video["threshold_source"].eq("none-sample twin").all()
    assert video["branch_outcome"].notna().all() and (video["n"] > 0).all()
    assert (tmp_path / "ladder.png").stat().st_size > 0
    again = run_ladder(LadderConfig.quick(), tmp_path, progress=False)
    assert again["tasks_computed"] == 0


def test_a_branch_outcome_the_control_flips_is_noise_and_the_control_widens_tolerances():
    from bench.ladder.match import rung_matches

    def row(outcome: str, corner: float) -> pd.DataFrame:
        values = {"cell": "clip", "rate_lo": 0.4, "rate_hi": 0.6, "branch_outcome": outcome}
        return pd.DataFrame([{**values, "corner_err_px": corner, "rot_err_deg": 5.0,
                              "trans_err_mm": 5.0}])  # fmt: skip

    ref, rung = row("correct", 1.0), row("false_negative", 1.0)
    assert not rung_matches(rung, ref)  # no control: outcomes must agree
    assert not rung_matches(rung, ref, row("correct", 1.0))  # the control keeps it
    assert rung_matches(rung, ref, row("false_negative", 1.0))  # other draws flip it
    far = row("correct", 1.5)  # 0.5 px off: beyond 25 % of 1.0 px
    assert not rung_matches(far, ref, row("correct", 1.0))
    assert rung_matches(far, ref, row("correct", 1.3))  # within twice the control's 0.3
