"""``score --detections``: another tool's detections scored as a built-in pipeline's, and every
malformed results file refused in one line with exit code 2 and nothing written."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from fake_dataset import SAMPLES, make_dataset

from bench.cli.main import main
from bench.common.manifest import sha256
from bench.dataset.loader import open_dataset
from scenes.tables import CORNER_COLUMNS, ROTATION_COLUMNS, TRANSLATION_COLUMNS

CORNERS = [name for pair in CORNER_COLUMNS for name in pair]
POSE = [*ROTATION_COLUMNS, *TRANSLATION_COLUMNS]
LONG, SHORT = SAMPLES


@pytest.fixture(scope="module")
def fake(tmp_path_factory) -> Path:
    return make_dataset(tmp_path_factory.mktemp("results") / "data")


@pytest.fixture(scope="module")
def truth(fake) -> pd.DataFrame:
    """The labels of every visible marker as a results table: an exact method."""
    parts = []
    for sample in open_dataset(fake):
        labels = sample.labels[sample.labels["visible"]]
        parts.append(labels[["frame", "marker_id", *CORNERS, *POSE]].assign(sample_id=sample.id))
    table = pd.concat(parts, ignore_index=True)
    return table[["sample_id", *table.columns[:-1]]]


def _score(fake: Path, results: Path, out: Path, *extra: str) -> int:
    argv = ["score", str(fake), "--detections", str(results), "--name", "exact", "--out", str(out)]
    return main([*argv, *extra])


def _samples(out: Path) -> pd.DataFrame:
    return pd.read_csv(out / "samples.csv").set_index("sample_id")


@pytest.mark.slow
def test_exact_corners_score_perfectly_and_without_timing_as_accuracy_only(
    fake, truth, tmp_path, capsys
) -> None:
    path = tmp_path / "exact.csv"
    truth.drop(columns=POSE).to_csv(path, index=False)
    assert _score(fake, path, tmp_path / "out") == 0
    assert "accuracy only" in capsys.readouterr().out
    table = _samples(tmp_path / "out")
    long = table.loc[LONG]
    assert long["recall"] == 1 and long["false_detections"] == 0
    assert long["corner_err_px"] == 0 and long["deflection_err_mm"] < 1e-9
    assert table["frames_per_s"].isna().all()  # never a made-up speed
    assert (tmp_path / "out" / LONG / "detections.parquet").is_file()
    manifest = json.loads((tmp_path / "out" / "manifest.json").read_text())
    assert manifest["inputs"][str(path)] == sha256(path)
    assert manifest["config"]["results"]["timed"] is False


@pytest.mark.slow  # over a second of CPU: out of `make test-fast`
def test_speed_from_the_files_times_or_fps(fake, truth, tmp_path) -> None:
    path = tmp_path / "timed.csv"
    truth.assign(frame_time_s=0.02).to_csv(path, index=False)
    assert _score(fake, path, tmp_path / "a") == 0
    assert np.allclose(_samples(tmp_path / "a")["frames_per_s"], 50)
    assert _score(fake, path, tmp_path / "b", "--fps", "31.5") == 0
    assert np.allclose(_samples(tmp_path / "b")["frames_per_s"], 31.5)


@pytest.mark.slow  # over a second of CPU: out of `make test-fast`
def test_a_folder_of_parquet_files_with_poses_and_the_dataset_hash(
    fake, truth, tmp_path, capsys
) -> None:
    folder = tmp_path / "results"
    folder.mkdir()
    digest = sha256(fake / "manifest.json")
    for sample_id, part in truth.groupby("sample_id"):
        rows = part.drop(columns="sample_id").assign(dataset_sha256=digest)
        rows.to_parquet(folder / f"{sample_id}.parquet", index=False)
    assert _score(fake, folder, tmp_path / "out") == 0
    long = _samples(tmp_path / "out").loc[LONG]
    assert long["recall"] == 1 and long["rot_err_deg"] < 1e-6 and long["trans_err_mm"] < 1e-9
    empty = truth[:0].drop(columns=["sample_id", *POSE])  # a header only: nothing found
    for sample_id in SAMPLES:
        (folder / f"{sample_id}.parquet").unlink()
    empty.to_csv(folder / f"{SHORT}.csv", index=False)
    truth[truth["sample_id"] == LONG].drop(columns=POSE).to_csv(folder / f"{LONG}.csv")
    assert _score(fake, folder, tmp_path / "again") == 2  # the CSV's index: an extra column
    assert "column 'Unnamed: 0' is not in the format" in capsys.readouterr().err
    truth[truth["sample_id"] == LONG].drop(columns=POSE).to_csv(folder / f"{LONG}.csv", index=False)
    assert _score(fake, folder, tmp_path / "again") == 0
    table = _samples(tmp_path / "again")
    assert table.loc[SHORT, "outcome"] == "refused" and table.loc[LONG, "recall"] == 1
    assert "no marker" in table.loc[SHORT, "refused_reason"]


def _break(table: pd.DataFrame, how: str) -> pd.DataFrame:
    t = table.copy()
    if how == "missing column":
        return t.drop(columns=CORNERS[4])
    if how == "extra column":
        return t.assign(confidence=1.0)
    if how == "some pose columns":
        return t.drop(columns=POSE[4])
    if how in ("nan corner", "inf corner"):
        t.loc[3, CORNERS[3]] = math.nan if how == "nan corner" else math.inf
    elif how == "corner outside":
        t.loc[3, CORNERS[0]] = 1e4
    elif how == "text frame":
        t["frame"] = t["frame"].astype(str)
        t.loc[3, "frame"] = "four"
    elif how == "unknown marker id":
        t.loc[3, "marker_id"] = 999  # 4x4_50 has ids 0 .. 49
    elif how == "duplicate row":
        t = pd.concat([t, t.iloc[[3]]], ignore_index=True)
    elif how == "frame not in video":
        t.loc[3, "frame"] = 10_000
    elif how == "another dataset's sample":
        t.loc[3, "sample_id"] = "stiff-close-none-outdoor-sun"
    elif how == "some samples only":
        t = t[t["sample_id"] != SHORT]
    elif how == "another dataset's hash":
        t["dataset_sha256"] = "0" * 64
    elif how.startswith("frame time "):  # 0: no timing; 1e-320: inf frames/s; 1e308: overflow
        t["frame_time_s"] = 0.02
        t.loc[3, "frame_time_s"] = float(how.split()[-1])
    return t


BROKEN = {  # how: what the one line must name
    "missing column": f"'{CORNERS[4]}' is missing",
    "extra column": "'confidence' is not in the format",
    "some pose columns": f"'{POSE[4]}' is missing",
    "nan corner": f"row 4: column '{CORNERS[3]}'",
    "inf corner": f"row 4: column '{CORNERS[3]}'",
    "corner outside": f"row 4: column '{CORNERS[0]}'",
    "text frame": "row 4: column 'frame'",
    "unknown marker id": "row 4: column 'marker_id'",
    "duplicate row": "a second row",
    "frame not in video": "row 4: column 'frame'",
    "another dataset's sample": "row 4: sample_id 'stiff-close-none-outdoor-sun'",
    "some samples only": f"no detections of sample {SHORT}",
    "another dataset's hash": "dataset_sha256",
    "frame time 0": "row 4: column 'frame_time_s' is 0.0; expected seconds in 1e-06 .. 3600",
    "frame time 1e-320": "row 4: column 'frame_time_s' is 1e-320; expected seconds in 1e-06",
    "frame time 1e308": "row 4: column 'frame_time_s' is 1e+308; expected seconds in 1e-06",
}


@pytest.mark.parametrize("how", list(BROKEN))
@pytest.mark.parametrize("suffix", [".csv", ".parquet"])
def test_bad_results_are_refused_in_one_line(fake, truth, tmp_path, capsys, how, suffix) -> None:
    path = tmp_path / f"broken{suffix}"
    table = _break(truth, how)
    if suffix == ".csv":
        table.to_csv(path, index=False)
    else:
        table.to_parquet(path, index=False)
    assert _score(fake, path, tmp_path / "out") == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    assert str(path) in err and BROKEN[how] in err, err
    assert not (tmp_path / "out").exists()  # nothing written


def test_bad_folders_and_options_are_refused(fake, truth, tmp_path, capsys) -> None:
    folder = tmp_path / "results"
    folder.mkdir()
    truth[truth["sample_id"] == LONG].to_csv(folder / f"{LONG}.csv", index=False)
    out = tmp_path / "out"
    assert _score(fake, folder, out) == 2
    assert f"no detections of sample {SHORT}" in capsys.readouterr().err
    (folder / "notes.txt").write_text("hello")
    assert _score(fake, folder, out) == 2
    assert "notes.txt: expected a <sample id>.csv" in capsys.readouterr().err
    (folder / "notes.txt").unlink()
    truth[:0].to_csv(folder / "other-sample.csv", index=False)
    assert _score(fake, folder, out) == 2
    assert "'other-sample' is not a sample of this dataset" in capsys.readouterr().err
    good = tmp_path / "good.csv"
    truth.to_csv(good, index=False)
    for extra, says in (
        (["--name", "../up"], "--name: '../up'"),
        (["--name", "paper"], "built-in pipeline's name"),
        (["--fps", "-3"], "--fps: -3: expected a finite number of frames/s in 1/3600 .. 1e+06"),
        (["--fps", "nan"], "--fps: nan"),
        (["--fps", "0"], "--fps: 0:"),
        (["--fps", "1e308"], "--fps: 1e+308:"),  # was inf frames/s and an overflow warning
        (["--fps", "1e-320"], "--fps: 9.99989e-321:"),
    ):
        assert _score(fake, good, out, *extra) == 2
        assert says in capsys.readouterr().err
    assert main(["score", str(fake), "--name", "x", "--out", str(out)]) == 2
    assert "go with --detections" in capsys.readouterr().err
    os.mkfifo(tmp_path / "fifo.csv")
    (tmp_path / "loop1").symlink_to("loop2")
    (tmp_path / "loop2").symlink_to("loop1")
    for name, says in (
        ("fifo.csv", "not a regular file (a named pipe)"),
        ("loop1", "a symlink loop"),
    ):
        assert _score(fake, tmp_path / name, out) == 2  # never "no such file or folder"
        assert capsys.readouterr().err.endswith(f"{name}: {says}\n")
    assert not out.exists()


def test_a_sample_with_both_a_csv_and_a_parquet_file_is_refused(
    fake, truth, tmp_path, capsys
) -> None:
    """Reading either file alone would score half the results without a word."""
    folder, out = tmp_path / "results", tmp_path / "out"
    folder.mkdir()
    for sample_id, part in truth.groupby("sample_id"):
        part.to_csv(folder / f"{sample_id}.csv", index=False)
    rows = truth[truth["sample_id"] == LONG]
    rows.iloc[len(rows) // 2 :].to_parquet(folder / f"{LONG}.parquet", index=False)
    assert _score(fake, folder, out) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    assert f"two files for sample {LONG}: {LONG}.csv and {LONG}.parquet" in err, err
    assert not out.exists()


def test_caps_bound_the_read(fake, truth, tmp_path, capsys, monkeypatch) -> None:
    from bench.evaluate import results_file

    path = tmp_path / "big.csv"
    truth.to_csv(path, index=False)
    monkeypatch.setattr(results_file, "MAX_ROWS", 100)
    assert _score(fake, path, tmp_path / "out") == 2
    assert "more than 100 rows" in capsys.readouterr().err
    monkeypatch.setattr(results_file, "MAX_FILE_BYTES", 1000)
    assert _score(fake, path, tmp_path / "out") == 2
    assert "expected at most 1000" in capsys.readouterr().err


#: Another tool: plain OpenCV on the loader's frames, its default parameters, no project code.
PLAIN_OPENCV = Path(__file__).resolve().parents[1] / "examples" / "results_file" / "plain_opencv.py"


@pytest.mark.slow
@pytest.mark.usefixtures("figures_not_drawn")  # the scores are the answer
def test_plain_opencv_results_score_as_the_equivalent_built_in_pipeline(
    rendered_pair, tmp_path, tmp_path_factory, worker_id
) -> None:
    """OpenCV's defaults are ``naive``'s detector (full frame, windows 3-23, no refinement):
    its results file, scored with ``naive``'s later stages, gets ``naive``'s scores."""
    import subprocess
    import sys

    from test_plugins import plugin_compare

    results = tmp_path / "plain.csv"
    argv = [sys.executable, str(PLAIN_OPENCV), str(rendered_pair), str(results)]
    subprocess.run(argv, check=True)
    # naive's scores on the pair (score_dataset's, as `score --pipeline naive` writes them),
    # from the compare of test_plugins, which scores naive on a copy of the pair: scored once
    folder, _, _ = plugin_compare(tmp_path_factory, worker_id, rendered_pair)
    built_in, theirs = folder / "data" / "scores" / "naive", tmp_path / "theirs"
    assert _score(rendered_pair, results, theirs, "--pipeline", "naive") == 0
    a, b = _samples(built_in), _samples(theirs)
    assert (a["recall"] > 0.9).all()
    for column in ("markers_visible", "markers_found", "recall", "false_detections", "outcome"):
        assert (a[column] == b[column]).all(), column
    for column in ("corner_err_px", "rot_err_deg", "trans_err_mm", "deflection_err_mm"):
        assert np.allclose(a[column], b[column], atol=1e-3, equal_nan=True), column
    assert (b["frames_per_s"] > 0).all()  # from the file's own times


def _branches(fake: Path, path: Path, out: Path, *extra: str) -> int:
    argv = ["score", str(fake), "--branches", str(path), "--name", "mine", "--out", str(out)]
    return main([*argv, *extra])


def test_branch_estimates_alone_are_scored(fake, tmp_path, capsys) -> None:
    path = tmp_path / "branches.csv"
    path.write_text(f"sample_id,whisker_left,whisker_right\n{LONG},,\n{SHORT},5,6\n")
    assert _branches(fake, path, tmp_path / "out") == 0
    assert "accuracy only" in capsys.readouterr().out
    table = _samples(tmp_path / "out")
    assert table.loc[LONG, "outcome"] == "correct" and table.loc[SHORT, "outcome"] == "correct"
    assert json.loads(table.loc[SHORT, "estimated_gaps"]) == [[5, 6]]
    path.write_text(f"sample_id,whisker_left,whisker_right\n{LONG},0,1\n{SHORT},,\n")
    assert _branches(fake, path, tmp_path / "again") == 0
    outcomes = _samples(tmp_path / "again")["outcome"]
    assert outcomes[LONG] == "false_positive" and outcomes[SHORT] == "false_negative"


@pytest.mark.parametrize(
    ("rows", "says"),
    [
        ([f"{LONG},,"], f"no row of sample {SHORT}"),
        ([f"{LONG},,", f"{SHORT},6,8"], "row 2: column 'whisker_right'"),
        ([f"{LONG},,", f"{SHORT},12,13"], "row 2: column 'whisker_left'"),
        ([f"{LONG},,", f"{SHORT},6,"], "row 2: column 'whisker_right'"),
        ([f"{LONG},,", f"{SHORT},6.5,7.5"], "row 2: column 'whisker_left'"),
        ([f"{LONG},,", f"{SHORT},6,7", f"{SHORT},6,7"], "row 3: sample"),
        ([f"{LONG},,", f"{LONG},1,2", f"{SHORT},,"], "row 2: sample"),
        ([f"{LONG},,", "other-sample,1,2", f"{SHORT},,"], "row 2: column 'sample_id'"),
        # text pandas would read as NaN, i.e. as "no branch found": not an integer
        ([f"{LONG},,", f"{SHORT},nan,nan"], "row 2: column 'whisker_left' is 'nan'; expected an"),
        ([f"{LONG},,", f"{SHORT},NA,NA"], "row 2: column 'whisker_left' is 'NA'"),
        ([f"{LONG},,", f"{SHORT}, , "], "row 2: column 'whisker_left' is ' '"),
    ],
)
def test_bad_branch_files_are_refused(fake, tmp_path, capsys, rows, says) -> None:
    path = tmp_path / "branches.csv"
    path.write_text("\n".join(["sample_id,whisker_left,whisker_right", *rows]) + "\n")
    assert _branches(fake, path, tmp_path / "out") == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(path) in err and says in err, err
    assert not (tmp_path / "out").exists()


def test_a_parquet_nan_is_refused_and_a_null_is_an_empty_cell(fake, tmp_path, capsys) -> None:
    """pandas reads a float NaN and a null alike; in a branches file only null means "no
    branch found" (a NaN is refused as ``nan`` text is in CSV)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    path = tmp_path / "branches.parquet"

    def write(left: list, right: list) -> None:
        columns = {
            "sample_id": pa.array([LONG, SHORT]),
            "whisker_left": pa.array(left, pa.float64()),
            "whisker_right": pa.array(right, pa.float64()),
        }
        pq.write_table(pa.table(columns), path)

    write([None, float("nan")], [None, float("nan")])
    assert _branches(fake, path, tmp_path / "out") == 2
    err = capsys.readouterr().err.strip()
    assert "row 2: column 'whisker_left'" in err and "an empty cell" in err, err
    assert not (tmp_path / "out").exists()
    write([None, None], [None, None])
    assert _branches(fake, path, tmp_path / "out") == 0
    outcomes = _samples(tmp_path / "out")["outcome"]
    assert outcomes[LONG] == "correct" and outcomes[SHORT] == "false_negative"


def test_branch_files_columns_hash_and_options(fake, tmp_path, capsys) -> None:
    path, out = tmp_path / "branches.csv", tmp_path / "out"
    path.write_text(f"sample_id,whisker_left,whisker_right,score\n{LONG},,,1\n{SHORT},,,1\n")
    assert _branches(fake, path, out) == 2
    assert "'score' is not in the format" in capsys.readouterr().err
    head = "sample_id,whisker_left,whisker_right,dataset_sha256"
    path.write_text(f"{head}\n{LONG},,,{'0' * 64}\n{SHORT},,,{'0' * 64}\n")
    assert _branches(fake, path, out) == 2
    assert "results of another dataset" in capsys.readouterr().err
    digest = sha256(fake / "manifest.json")
    path.write_text(f"{head}\n{LONG},,,{digest}\n{SHORT},,,{digest}\n")
    assert _branches(fake, path, out, "--fps", "30") == 2
    assert "--fps: goes with --detections" in capsys.readouterr().err
    assert _branches(fake, path, out, "--detections", str(path)) == 2
    assert "not both" in capsys.readouterr().err
    assert not out.exists()
    assert _branches(fake, path, out) == 0
