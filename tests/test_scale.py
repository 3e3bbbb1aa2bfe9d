"""``bench scale``: a row per (executor, workers), positive rates, identical outputs, and the
frame count of the extrapolation equal to what the generator renders.

The end-to-end run takes the in-process baseline and a pool: the benchmark hands the executor's
name to the study and the dataset and nothing else, and the same bytes on Dask are
``tests/test_dask.py``'s to check (the study on every executor, the dataset resumed on Dask).
A Dask row here took this test from 8.9 to 14.3 s (run alone, 2026-11-28)."""

from __future__ import annotations

import json

import pytest

from bench.benchmarks.scale import bench_scale, default_dataset_frames, scale_rows
from bench.dataset.config import DatasetConfig
from bench.study.config import StudyConfig

#: Two cells and two samples: each worker of two gets a task; what the test checks (rows, rates,
#: outputs identical across executors, the frame count) holds at any image and frame count, so
#: both are the fewest that still make a video: 2 images a cell, 2 frames a sample.
STUDY = StudyConfig(sizes_mm=(13.2,), alphas_deg=(0.0, 60.0), phis_deg=(0.0,), images=2)
#: Every 37th frame of the pair's 74-frame samples: 2 frames each.
FRAMES_STEP = 37


def test_rows_start_with_the_baseline_and_skip_what_is_not_asked():
    assert scale_rows(("inline", "pool", "dask"), 3) == [
        ("inline", 1),
        ("pool", 2),
        ("pool", 3),
        ("dask", 2),
        ("dask", 3),
    ]
    assert scale_rows(("pool",), 2) == [("inline", 1), ("pool", 2)]
    assert scale_rows(("inline", "pool", "dask"), 1) == [("inline", 1)]


def test_frame_count_follows_the_grid_and_the_step():
    one = DatasetConfig(
        foliage=("soft",), distances=("far",), branches=((),), protocols=("indoor",)
    )
    frames = default_dataset_frames(one)
    assert frames > 100  # the slow indoor protocol: hundreds of frames
    doubled = DatasetConfig(
        foliage=("soft", "stiff"), distances=("far",), branches=((),), protocols=("indoor",)
    )
    assert default_dataset_frames(doubled) == 2 * frames
    stepped = DatasetConfig(
        foliage=("soft",), distances=("far",), branches=((),), protocols=("indoor",), frames_step=3
    )
    assert default_dataset_frames(stepped) == -(-frames // 3)


@pytest.mark.start_early
@pytest.mark.slow
def test_scale_rows_rates_and_identical_outputs(variant, tmp_path, pair_config, capsys):
    if variant.startswith("scalar"):
        pytest.skip("frame rendering needs a JIT variant")
    import dataclasses

    dataset = dataclasses.replace(pair_config, frames_step=FRAMES_STEP)
    assert default_dataset_frames(dataset) >= 2 * len(dataset.samples())  # videos, not stills
    figures = bench_scale(STUDY, dataset, ("inline", "pool"), 2, variant, tmp_path / "b")
    rows = figures["rows"]
    assert [(r["executor"], r["workers"]) for r in rows] == [("inline", 1), ("pool", 2)]
    assert all(r["images_per_s"] > 0 and r["frames_per_s"] > 0 for r in rows)
    assert figures["outputs_identical"] is True
    assert "outputs identical: yes" in capsys.readouterr().out
    # what the extrapolation counts is what the generator rendered
    assert {r["frames"] for r in rows} == {default_dataset_frames(dataset)}
    written = json.loads((tmp_path / "b" / "bench.json").read_text())
    assert written["rows"] == json.loads(json.dumps(rows))
    manifest = json.loads((tmp_path / "b" / "manifest.json").read_text())
    assert manifest["kind"] == "bench-scale" and "bench.json" in manifest["outputs"]
