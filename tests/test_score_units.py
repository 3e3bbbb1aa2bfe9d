"""``score`` reuses a sample scored before by the same code and settings (bench.evaluate
.score_units), never one that is damaged, swapped or made otherwise; it refuses a folder holding
another dataset's samples and labels that do not fit the sample, before writing anything."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pandas as pd
import pytest
from conftest import copy_pair
from test_detect import _reseal

import bench.evaluate.score as score_module
from bench.cli.main import main
from bench.evaluate import score_units
from bench.evaluate.score import score_dataset
from pipeline.presets import PRESETS, get_pipeline
from scenes.tables import CORNER_COLUMNS, check_labels

pytestmark = pytest.mark.usefixtures("figures_not_drawn")

FAST = PRESETS["fast"]


@pytest.fixture
def data(rendered_pair, tmp_path):
    return copy_pair(rendered_pair, tmp_path / "data")


def _counting(monkeypatch) -> list[str]:
    """The samples detected on from now on (reused ones are not)."""
    detected, score = [], score_module._score_sample

    def counted(task, context):
        detected.append(task.record["sample_id"])
        return score(task, context)

    monkeypatch.setattr(score_module, "_score_sample", counted)
    return detected


@pytest.mark.slow
def test_a_rerun_reuses_every_sample_and_writes_the_same_table(data, tmp_path, monkeypatch, capsys):
    out = tmp_path / "scores"
    first = score_dataset(data, FAST, out)
    table = (out / "samples.csv").read_bytes()
    assert first.attrs["reused"] == []
    (out / "samples.csv").unlink()  # as if stopped before the end
    (out / "manifest.json").unlink()
    detected = _counting(monkeypatch)
    capsys.readouterr()
    assert main(["score", str(data), "--pipeline", "fast", "--out", str(out)]) == 0
    assert "2 samples (2 scored by an earlier run of the same code and settings)" in (
        capsys.readouterr().out
    )
    assert detected == []
    assert (out / "samples.csv").read_bytes() == table  # the same bytes, timing included
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["reused"] == sorted(first["sample_id"])
    again = score_dataset(data, FAST, out)  # the table returned is the one written
    pd.testing.assert_frame_equal(again, first)


@pytest.mark.slow
def test_a_damaged_swapped_or_otherwise_made_sample_is_scored_again(data, tmp_path, monkeypatch):
    out = tmp_path / "scores"
    first = score_dataset(data, FAST, out)
    twin, branch = sorted(first["sample_id"], key=lambda s: "none" not in s)
    with (out / branch / "detections.parquet").open("ab") as f:
        f.write(b"\0")  # damaged: redone, the twin reused
    detected = _counting(monkeypatch)
    assert score_dataset(data, FAST, out).attrs["reused"] == [twin]
    assert detected == [branch]
    shutil.copy(out / twin / score_units.RECORD, out / branch / score_units.RECORD)  # swapped
    detected.clear()
    score_dataset(data, FAST, out)
    assert detected == [branch]
    # other code: nothing reused (the hash of the project's files is part of the settings)
    monkeypatch.setattr(score_units, "code_sha256", lambda: "0" * 64)
    detected.clear()
    score_dataset(data, FAST, out)
    assert sorted(detected) == sorted(first["sample_id"])
    # another pipeline into the same folder: nothing reused
    detected.clear()
    score_dataset(data, get_pipeline("fast/window=3-23-10"), out)
    assert sorted(detected) == sorted(first["sample_id"])


def _tree(folder) -> list[str]:
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*"))


@pytest.mark.slow  # the rendered pair
def test_a_folder_with_another_datasets_samples_is_refused_before_any_write(
    rendered_pair, tmp_path, capsys
):
    out = tmp_path / "mixed"
    (out / "far-away-sample").mkdir(parents=True)
    (out / "far-away-sample" / "detections.parquet").write_bytes(b"")
    before = _tree(tmp_path)
    assert main(["score", str(rendered_pair), "--pipeline", "fast", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert "far-away-sample, not a sample of this dataset" in err and len(err.splitlines()) == 1
    assert _tree(tmp_path) == before


def _edited(data, edit) -> tuple[str, str]:
    """The branch sample's labels edited by ``edit`` and resealed as the dataset's own:
    (sample id, the labels file's path)."""
    sample_id = next(p.name for p in sorted(data.iterdir()) if "-100-" in p.name)
    path = data / sample_id / "labels.parquet"
    edit(pd.read_parquet(path)).to_parquet(path, index=False)
    _reseal(data, sample_id)
    return sample_id, str(path)


def _drop_frame(t):
    return t[t["frame"] != 5]


def _repeat_row(t):
    return pd.concat([t, t[t["frame"] == 5].head(1)]).sort_values(["frame", "marker_id"])


def _nan_corner(t):
    t = t.copy()
    t.loc[t.index[t["visible"]][0], CORNER_COLUMNS[0][0]] = np.nan
    return t


@pytest.mark.slow  # the rendered pair
@pytest.mark.parametrize(
    "edit, says",
    [
        (_drop_frame, "no rows for frame"),  # resealed with sample.json's frames to match
        (_repeat_row, "two rows"),
        (_nan_corner, "not a finite number"),
    ],
)
def test_labels_that_do_not_fit_the_sample_are_refused_before_any_write(
    rendered_pair, tmp_path, capsys, edit, says
):
    data = copy_pair(rendered_pair, tmp_path / "data")
    _, path = _edited(data, edit)
    before = _tree(tmp_path)
    assert main(["score", str(data), "--pipeline", "fast"]) == 2
    err = capsys.readouterr().err.strip()
    assert path in err and says in err and len(err.splitlines()) == 1, err
    assert _tree(tmp_path) == before


def test_check_labels_names_the_frame_and_marker():
    frames = np.repeat(np.arange(3), 2)
    table = pd.DataFrame({"frame": frames, "marker_id": np.tile([0, 1], 3)})
    from scenes.tables import LABELS

    for column in LABELS:
        if column.name not in table:
            table[column.name] = np.zeros(len(table), column.dtype)
    check_labels(table, 3, "labels")  # one row per marker and frame: accepted
    with pytest.raises(ValueError, match="labels: frames 0..2 outside the sample's 0..1"):
        check_labels(table, 2, "labels")
    with pytest.raises(ValueError, match=r"labels: no rows for frame 3 \(of 0..3\)"):
        check_labels(table, 4, "labels")
    table.loc[3, "visible"] = True
    table.loc[3, CORNER_COLUMNS[2][1]] = np.inf
    with pytest.raises(ValueError, match="frame 1, marker 1: visible, with a corner"):
        check_labels(table, 3, "labels")


def test_a_pipeline_name_instead_of_its_config_is_a_clear_type_error(tmp_path):
    with pytest.raises(TypeError, match="'fast' is a str, not a PipelineConfig; get_pipeline"):
        score_dataset(tmp_path, "fast", tmp_path / "out")
    assert not (tmp_path / "out").exists()


def test_nothing_is_reused_for_a_plugin_or_another_tools_detections_or_other_libraries(
    monkeypatch,
):
    from types import SimpleNamespace

    own = score_units.run_units("s", FAST, external=False)
    assert own == score_units.unit_settings("s") and own != score_units.unit_settings("t")
    plugin = SimpleNamespace(detector=SimpleNamespace(backend="plugin:mine:detect"))
    assert score_units.run_units("s", plugin, external=False) is None  # the user's code
    assert score_units.run_units("s", FAST, external=True) is None  # their file is no setting
    versions = dict(score_units.package_versions())
    monkeypatch.setattr(
        score_units, "package_versions", lambda: {**versions, "numpy": "0.0"}
    )  # another library, another answer: nothing reused
    assert score_units.run_units("s", FAST, external=False) != own
