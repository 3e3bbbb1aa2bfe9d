"""The committed indoor grid (results/indoor, `make indoor`) is what docs/datasets.md says it is.

The videos stay out of the repository, so these checks tie the committed files to each other:
the score ran on the dataset the manifest describes (the default grid's indoor samples, every
frame, the prototype camera), its table and chart are the ones it wrote, and every outcome
follows from the gaps in the same row by the scorer's own rule.
"""

from __future__ import annotations

import json
from pathlib import Path

import pandas as pd
import pytest

from bench.common.manifest import sha256
from bench.dataset.config import DatasetConfig
from bench.evaluate.score import branch_outcome

RESULTS = Path(__file__).resolve().parents[1] / "results" / "indoor"


@pytest.fixture(scope="module")
def committed() -> tuple[dict, dict, pd.DataFrame]:
    dataset = json.loads((RESULTS / "dataset-manifest.json").read_text())
    score = json.loads((RESULTS / "score-manifest.json").read_text())
    return dataset, score, pd.read_csv(RESULTS / "samples.csv")


def test_dataset_is_the_default_indoor_grid_on_every_frame(committed):
    dataset, _, samples = committed
    config = dataset["config"]
    expected = DatasetConfig(protocols=("indoor",))
    want = json.loads(json.dumps(expected.to_json(), default=str))  # tuples as JSON lists
    assert config["protocols"] == ["indoor"] and config["frames_step"] == 1
    assert dataset["camera_profile"] == "prototype"
    for key in ("foliage", "distances", "branches", "lightings", "mechanics", "seed"):
        assert config[key] == want[key], key
    ids = sorted(s.sample_id for s in expected.samples())
    assert sorted(dataset["samples"]) == ids == sorted(samples["sample_id"])


def test_score_read_the_committed_dataset_and_wrote_these_files(committed):
    dataset, score, _ = committed
    assert score["kind"] == "score" and score["config"]["pipeline"]["name"] == "paper"
    videos = {k.split("/")[-2]: v for k, v in score["inputs"].items() if k.endswith("video.mp4")}
    recorded = {k.split("/")[0]: v for k, v in dataset["files"].items() if k.endswith("video.mp4")}
    assert videos == recorded and len(videos) == len(dataset["samples"])
    for name in ("samples.csv", "grid-indoor-sun.png"):
        assert sha256(RESULTS / name) == score["outputs"][name], name


def test_every_outcome_follows_from_its_gaps(committed):
    *_, samples = committed
    scored = samples[samples["outcome"] != "refused"]
    assert len(scored) > 0
    for row in scored.itertuples():
        got = branch_outcome(json.loads(row.estimated_gaps), json.loads(row.true_gaps))
        assert got["outcome"] == row.outcome, row.sample_id
    refused = samples[samples["outcome"] == "refused"]  # the column is written only with one
    assert refused.empty or refused["refused_reason"].str.startswith("no no-contact frames").all()
