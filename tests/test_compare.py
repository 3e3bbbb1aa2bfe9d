"""``whiskerbench compare``: the Pareto front, and the report end to end on a rendered pair."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pandas as pd
import pytest

from bench.evaluate.compare import pareto_front
from pipeline.presets import PRESETS, get_pipeline


def test_pareto_front_keeps_only_undominated_points():
    speed = np.array([10.0, 100.0, 50.0, 50.0, 5.0])
    accuracy = np.array([0.9, 0.5, 0.8, 0.7, 0.95])
    assert pareto_front(speed, accuracy, True).tolist() == [True, True, True, False, True]
    error = np.array([0.1, 0.5, 0.2, 0.1, 0.05])  # lower is better: (50, 0.1) beats (10, 0.1)
    assert pareto_front(speed, error, False).tolist() == [False, True, False, True, True]
    assert pareto_front(np.array([1.0, 1.0]), np.array([0.5, 0.5]), True).all()  # ties stay


@pytest.mark.slow
def test_compare_writes_a_report_with_every_variant(rendered_pair, tmp_path):
    from bench.evaluate.compare import run_compare
    from bench.evaluate.sweep_config import QUICK_SWEEP

    sweep = dataclasses.replace(
        QUICK_SWEEP, alphas_deg=(0.0, 90.0), phis_deg=(0.0,), lightings=("lab",), images=3
    )
    variants = [PRESETS["paper"], get_pipeline("fast/window=3-23-10")]
    out = tmp_path / "report"
    summary = run_compare(rendered_pair, variants, out, sweep, speed_frames=3, speed_seconds=0.0)
    assert summary["pipeline"].tolist() == ["paper", "fast/window=3-23-10"]
    assert (summary["fps"] > 0).all() and (summary["samples"] == 2).all()
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
    assert str(rendered_pair / "manifest.json") in manifest["inputs"]


@pytest.mark.slow
def test_the_sweeps_use_the_datasets_camera_unless_told(rendered_pair, tmp_path):
    import pytest

    from bench.cli.evaluate import _sweep_camera
    from bench.cli.main import main

    assert _sweep_camera(None, rendered_pair).name == "ideal"  # what the pair was rendered with
    assert _sweep_camera("prototype", rendered_pair).name == "prototype"
    with pytest.raises(ValueError, match="--camera: 'nope' is neither"):
        _sweep_camera("nope", rendered_pair)
    out = tmp_path / "never"
    argv = ["compare", str(rendered_pair), "--quick", "--camera", "nope", "--out", str(out)]
    assert main(argv) == 2
    assert not out.exists()
