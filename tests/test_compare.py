"""``whiskerbench compare``: the Pareto front, and the report end to end on a rendered pair."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pandas as pd
import pytest
from conftest import drawn_only

from bench.evaluate.pareto import pareto_front
from pipeline.presets import PRESETS, get_pipeline


def test_pareto_front_keeps_only_undominated_points():
    speed = np.array([10.0, 100.0, 50.0, 50.0, 5.0])
    accuracy = np.array([0.9, 0.5, 0.8, 0.7, 0.95])
    assert pareto_front(speed, accuracy, True).tolist() == [True, True, True, False, True]
    error = np.array([0.1, 0.5, 0.2, 0.1, 0.05])  # lower is better: (50, 0.1) beats (10, 0.1)
    assert pareto_front(speed, error, False).tolist() == [False, True, False, True, True]
    assert pareto_front(np.array([1.0, 1.0]), np.array([0.5, 0.5]), True).all()  # ties stay


@pytest.mark.slow
def test_compare_writes_a_report_with_every_variant(rendered_pair, tmp_path, monkeypatch):
    from bench.evaluate.compare import run_compare
    from bench.evaluate.sweep_config import QUICK_SWEEP

    drawn_only(monkeypatch, "pareto.png", "sweeps.png", "grid-*.png")  # the report's figures

    sweep = dataclasses.replace(
        QUICK_SWEEP, alphas_deg=(0.0, 90.0), phis_deg=(0.0,), lightings=("lab",), images=3
    )
    variants = [PRESETS["paper"], get_pipeline("fast/window=3-23-10")]
    out = tmp_path / "report"
    summary = run_compare(rendered_pair, variants, out, sweep, speed_frames=12, speed_rounds=3)
    assert summary["pipeline"].tolist() == ["paper", "fast/window=3-23-10"]
    assert (summary["fps"] > 0).all() and (summary["samples"] == 2).all()
    _check_the_speed(rendered_pair, out, summary, [v.name for v in variants])
    paper = summary.iloc[0]
    assert paper["correct_rate"] == 1.0 and paper["recall"] > 0.98
    report = (out / "report.md").read_text()
    for picture in (
        "pareto.png",
        "sweeps.png",
        "grids/paper-grid-outdoor-lab.png",
        "grids/fast~window=3-23-10-grid-outdoor-lab.png",
    ):
        assert f"]({picture})" in report and (out / picture).stat().st_size > 1000
    sweeps = pd.read_csv(out / "sweeps.csv")
    assert set(sweeps["pipeline"]) == {"paper", "fast/window=3-23-10"}
    assert (sweeps.groupby(["pipeline", "axis", "level"])["seed"].nunique() == 2).all()
    assert (out / "boundaries.csv").exists() and (out / "summary.csv").exists()
    # bulk per-sample output stays beside the dataset, not in the report
    assert (rendered_pair / "scores" / "fast~window=3-23-10" / "samples.csv").exists()
    assert not list(out.rglob("*.parquet"))
    # provenance: the sweep config is a file beside the table; the manifest's digests hold
    from test_provenance import check_manifest

    sweep_config = json.loads((out / "sweep_config.json").read_text())
    assert sweep_config["config"] == json.loads(json.dumps(sweep.to_json(), default=str))
    assert [p["name"] for p in sweep_config["pipelines"]] == ["paper", "fast/window=3-23-10"]
    manifest = check_manifest(out, "compare")
    assert {"report.md", "sweeps.csv", "sweep_config.json"} <= set(manifest["outputs"])
    assert {"sweeps_band_ends.csv", "boundaries_band_ends.csv"} <= set(manifest["outputs"])
    assert str(rendered_pair / "manifest.json") in manifest["inputs"]
    _check_the_band(out, sweep, sweeps, len(variants))


def _check_the_speed(dataset, out, summary: pd.DataFrame, names: list[str]) -> None:
    """Timed on the dataset's own frames, alternating over the rounds asked for; the median
    inside its spread; leaders.csv and the report say whether the speed lead is within it."""
    from bench.dataset.loader import open_dataset

    ds = open_dataset(dataset)
    frames = pd.read_csv(out / "speed_frames.csv")
    assert set(frames["sample_id"]) == set(ds.sample_ids)  # 2 runs (10 and 2): one a sample
    for row in frames.itertuples():
        assert 0 <= row.frame < len(ds[row.sample_id])
    assert frames["timed"].sum() == 12
    rounds = pd.read_csv(out / "speed_rounds.csv")
    assert [rounds[rounds["round"] == r]["pipeline"].tolist() for r in range(3)] == [
        names, names[::-1], names
    ]  # fmt: skip
    assert (summary["speed_rounds"] == 3).all()
    assert (summary["fps_min"] <= summary["fps"]).all()
    assert (summary["fps"] <= summary["fps_max"]).all()
    fps = pd.read_csv(out / "leaders.csv").set_index("measure").loc["fps"]
    leader = summary.set_index("pipeline").loc[fps["leader"]]
    other = summary.set_index("pipeline").drop(fps["leader"]).iloc[0]
    assert fps["lead_within_spread"] == (other["fps_max"] >= leader["fps_min"])
    report = (out / "report.md").read_text()
    assert "Frames/s: 12 frames of this dataset, in 2 runs" in report
    assert f"The speed lead of {fps['leader']}: " in report


def _check_the_band(out, sweep, sweeps: pd.DataFrame, pipelines: int) -> None:
    """The sweeps through the prototype twin: the lens-sharpness axis at its band's ends, the
    boundary axes again at each end, and leaders.csv's verdicts follow the tables beside it."""
    from bench.evaluate.sweep_config import BOUNDARY_AXES

    low, high = sweep.camera.band.psf_ends
    assert sweep.camera.name == "prototype" and low < 1 < high
    lens = sweeps[sweeps["axis"] == "psf_scale"]
    assert sorted(set(lens["level_value"])) == [low, high]  # QUICK: the band's ends
    ends = pd.read_csv(out / "sweeps_band_ends.csv")
    assert set(ends["psf_scale"]) == {low, high} and set(ends["axis"]) == set(BOUNDARY_AXES)
    assert len(ends) == 2 * pipelines * len(sweep.band_end_sweeps()[0].points())
    leads = pd.read_csv(out / "leaders.csv").set_index("measure")
    assert pd.isna(leads.loc["fps", "holds_across_band"])  # speed is not judged
    assert pd.isna(leads.loc["psf_scale", "holds_across_band"])  # it spans the band itself
    # recall (from the dataset at one scale): the leaders at each end are the lens axis' there
    expected = []
    for end in (low, high):
        recall = lens[lens["level_value"] == end].groupby("pipeline", sort=False)["recall"].mean()
        expected.append(f"{end:g}: " + ", ".join(recall.index[recall == recall.max()]))
    assert leads.loc["recall", "band_leaders"] == "; ".join(expected)
    # alpha: the leaders at each end are those of that end's rerun (last level kept)
    edges = pd.read_csv(out / "boundaries_band_ends.csv")
    alpha = edges[edges["axis"] == "alpha_deg"]
    judged = leads.loc["alpha_deg"]
    holders = set(judged["leader"].split(", "))
    for end in (low, high):
        kept = alpha[alpha["psf_scale"] == end].set_index("pipeline")["last_ok"].fillna(-np.inf)
        best = [name for name in kept.index if kept[name] == kept.max()]
        assert f"{end:g}: {', '.join(best)}" in judged["band_leaders"]
        holders &= set(best)
    assert judged["holds_across_band"] == bool(holders)
    report = (out / "report.md").read_text()
    assert "## Across the lens' uncertain blur" in report
    assert f"{low:g} to {high:g} times the table as calibrated" in report
    assert "Leads that hold across the band" in report or "do not hold" in report


@pytest.mark.slow
@pytest.mark.usefixtures("figures_not_drawn")
def test_the_sweeps_use_the_datasets_camera_unless_told(rendered_pair, tmp_path):
    import pytest

    from bench.cli.compare import _sweep_camera
    from bench.cli.main import main

    assert _sweep_camera(None, rendered_pair).name == "ideal"  # what the pair was rendered with
    assert _sweep_camera("prototype", rendered_pair).name == "prototype"
    with pytest.raises(ValueError, match="--camera: 'nope' is neither"):
        _sweep_camera("nope", rendered_pair)
    out = tmp_path / "never"
    argv = ["compare", str(rendered_pair), "--quick", "--camera", "nope", "--out", str(out)]
    assert main(argv) == 2
    assert not out.exists()


def _hand_summary() -> pd.DataFrame:
    """Four pipelines, two of them on locus' detector; one measure tied."""
    nan = float("nan")
    return pd.DataFrame(
        {
            "pipeline": ["paper", "fast", "locus", "robust/detector=locus"],
            "fps": [16.0, 150.0, 25.0, 20.0],
            "recall": [0.98, 0.97, 1.0, 1.0],
            "corner_err_px": [0.9, 1.1, 0.24, 0.1],
            "own_rot_err_deg": [nan, nan, 3.0, 2.5],
        }
    )


def _hand_edges() -> pd.DataFrame:
    nan = float("nan")
    rows = [
        ("paper", "alpha_deg", 92.0, ""),
        ("fast", "alpha_deg", 92.0, ""),
        ("locus", "alpha_deg", nan, "0,40,92"),  # fails from the first level
        ("robust/detector=locus", "alpha_deg", 40.0, "92"),
        ("paper", "lighting", nan, "canopy"),
        ("fast", "lighting", nan, "backlit,canopy"),
        ("locus", "lighting", nan, ""),
        ("robust/detector=locus", "lighting", nan, "canopy"),
    ]
    return pd.DataFrame(rows, columns=["pipeline", "axis", "last_ok", "failing"])


def test_who_leads_on_a_hand_made_summary():
    from bench.evaluate.leaders import is_peer, leader_lines, leaders

    assert [is_peer(n) for n in _hand_summary()["pipeline"]] == [False, False, True, False]
    assert is_peer("apriltag/refine=lines") and not is_peer("paper/detector=apriltag")
    t = leaders(_hand_summary(), _hand_edges()).set_index("measure")
    # only the measures present, summary first, then the boundary axes
    assert list(t.index) == ["fps", "recall", "corner_err_px", "own_rot_err_deg", "alpha_deg",
                             "lighting"]  # fmt: skip
    fps = t.loc["fps"]
    assert (fps["leader"], fps["value"]) == ("fast", 150.0)
    assert (fps["best_peer"], fps["peer_value"]) == ("locus", 25.0)
    recall = t.loc["recall"]  # a tie names both; the project's best is the locus-based robust
    assert recall["leader"] == "locus, robust/detector=locus"
    assert (recall["best_project"], recall["best_peer"]) == ("robust/detector=locus", "locus")
    assert t.loc["corner_err_px", "leader"] == "robust/detector=locus"  # lower is better
    own = t.loc["own_rot_err_deg"]  # NaN (OpenCV has no own pose) is not a value
    assert (own["leader"], own["best_project"], own["best_peer"]) == (
        "robust/detector=locus", "robust/detector=locus", "locus"
    )  # fmt: skip
    alpha = t.loc["alpha_deg"]
    assert (alpha["leader"], alpha["value"]) == ("paper, fast", 92.0)
    assert alpha["best_peer"] == "locus" and alpha["peer_value"] == -np.inf
    lighting = t.loc["lighting"]  # fewest lightings failed
    assert (lighting["leader"], lighting["value"]) == ("locus", 0.0)
    assert (lighting["best_project"], lighting["project_value"]) == (
        "paper, robust/detector=locus", 1.0
    )  # fmt: skip
    lines = leader_lines(leaders(_hand_summary(), _hand_edges()))
    assert lines[0] == "frames/s: fast leads (150); best project pipeline fast (150); best peer " \
        "locus (25)"  # fmt: skip
    assert lines[1].startswith("marker recall: locus, robust/detector=locus lead (1);")
    assert "best peer locus (fails from the first level)" in lines[4]
    # change the values: the leader follows them
    faster = _hand_summary().assign(fps=[16.0, 150.0, 200.0, 20.0])
    t = leaders(faster).set_index("measure")
    assert t.loc["fps", "leader"] == "locus" and t.loc["fps", "best_project"] == "fast"
    assert "alpha_deg" not in t.index  # no sweeps, no boundary rows


def _hand_band() -> dict[str, dict[float, pd.Series]]:
    """Band-end values for three measures of :func:`_hand_summary` / :func:`_hand_edges`:
    recall's tied lead keeps one of its leaders at both ends, corner error's changes hands at
    the high end, alpha's tie at the low end keeps its leader."""
    names = ["paper", "fast", "locus", "robust/detector=locus"]
    nan = float("nan")
    return {
        "recall": {
            0.5: pd.Series([1.0, 1.0, 1.0, 0.99], names),
            1.5: pd.Series([0.2, 0.1, 0.97, 0.96], names),
        },
        "corner_err_px": {
            0.5: pd.Series([0.3, 0.4, 0.2, 0.08], names),
            1.5: pd.Series([nan, nan, 0.3, 0.35], names),  # NaN: not found, not a value
        },
        "alpha_deg": {
            0.5: pd.Series([92.0, 92.0, 40.0, 92.0], names),
            1.5: pd.Series([92.0, 40.0, -np.inf, 40.0], names),
        },
    }


def test_whether_a_lead_holds_across_the_band():
    from bench.evaluate.leaders import band_lines, leader_lines, leaders

    t = leaders(_hand_summary(), _hand_edges(), _hand_band()).set_index("measure")
    recall = t.loc["recall"]  # locus and robust/detector=locus tie at 1; locus leads at both
    assert recall["holds_across_band"] is True
    assert recall["band_leaders"] == "0.5: paper, fast, locus; 1.5: locus"
    corner = t.loc["corner_err_px"]  # robust/detector=locus leads at 1 and 0.5, not at 1.5
    assert corner["holds_across_band"] is False
    assert corner["band_leaders"] == "0.5: robust/detector=locus; 1.5: locus"
    alpha = t.loc["alpha_deg"]  # paper keeps its (tied) lead at both ends, fast does not
    assert alpha["holds_across_band"] is True and alpha["band_leaders"].endswith("1.5: paper")
    for measure in ("fps", "own_rot_err_deg", "lighting"):  # no evidence: not judged
        assert t.loc[measure, "holds_across_band"] is None
        assert t.loc[measure, "band_leaders"] == ""
    lines = leader_lines(leaders(_hand_summary(), _hand_edges(), _hand_band()))
    assert lines[2].endswith(
        "; does not hold across the band (leading at PSF 0.5: robust/detector=locus; 1.5: locus)"
    )
    assert "across the band" not in lines[0]  # frames/s: not judged
    said = band_lines(t.reset_index())
    assert said[0] == (
        "Leads that hold across the band: marker recall (locus, robust/detector=locus); "
        f"{t.loc['alpha_deg', 'label']} (paper, fast)."
    )
    assert said[1].startswith("Leads that do not hold across the band: corner error (px, median)")
    assert "robust/detector=locus at the nominal PSF" in said[1]
    assert said[2].startswith("Not judged across the band") and "frames/s" in said[2]
    assert band_lines(leaders(_hand_summary(), _hand_edges())) == []  # no band, no verdicts


def _without_peers(monkeypatch):
    """Every peer's library reported as not installed."""
    from pipeline import backends

    def missing(name, package):
        def load():
            raise backends.missing_library(name, package)

        return load

    for name, package in (("locus", "locus-tag"), ("apriltag", "apriltag-python")):
        module = backends._adapter(backends.BACKENDS[name].adapter)
        monkeypatch.setattr(module, "load", missing(name, package))


def test_compare_refuses_a_missing_peer_in_one_line(monkeypatch, tmp_path, capsys):
    from bench.cli.main import main

    _without_peers(monkeypatch)
    dataset, out = tmp_path / "data", tmp_path / "report"
    dataset.mkdir()
    argv = ["compare", str(dataset), "--pipelines", "paper,locus", "--quick", "--out", str(out)]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "locus-tag" in err and "pip install -e '.[peers]'" in err
    assert not out.exists() and list(dataset.iterdir()) == []  # nothing written
    out = tmp_path / "bench"
    assert main(["bench", "pipeline", "--pipelines", "paper,locus", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "locus-tag" in err and not out.exists()


def test_without_peers_the_default_pipelines_are_the_opencv_presets(monkeypatch):
    from bench.cli.compare import _installed_presets

    _without_peers(monkeypatch)
    names = [p.name for p in _installed_presets()]
    assert names == [n for n, p in PRESETS.items() if p.detector.backend == "opencv"]
    assert "paper" in names and "locus" not in names


def test_the_sweeps_refuse_a_family_a_backend_cannot_detect():
    from bench.evaluate.sweep_config import SweepConfig
    from bench.evaluate.sweeps import sweep_pipelines

    sweep = SweepConfig(dictionary="apriltag_25h9")  # AprilTag 3 and OpenCV have it, locus not
    with pytest.raises(ValueError, match="^pipeline 'locus' in the sweeps: detector locus cannot"):
        sweep_pipelines([PRESETS["paper"], PRESETS["locus"]], sweep)
    paper = sweep_pipelines([PRESETS["paper"]], sweep)[0]
    assert paper.detector.dictionary == "apriltag_25h9"  # the sweep's family replaces its own


def peer_compare(tmp_path_factory, worker_id, rendered_pair):
    """(folder, summary) of ``compare`` of fast (the project's pipeline beside the peer: half
    of paper's work on the pair's frames) and locus on a copy of the rendered pair, figures
    not drawn, run once per test run (:func:`conftest.compare_once`). Read, never written:
    :func:`test_a_peer_runs_in_every_part_of_compare` reads the report, test_score_backends'
    locus test the scores of locus (``score_dataset``'s, as ``score`` writes them)."""
    from conftest import compare_once

    from bench.evaluate.sweep_config import QUICK_SWEEP

    sweep = dataclasses.replace(
        QUICK_SWEEP, alphas_deg=(0.0,), phis_deg=(30.0,), lightings=("lab",), blur_px=(0.0,),
        read_noise_e=(3.0,), seeds=1, images=2,
    )  # fmt: skip
    variants = [PRESETS["fast"], PRESETS["locus"]]
    return compare_once(
        tmp_path_factory, worker_id, rendered_pair, "peer-compare", lambda _: variants, sweep
    )


@pytest.mark.slow
def test_a_peer_runs_in_every_part_of_compare(rendered_pair, tmp_path_factory, worker_id):
    from pipeline.backends import available

    if not available("locus"):
        pytest.skip("locus-tag is not installed")
    folder, summary = peer_compare(tmp_path_factory, worker_id, rendered_pair)
    out = folder / "report"
    locus = summary.set_index("pipeline").loc["locus"]
    assert locus["fps"] > 0 and locus["recall"] > 0.9 and np.isfinite(locus["own_rot_err_deg"])
    sweeps = pd.read_csv(out / "sweeps.csv").set_index("pipeline")
    assert sweeps.loc["fast", "own_rot_err_deg"].isna().all()
    assert np.isfinite(sweeps.loc["locus", "own_rot_err_deg"]).any()
    assert (sweeps["backend_failures"] == 0).all()
    leads = pd.read_csv(out / "leaders.csv").set_index("measure")
    assert leads.loc["fps", "best_peer"] == "locus" and leads.loc["fps", "best_project"] == "fast"
    report = (out / "report.md").read_text()
    assert "## Who leads" in report and "- locus: no failed frames" in report
    assert "](grids/locus-grid-outdoor-lab.png)" in report


def _all_refused(samples: int = 2) -> pd.DataFrame:
    """The scores of a pipeline that refused every sample, as ``score_dataset`` tables them."""
    from bench.evaluate.score import SCORED_COLUMNS

    rows = [
        {"sample_id": f"s{i}", "outcome": "refused", "refused_reason": "no no-contact frames"}
        for i in range(samples)
    ]
    columns = ["sample_id", "outcome", "refused_reason", *SCORED_COLUMNS]
    return pd.DataFrame(rows).reindex(columns=columns)


@pytest.mark.slow  # over a second of CPU: out of `make test-fast`
def test_a_pipeline_that_refuses_every_sample_keeps_its_row(tmp_path):
    """No rate, no error (NaN), the counts kept; off the Pareto front, in the chart's and the
    report's words, leading on nothing but its speed."""
    from bench.evaluate.compare import summarize
    from bench.evaluate.compare_report import refused_lines
    from bench.evaluate.leaders import leaders
    from bench.evaluate.pareto import plot_pareto

    row = summarize("naive", _all_refused())
    assert (row["samples"], row["refused_samples"]) == (2, 2)
    for rate in ("correct_rate", "recall", "deflection_err_mm", "corner_err_px", "rot_err_deg"):
        assert np.isnan(row[rate]), rate
    assert pareto_front(np.array([5.0, 1.0]), np.array([np.nan, 0.5]), True).tolist() == [
        False, True
    ]  # fmt: skip
    summary = pd.DataFrame([{**row, "fps": 50.0}])
    plot_pareto(summary, tmp_path / "alone.png")  # every pipeline without a value: still a chart
    paper = {**row, "pipeline": "paper", "refused_samples": 0, "correct_rate": 0.5, "recall": 0.9}
    summary = pd.DataFrame([{**row, "fps": 50.0}, {**paper, "fps": 20.0}])
    plot_pareto(summary, tmp_path / "pareto.png")
    assert (tmp_path / "pareto.png").stat().st_size > 1000
    t = leaders(summary).set_index("measure")
    assert t.loc["fps", "leader"] == "naive" and t.loc["recall", "leader"] == "paper"
    assert t.loc["correct_rate", "leader"] == "paper"
    assert refused_lines(summary) == [
        "naive: refused all 2 samples (why: `refused_reason` in its scores' samples.csv), so it "
        "has no accuracy measure"
    ]


def _refusing(monkeypatch, refused: str) -> None:
    """Pipeline ``refused`` refuses every sample (no no-contact frames); the others run."""
    from bench.evaluate import detect
    from pipeline.deflection import NoBaselineError

    real = detect.run_detect

    def run_detect(video, camera, config, *args, **kwargs):
        if config.name == refused:
            raise NoBaselineError("no no-contact frames at the start (planted)")
        return real(video, camera, config, *args, **kwargs)

    monkeypatch.setattr(detect, "run_detect", run_detect)


@pytest.mark.slow
@pytest.mark.usefixtures("figures_not_drawn")
def test_score_and_compare_report_a_pipeline_that_refuses_every_sample(
    rendered_pair, tmp_path, monkeypatch, capsys
):
    import shutil

    from bench.cli.main import main
    from bench.evaluate import sweep_config
    from bench.evaluate.score import SCORED_COLUMNS

    dataset = tmp_path / "data"  # a copy: the session's pair keeps its own scores
    shutil.copytree(rendered_pair, dataset)
    _refusing(monkeypatch, "naive")
    assert main(["score", str(dataset), "--pipeline", "naive", "--out", str(tmp_path / "s")]) == 0
    out, err = capsys.readouterr()
    assert "2 samples, 2 refused: no rates;" in out and err.count("refused: no no-contact") == 2
    assert "note: naive refused 2 of 2 samples" in out and f"{tmp_path / 's'}/samples.csv" in out
    table = pd.read_csv(tmp_path / "s" / "samples.csv")
    assert set(SCORED_COLUMNS) <= set(table) and (table["outcome"] == "refused").all()

    tiny = dataclasses.replace(
        sweep_config.QUICK_SWEEP, alphas_deg=(0.0,), phis_deg=(0.0,), lightings=("lab",),
        blur_px=(0.0,), read_noise_e=(3.0,), seeds=1, images=2,
    )  # fmt: skip
    monkeypatch.setattr(sweep_config, "QUICK_SWEEP", tiny)
    monkeypatch.setattr(
        "bench.evaluate.compare.time_pipelines", lambda runs, named, rounds: _timing(named, 10.0)
    )
    report = tmp_path / "report"
    # beside it a pipeline that answers: fast, half of paper's work on the pair's frames
    argv = ["compare", str(dataset), "--pipelines", "fast,naive", "--quick", "--out", str(report)]
    assert main([*argv, "--speed-frames", "2", "--speed-rounds", "3"]) == 0
    out = capsys.readouterr().out
    assert "naive:    10.0 frames/s (9.0-11.0), refused all 2 samples, no rates" in out
    assert "speed lead of fast, naive: a tie, within the spread across rounds" in out
    assert f"refused_reason in {dataset / 'scores' / 'naive' / 'samples.csv'}" in out
    assert "note: fast" not in out  # it refused nothing and read the markers
    summary = pd.read_csv(report / "summary.csv").set_index("pipeline")
    assert summary.loc["naive", ["samples", "refused_samples"]].tolist() == [2, 2]
    assert np.isnan(summary.loc["naive", "correct_rate"]) and summary.loc["fast", "recall"] > 0.9
    # a scored table has no column the refused table lacks (SCORED_COLUMNS is complete)
    scored = pd.read_csv(dataset / "scores" / "fast" / "samples.csv")
    assert set(scored) <= set(table)
    assert "- naive: refused all 2 samples" in (report / "report.md").read_text()
    leads = pd.read_csv(report / "leaders.csv").set_index("measure")
    assert leads.loc["fps", "leader"] == "fast, naive" and leads.loc["recall", "leader"] == "fast"


def _timing(pipelines, fps: float):
    """Three rounds at ``fps`` - 1, ``fps`` and ``fps`` + 1 for every pipeline, in place of
    ``compare``'s timing."""
    from bench.evaluate.timing import ROUND_COLUMNS, Timing

    rows = [(r, p, name, 10, 10 / (fps - 1 + r), fps - 1 + r) for r in range(3)
            for p, name in enumerate(pipelines)]  # fmt: skip
    return Timing(pd.DataFrame(rows, columns=list(ROUND_COLUMNS)), {n: [] for n in pipelines})


class _Reached(BaseException):
    """compare reached its work with this sweep."""


@pytest.fixture(scope="module")
def fake_data(tmp_path_factory):
    from fake_dataset import make_dataset

    return make_dataset(tmp_path_factory.mktemp("compare") / "data")


def _sweep_of(argv: list[str], monkeypatch):
    """The sweep compare hands its work (the work itself replaced)."""
    from bench.cli.main import main
    from bench.evaluate import compare

    def reached(dataset, pipelines, out, sweep, **_):
        raise _Reached(sweep)

    monkeypatch.setattr(compare, "run_compare", reached)
    with pytest.raises(_Reached) as caught:
        main(["compare", *argv])
    return caught.value.args[0]


def test_quick_takes_an_explicit_seeds_as_other_quick_options_do(fake_data, monkeypatch):
    """--quick fills in only what was not given: --seeds 3 sweeps the quick levels 3 times."""
    from bench.evaluate.sweep_config import QUICK_SWEEP, sweep_options

    base = [str(fake_data), "--pipelines", "fast", "--quick"]
    assert _sweep_of(base, monkeypatch).seeds == QUICK_SWEEP.seeds
    sweep = _sweep_of([*base, "--seeds", "3"], monkeypatch)
    assert sweep.seeds == 3 and sweep.points() == _sweep_of(base, monkeypatch).points()
    assert sweep_options(sweep)[-2:] == ["--quick", "--seeds 3"]  # the figures' titles


@pytest.mark.parametrize(
    ("args", "says"),
    [
        (["--quick", "--seeds", "-7"], r"--seeds: -7: must be >= 1 \(with --quick\)$"),
        (["--quick", "--seeds", "0"], r"--seeds: 0: must be >= 1 \(with --quick\)$"),
        (["--quick", "--seeds", "100000000"], r"--seeds: 100000000: .* would take .*limit \d+"),
        (["--seeds", "4"], r"--seeds: 4: must be >= 5 \(use --quick for a smoke run\)$"),
    ],
)
def test_seeds_out_of_range_are_refused_with_or_without_quick(
    fake_data, tmp_path, capsys, args, says
):
    import re

    from bench.cli.main import main

    out = tmp_path / "never"
    assert main(["compare", str(fake_data), "--pipelines", "fast", *args, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and re.search(says, err[0]), err
    assert not out.exists() and not (fake_data / "scores").exists()


def test_a_lens_narrower_than_the_base_angle_is_refused_naming_camera(
    fake_data, tmp_path, capsys, monkeypatch
):
    """Like the study, the sweep's alphas end at the lens's edge (60 deg: accepted); its base
    angle (40 deg), where every other axis is read, is not moved: a 30-degree lens is refused
    naming --camera, never the sweep's own base_alpha_deg."""
    from bench.cli.main import main
    from scenes.camera import default_camera
    from scenes.profile import CameraProfile

    def lens(theta_max_deg: float):
        path = tmp_path / f"k{theta_max_deg:g}.json"
        camera = dataclasses.replace(default_camera(), theta_max_deg=theta_max_deg)
        path.write_text(json.dumps(CameraProfile(name=path.stem, lens=camera).to_json()))
        return str(path)

    base = [str(fake_data), "--pipelines", "fast", "--quick", "--camera"]
    assert max(_sweep_of([*base, lens(60.0)], monkeypatch).alphas_deg) == 60.0
    out = tmp_path / "never"
    assert main(["compare", *base, lens(30.0), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [
        f"whiskerbench compare: error: --camera {tmp_path}/k30.json: its lens sees 0..30 deg off "
        "axis; the sweep's base angle is 40 deg (every axis but alpha is read there): a lens "
        "that sees at least 40 deg is needed"
    ]
    assert not out.exists() and not (fake_data / "scores").exists()
