"""Integrity: score and compare refuse a tampered dataset naming the file; folders are claimed by
one command; sample ids stay inside their folders; a killed run's temporary files are cleaned."""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import pytest
from conftest import copy_pair

from bench.common.manifest import sha256
from bench.dataset.verify import DatasetIntegrityError, verify_dataset
from pipeline.presets import PRESETS

pytestmark = pytest.mark.usefixtures("figures_not_drawn")  # answers, not figures

BRANCH = "soft-intermediate-100-outdoor-lab"
TWIN = "soft-intermediate-none-outdoor-lab"
#: The id of another (killed) run, in its temporary files' names.
OTHER_RUN = "0123456789ab"


@pytest.fixture
def data(rendered_pair, tmp_path):
    """A private copy of the rendered pair (without other tests' score folders)."""
    out = tmp_path / "data"
    copy_pair(rendered_pair, out)
    return out


def _snapshot(folder) -> dict:
    """{relative path: SHA-256} of every file under ``folder``: to show nothing changed."""
    return {
        str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


def _reseal(dataset, sample_id) -> None:
    """Record a sample's edited files as the dataset's own (an attacker who also edits the
    hashes): what is left to catch them is the id check."""
    folder = dataset / sample_id
    record = json.loads((folder / "sample.json").read_text())
    manifest = json.loads((dataset / "manifest.json").read_text())
    for name in [*record["files"], "sample.json"]:
        manifest["files"][f"{sample_id}/{name}"] = sha256(folder / name)
    (dataset / "manifest.json").write_text(json.dumps(manifest))


def _score_cli(dataset, out, capsys) -> tuple[int, str]:
    from bench.cli.main import main

    code = main(["score", str(dataset), "--out", str(out)])
    return code, capsys.readouterr().err.strip()


@pytest.mark.slow
def test_the_rendered_pair_verifies(data) -> None:
    verified = verify_dataset(data)
    assert sorted(verified.records) == [BRANCH, TWIN]
    for path, digest in verified.inputs().items():
        assert hashlib.sha256(Path(path).read_bytes()).hexdigest() == digest


@pytest.mark.slow
def test_swapped_videos_are_refused_naming_the_file(data, tmp_path, capsys) -> None:
    a, b = data / BRANCH / "video.mp4", data / TWIN / "video.mp4"
    a.rename(tmp_path / "swap.mp4")
    b.rename(a)
    (tmp_path / "swap.mp4").rename(b)
    out = tmp_path / "scores"
    code, err = _score_cli(data, out, capsys)
    assert code == 2 and len(err.splitlines()) == 1
    assert f"{data / BRANCH / 'video.mp4'}: SHA-256 differs from the dataset manifest" in err
    assert not out.exists()


@pytest.mark.slow
def test_edited_labels_are_refused(data, tmp_path) -> None:
    from bench.evaluate.score import score_dataset

    labels = pd.read_parquet(data / TWIN / "labels.parquet")
    labels.loc[0, "deflection_mm"] += 1.0
    labels.to_parquet(data / TWIN / "labels.parquet", index=False)
    with pytest.raises(DatasetIntegrityError, match=f"{TWIN}/labels.parquet: SHA-256 differs"):
        score_dataset(data, PRESETS["paper"], tmp_path / "scores")
    assert not (tmp_path / "scores").exists()


@pytest.mark.slow
def test_an_edited_branch_position_is_refused(data) -> None:
    path = data / BRANCH / "sample.json"
    record = json.loads(path.read_text())
    record["branch_gaps"] = [[3, 4]]
    path.write_text(json.dumps(record, indent=2))
    with pytest.raises(DatasetIntegrityError, match=f"{BRANCH}/sample.json: SHA-256 differs"):
        verify_dataset(data)


@pytest.mark.slow
def test_a_file_that_differs_from_sample_json_is_refused(data) -> None:
    """Both manifests must agree: a sample.json listing another digest is refused too."""
    path = data / TWIN / "sample.json"
    record = json.loads(path.read_text())
    record["files"]["camera.json"] = "0" * 64
    path.write_text(json.dumps(record))
    _reseal(data, TWIN)
    with pytest.raises(DatasetIntegrityError, match="camera.json: SHA-256 differs from sample"):
        verify_dataset(data)


@pytest.mark.slow
def test_a_sample_id_that_leaves_its_folder_is_refused(data, tmp_path, capsys) -> None:
    path = data / BRANCH / "sample.json"
    record = json.loads(path.read_text())
    record["sample_id"] = "../evil"
    path.write_text(json.dumps(record))
    _reseal(data, BRANCH)  # hashes agree: only the id is wrong
    out = tmp_path / "scores"
    code, err = _score_cli(data, out, capsys)
    assert code == 2 and len(err.splitlines()) == 1
    assert "'../evil' is not a plain folder name" in err
    assert not out.exists() and not (tmp_path / "evil").exists()
    # the same id in the manifest's sample list
    manifest = json.loads((data / "manifest.json").read_text())
    manifest["samples"][0] = "../evil"
    (data / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(DatasetIntegrityError, match="'../evil' is not a plain folder name"):
        verify_dataset(data)


@pytest.mark.slow
def test_missing_and_unlisted_samples_are_refused(data) -> None:
    shutil.copytree(data / TWIN, data / "extra")
    with pytest.raises(DatasetIntegrityError, match="extra/sample.json: a sample not in"):
        verify_dataset(data)
    shutil.rmtree(data / "extra")
    (data / TWIN / "preview.mp4").unlink()
    with pytest.raises(DatasetIntegrityError, match="preview.mp4: listed in the dataset manifest"):
        verify_dataset(data)


@pytest.mark.slow
def test_compare_refuses_a_tampered_dataset_before_any_work(data, tmp_path) -> None:
    from bench.evaluate.compare import run_compare

    (data / TWIN / "camera.json").write_text((data / TWIN / "camera.json").read_text() + " ")
    out = tmp_path / "report"
    with pytest.raises(DatasetIntegrityError, match=f"{TWIN}/camera.json: SHA-256 differs"):
        run_compare(data, [PRESETS["paper"]], out, speed_frames=2)
    assert not out.exists() and not (data / "scores").exists()


@pytest.mark.slow
def test_one_commands_folder_is_refused_by_another(data, tmp_path, capsys) -> None:
    from bench.dataset.config import DatasetConfig, DatasetConfigError
    from bench.dataset.generate import run_dataset
    from bench.study.config import StudyConfig, StudyConfigError
    from bench.study.run import run_study

    before = _snapshot(data)
    with pytest.raises(StudyConfigError, match="holds the output of `dataset`") as info:
        run_study(StudyConfig(sizes_mm=(13.2,), images=2), data, progress=False)
    assert info.value.field == "out"
    code, err = _score_cli(data, data, capsys)  # score --out <the dataset>
    assert code == 2 and "holds the output of `dataset`" in err
    assert _snapshot(data) == before

    study = tmp_path / "study"
    study.mkdir()
    (study / "manifest.json").write_text(json.dumps({"kind": "detectability", "config": {}}))
    (study / "cells").mkdir()
    (study / "cells" / "c.parquet").write_bytes(b"cell")
    before = _snapshot(study)
    with pytest.raises(DatasetConfigError, match="holds the output of `detectability`"):
        run_dataset(DatasetConfig(foliage=("soft",)), study, progress=False)
    assert _snapshot(study) == before


def _dead_pid() -> int:
    child = subprocess.Popen([sys.executable, "-c", "pass"])
    child.wait()
    return child.pid


@pytest.mark.slow
def test_a_killed_runs_temporary_files_are_cleaned_by_the_next_run(
    data, variant, pair_config
) -> None:
    from bench.dataset.generate import run_dataset

    dead = data / BRANCH / f".video.mp4.{OTHER_RUN}-{_dead_pid()}.tmp-k1lled.mp4"
    dead.write_bytes(b"half a video")
    live_child = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        live = data / f".manifest.json.{OTHER_RUN}-{live_child.pid}.tmp-busy.json"
        live.write_bytes(b"another run is writing this")
        # the rendered pair's own config: every sample is skipped
        manifest = run_dataset(pair_config, data, variant=variant, progress=False)
        assert manifest["skipped"] == 2
        assert not dead.exists() and live.exists()
    finally:
        live_child.kill()
        live_child.wait()


def test_a_folder_holding_only_a_failed_runs_mark_takes_a_corrected_command(tmp_path) -> None:
    from bench.common.resumable import finish_run, open_run
    from bench.common.units import write_unit

    folder = tmp_path / "run"
    with open_run(folder, "detectability", {"images": 7}, units="cells/*"):
        assert json.loads((folder / "manifest.json").read_text())["finished"] is None
    with open_run(folder, "detectability", {"images": 8}, units="cells/*") as run:  # no cell yet
        (folder / "cells").mkdir()
        (folder / "cells" / "a.parquet").write_bytes(b"cell")
        files = {"a.parquet": sha256(folder / "cells" / "a.parquet")}
        write_unit(
            folder / "cells" / "a.json", {"settings_sha256": run.settings_sha256, "files": files}
        )
        finish_run(run)
    with pytest.raises(ValueError, match="another configuration"):
        open_run(folder, "detectability", {"images": 9}, units="cells/*")
    with pytest.raises(ValueError, match="holds the output of `detectability`"):
        open_run(folder, "dataset", {"images": 8})
    assert json.loads((folder / "manifest.json").read_text())["config"] == {"images": 8}


def test_atomic_temporary_names_carry_the_run_id_and_the_writers_pid(tmp_path) -> None:
    from bench.common.atomic import atomic_path, clean_stale, run_id

    with atomic_path(tmp_path / "a.parquet") as tmp:
        assert tmp.name.startswith(f".a.parquet.{run_id()}-{os.getpid()}.tmp-")
        assert tmp.suffix == ".parquet"
        tmp.write_bytes(b"x")
        assert clean_stale(tmp_path) == []  # this run's: its file stays
    assert (tmp_path / "a.parquet").read_bytes() == b"x"


def test_a_zombie_writers_temporary_file_is_stale(tmp_path) -> None:
    """A killed worker whose parent died too may stay a zombie (nobody reaps it): it writes
    nothing more, so its temporary files go, while a running process's stay."""
    from bench.common.atomic import clean_stale

    zombie = subprocess.Popen([sys.executable, "-c", "pass"])
    running = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        deadline = time.monotonic() + 10
        stat = Path(f"/proc/{zombie.pid}/stat")
        while stat.read_text().rsplit(")", 1)[1].split()[0] != "Z":  # exited, not reaped
            assert time.monotonic() < deadline
            time.sleep(0.01)
        stale = tmp_path / f".a.parquet.{OTHER_RUN}-{zombie.pid}.tmp-z.parquet"
        busy = tmp_path / f".b.parquet.{OTHER_RUN}-{running.pid}.tmp-r.parquet"
        stale.write_bytes(b"half")
        busy.write_bytes(b"half")
        assert clean_stale(tmp_path) == [stale] and busy.exists()
    finally:
        running.kill()
        running.wait()
        zombie.wait()
