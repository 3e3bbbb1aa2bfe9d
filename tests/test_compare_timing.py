"""Speed measured on what is compared: the dataset's own frames, the pipelines alternating over
repeated rounds, the median and spread reported, and a speed lead within the spread said so.

No test asserts a time: the clock is replaced where the arithmetic is checked."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from bench.evaluate import timing
from bench.evaluate.timing import (
    TimedRun,
    dataset_runs,
    plan_runs,
    round_order,
    runs_table,
    speed_figures,
    speed_of,
    time_pipelines,
    timed_track,
)
from pipeline.presets import PRESETS, get_pipeline


def _check_plan(lengths: dict[str, int], frames: int, run_frames: int) -> list:
    """The invariants of any plan: runs inside their sample, a lead-in and a timed frame at
    least, no frame twice, no more timed frames than asked."""
    plan = plan_runs(list(lengths.items()), frames, run_frames)
    for sample_id, indices in plan:
        assert indices.start >= 0 and indices.stop <= lengths[sample_id]
        assert 2 <= len(indices) <= run_frames + 1
    for sample_id in lengths:
        taken = [f for s, r in plan if s == sample_id for f in r]
        assert len(taken) == len(set(taken)), sample_id
    assert sum(len(r) - 1 for _, r in plan) <= frames
    return plan


def test_runs_are_spread_evenly_over_the_samples_and_their_time():
    lengths = {f"s{k}": 100 for k in range(8)}
    plan = _check_plan(lengths, 40, 10)  # 4 runs over 8 samples: every other one, centred
    assert [s for s, _ in plan] == ["s1", "s3", "s5", "s7"]
    assert all(r == range(44, 55) for _, r in plan)
    assert sum(len(r) - 1 for _, r in plan) == 40
    plan = _check_plan({"a": 64, "b": 30}, 45, 10)  # 5 runs, more than samples: 2 and 3
    assert [s for s, _ in plan] == ["a", "a", "b", "b", "b"]
    assert [r.start for s, r in plan if s == "a"] == [10, 42]  # the middle of each half
    assert [len(r) for s, r in plan if s == "b"] == [10, 10, 6]  # thirds of 30; the last run 5
    # a sample shorter than a run gives what it has; one of a single frame gives nothing
    plan = _check_plan({"short": 4, "single": 1, "long": 50}, 20, 10)
    assert plan == [("short", range(0, 4)), ("long", range(19, 30))]
    rng = np.random.default_rng(7)
    for _ in range(200):
        n = int(rng.integers(1, 12))
        lengths = {f"s{k}": int(rng.integers(1, 120)) for k in range(n)}
        _check_plan(lengths, int(rng.integers(1, 90)), int(rng.integers(1, 15)))
    with pytest.raises(ValueError, match="frames >= 1"):
        plan_runs([("a", 10)], 0)


def test_the_timed_frames_are_the_datasets_own(tmp_path):
    from fake_dataset import SAMPLES, make_dataset

    from bench.dataset.loader import open_dataset

    data = make_dataset(tmp_path / "data")
    runs = dataset_runs(data, frames=12, run_frames=5)
    ds = open_dataset(data)
    assert {run.source for run in runs} == set(SAMPLES)  # both samples, however short
    for run in runs:
        sample = ds[run.source]
        assert run.camera == sample.camera
        assert all(0 <= f < len(sample) for f in run.frame_ids)
        assert list(run.frame_ids) == list(range(run.frame_ids[0], run.frame_ids[-1] + 1))
        for f, image in zip(run.frame_ids, run.images, strict=True):  # noise: distinct frames
            np.testing.assert_array_equal(image, sample.frame(f).image)
    table = runs_table(runs)
    assert table["timed"].sum() == sum(run.timed_frames for run in runs) <= 12
    assert (~table.groupby("run")["timed"].first()).all()  # each run's first frame: lead-in


class _Clock:
    """A clock the fake tracker advances: 100 for a run's first frame, 1 for each other."""

    def __init__(self) -> None:
        self.now = 0.0


def _fake_track(clock: _Clock, calls: list, cost: dict[str, float] | None = None):
    def track(frames, camera, markers, detector, search, pose_method):
        name = detector.backend + "|" + search.mode  # which pipeline: see _pipelines
        calls.append(name)
        for i, _ in enumerate(frames):
            clock.now += 100.0 if i == 0 else (cost or {}).get(name, 1.0)
        return type("Result", (), {"detections": pd.DataFrame({"frame": [0]})})()

    return track


def _run(source: str, n: int) -> TimedRun:
    from pipeline.track import MarkerSet
    from scenes.camera import default_camera

    images = tuple(np.full((4, 4), k, np.uint8) for k in range(n))
    return TimedRun(source, tuple(range(n)), images, default_camera(), MarkerSet((1, 2), 10.0))


def _pipelines() -> dict:
    """Three pipelines the fake tracker tells apart by detector backend and search."""
    return {
        "paper": PRESETS["paper"],
        "fast": PRESETS["fast"],
        "robust/detector=locus": get_pipeline("robust/detector=locus"),
    }


def test_the_lead_in_frame_is_tracked_but_not_timed(monkeypatch):
    clock, calls = _Clock(), []
    monkeypatch.setattr(timing, "perf_counter", lambda: clock.now)
    monkeypatch.setattr(timing, "track", _fake_track(clock, calls))
    elapsed, _ = timed_track(_run("a", 7), PRESETS["paper"])
    assert elapsed == 6.0 and clock.now == 106.0  # the lead-in's 100 is not counted
    with pytest.raises(ValueError, match="a frame after its lead-in"):
        timed_track(_run("b", 1), PRESETS["paper"])


def test_pipelines_alternate_over_repeated_rounds(monkeypatch):
    clock, calls = _Clock(), []
    pipelines = _pipelines()
    keys = {n: p.detector.backend + "|" + p.search.mode for n, p in pipelines.items()}
    cost = dict(zip(keys.values(), (1.0, 0.5, 2.0), strict=True))
    monkeypatch.setattr(timing, "perf_counter", lambda: clock.now)
    monkeypatch.setattr(timing, "track", _fake_track(clock, calls, cost))
    runs = [_run("a", 5), _run("b", 3)]
    result = time_pipelines(runs, pipelines, rounds=4)
    names = list(pipelines)
    # every run tracked by every pipeline in turn, each round starting one pipeline later
    expected = [keys[n] for r in range(4) for _ in runs for n in round_order(names, r)]
    assert calls == expected
    assert round_order(names, 1) == ["fast", "robust/detector=locus", "paper"]
    rounds = result.rounds
    assert list(rounds.columns) == list(timing.ROUND_COLUMNS) and len(rounds) == 4 * 3
    for r in range(4):
        part = rounds[rounds["round"] == r].sort_values("position")
        assert part["pipeline"].tolist() == round_order(names, r)
    assert (rounds["frames"] == 6).all()  # 4 + 2 timed frames, lead-ins left out
    fps = rounds.groupby("pipeline")["fps"].first()
    assert fps["paper"] == 1.0 and fps["fast"] == 2.0 and fps["robust/detector=locus"] == 0.5
    assert [len(d) for d in result.detections.values()] == [2, 2, 2]  # first round, per run


def test_a_pipeline_that_fails_while_timed_drops_out_and_the_others_go_on(monkeypatch):
    """A plugin's BackendError in round 1: no row of it (no speed, not made up), why in
    ``failed``; the others keep every round, alternating among themselves."""
    from pipeline.backends import BackendError

    clock, calls = _Clock(), []
    fake = _fake_track(clock, calls)
    pipelines, failing = _pipelines(), "fast"
    key = pipelines[failing].detector.backend + "|" + pipelines[failing].search.mode

    def track(frames, camera, markers, detector, search, pose_method):
        if detector.backend + "|" + search.mode == key and len(calls) >= 6:  # after round 0
            calls.append("failed")
            raise BackendError("detector plugin:x: raised ZeroDivisionError: planted")
        return fake(frames, camera, markers, detector, search, pose_method)

    monkeypatch.setattr(timing, "perf_counter", lambda: clock.now)
    monkeypatch.setattr(timing, "track", track)
    result = time_pipelines([_run("a", 5), _run("b", 3)], pipelines, rounds=4)
    assert result.failed == {failing: "detector plugin:x: raised ZeroDivisionError: planted"}
    assert calls.count("failed") == 1  # not asked again after it failed
    rounds = result.rounds
    assert failing not in set(rounds["pipeline"]) and failing not in result.detections
    others = [n for n in pipelines if n != failing]
    assert sorted(rounds["pipeline"].value_counts().items()) == sorted((n, 4) for n in others)
    assert np.isnan(speed_of(speed_figures(rounds), failing)["fps"])


def test_median_and_spread_are_consistent():
    rows = [
        (r, 0, name, 10, 10 / f, f)
        for r, speeds in enumerate(([20.0, 5.0], [30.0, 6.0], [25.0, 4.0], [22.0, 5.5]))
        for name, f in zip(("a", "b"), speeds, strict=True)
    ]
    figures = speed_figures(pd.DataFrame(rows, columns=list(timing.ROUND_COLUMNS)))
    assert list(figures.index) == ["a", "b"]
    assert (figures["fps_min"] <= figures["fps"]).all()
    assert (figures["fps"] <= figures["fps_max"]).all()
    assert (figures["fps_max"] - figures["fps_min"] >= 0).all()
    assert figures.loc["a"].tolist() == [23.5, 20.0, 30.0, 4]
    assert speed_of(figures, "b") == {"fps": 5.25, "fps_min": 4.0, "fps_max": 6.0,
                                      "speed_rounds": 4}  # fmt: skip
    untimed = speed_of(figures, "results:theirs")  # accuracy only: NaN, not made up
    assert all(np.isnan(v) for v in untimed.values())


@pytest.mark.slow
def test_real_timing_on_the_datasets_frames(tmp_path):
    """The real clock on the fake dataset's frames: figures in order, no value asserted."""
    from fake_dataset import make_dataset

    runs = dataset_runs(make_dataset(tmp_path / "data"), frames=6, run_frames=3)
    result = time_pipelines(runs, {"paper": PRESETS["paper"], "fast": PRESETS["fast"]}, 3)
    figures = speed_figures(result.rounds)
    assert set(figures.index) == {"paper", "fast"} and (figures["speed_rounds"] == 3).all()
    assert np.isfinite(figures.to_numpy(float)).all() and (figures["fps_min"] > 0).all()
    assert (figures["fps_min"] <= figures["fps"]).all()
    assert (figures["fps"] <= figures["fps_max"]).all()


def _timed_summary(paper_max: float) -> pd.DataFrame:
    """fast leads on median frames/s; paper's fastest round is ``paper_max``; locus has an
    accuracy but no speed (another tool's results); theirs a given speed, no spread."""
    nan = float("nan")
    return pd.DataFrame(
        {
            "pipeline": ["paper", "fast", "locus", "theirs"],
            "fps": [80.0, 100.0, nan, 50.0],
            "fps_min": [70.0, 95.0, nan, nan],
            "fps_max": [paper_max, 110.0, nan, nan],
            "recall": [0.98, 0.97, 1.0, 0.9],
        }
    )


@pytest.mark.parametrize(("paper_max", "within", "rivals"), [(96.0, True, "paper"),
                                                             (90.0, False, "")])  # fmt: skip
def test_leaders_say_when_the_speed_lead_is_within_the_spread(tmp_path, paper_max, within, rivals):
    from bench.evaluate.compare_report import speed_section
    from bench.evaluate.leaders import leader_lines, leaders

    leads = leaders(_timed_summary(paper_max))
    fps = leads.set_index("measure").loc["fps"]
    assert fps["leader"] == "fast" and fps["value"] == 100.0
    assert fps["lead_within_spread"] is within and fps["spread_rivals"] == rivals
    recall = leads.set_index("measure").loc["recall"]  # no spread: not judged
    assert recall["lead_within_spread"] is None and recall["spread_rivals"] == ""
    line = leader_lines(leads)[0]
    assert ("within the spread across rounds of paper" in line) is within
    assert ("clear of the spread" in line) is not within
    # as leaders.csv is read back (NaN for the empty cells), the same words
    leads.to_csv(tmp_path / "leaders.csv", index=False)
    read = pd.read_csv(tmp_path / "leaders.csv")
    assert leader_lines(read)[0] == line
    said = speed_section(leads, {"frames": 40, "runs": 4, "samples": 4, "rounds": 5})
    assert said[0].startswith("Frames/s: 40 frames of this dataset, in 4 runs")
    assert said[2].startswith("The speed lead of fast: " + ("within" if within else "clear"))


def test_a_tie_or_a_single_timed_pipeline():
    from bench.evaluate.leaders import leaders

    tie = _timed_summary(90.0).assign(fps=[100.0, 100.0, float("nan"), 50.0])
    fps = leaders(tie).set_index("measure").loc["fps"]
    assert fps["leader"] == "paper, fast" and fps["lead_within_spread"] is True
    pair = tie.iloc[[0, 1]]  # a tie with nobody else timed is still a tie
    assert leaders(pair).set_index("measure").loc["fps", "lead_within_spread"] is True
    alone = _timed_summary(90.0).iloc[[1, 2]]  # fast, and locus without a speed
    fps = leaders(alone).set_index("measure").loc["fps"]
    assert fps["leader"] == "fast" and fps["lead_within_spread"] is None


def test_an_untimed_method_is_never_a_rival_for_the_speed_lead():
    """theirs (a results file's own speed, no spread) faster than every round: it leads on its
    median, not judged; below the leader it is no rival, whatever its value."""
    from bench.evaluate.leaders import leaders

    fast = _timed_summary(90.0).assign(fps=[80.0, 100.0, float("nan"), 500.0])
    fps = leaders(fast).set_index("measure").loc["fps"]
    assert fps["leader"] == "theirs" and fps["lead_within_spread"] is None
    close = _timed_summary(90.0).assign(fps=[80.0, 100.0, float("nan"), 99.0])
    fps = leaders(close).set_index("measure").loc["fps"]
    assert fps["leader"] == "fast" and fps["lead_within_spread"] is False
    assert fps["spread_rivals"] == ""


@pytest.mark.slow
def test_a_pipeline_without_a_speed_is_off_the_front_and_named(tmp_path, monkeypatch):
    import matplotlib.pyplot as plt

    from bench.evaluate import pareto
    from bench.evaluate.pareto import pareto_front, plot_pareto

    speed = np.array([100.0, np.nan, 50.0])
    assert pareto_front(speed, np.array([0.9, 1.0, 0.95]), True).tolist() == [True, False, True]
    summary = _timed_summary(96.0).assign(correct_rate=0.5, deflection_err_mm=1.0)
    monkeypatch.setattr(pareto.plt, "close", lambda fig: None)  # keep the figure to read it
    plot_pareto(summary, tmp_path / "pareto.png")
    assert (tmp_path / "pareto.png").stat().st_size > 1000
    for ax in plt.gcf().axes:  # locus, untimed: a dotted line at its accuracy, labelled
        dotted = [line for line in ax.get_lines() if line.get_linestyle() == ":"]
        assert len(dotted) == 1
        texts = [t.get_text() for t in ax.texts]
        assert "locus (accuracy only)" in texts and "locus" not in texts
    plt.close("all")


@pytest.mark.parametrize(
    ("option", "value", "message"),
    [
        ("--speed-frames", "0", "--speed-frames: 0: allowed range is 1..2000"),
        ("--speed-frames", "2001", "--speed-frames: 2001: allowed range is 1..2000"),
        ("--speed-rounds", "2", "--speed-rounds: 2: allowed range is 3..100"),
        ("--speed-rounds", "101", "--speed-rounds: 101: allowed range is 3..100"),
    ],
)
def test_compare_refuses_a_speed_option_out_of_range(tmp_path, capsys, option, value, message):
    from fake_dataset import make_dataset

    from bench.cli.main import main

    data = make_dataset(tmp_path / "data")
    before = sorted(p.name for p in data.rglob("*"))
    out = tmp_path / "report"
    argv = ["compare", str(data), "--pipelines", "paper", "--quick", "--out", str(out)]
    assert main([*argv, option, value]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and message in err
    assert not out.exists() and sorted(p.name for p in data.rglob("*")) == before


def test_bench_pipeline_refuses_too_few_rounds(tmp_path, capsys):
    from bench.cli.main import main

    out = tmp_path / "bench"
    assert main(["bench", "pipeline", "--rounds", "1", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert err == (
        "whiskerbench bench pipeline: error: --rounds: 1: allowed range is 3..100 (a median "
        "and a spread need 3)"
    )
    assert not out.exists()
