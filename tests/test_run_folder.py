"""Run folders (issue 24, parts 1 and 2): one run at a time, units checked before reuse, and a
command writes only what is its own.

The probe's kinds of cases: two commands on one ``--out`` (the lock, held by another process),
a lost or truncated manifest rerun with other settings, damaged cell files (swapped, emptied,
tripled, truncated), a partial dataset rerun, and an ``--out`` that is an input, a special file,
a symbolic link out of the folder, or another run's file; stale temporary files cleaned at the
top level only.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import pytest
from conftest import copy_pair
from fake_dataset import make_dataset

from bench.cli.main import main
from bench.common.manifest import sha256
from bench.common.run_folder import LOCK, open_folder, read_holder
from bench.common.units import DAMAGED, DONE, MISSING, write_unit

pytestmark = pytest.mark.usefixtures("figures_not_drawn")  # answers, not figures

ROOT = Path(__file__).resolve().parents[1]
OTHER_RUN = "0123456789ab"  # another run's id, in its temporary files' names
HOLD = """
import sys, time
from pathlib import Path
from bench.common.run_folder import open_folder, set_command_line
set_command_line(["holder", "--out", sys.argv[1]])
lock = open_folder(Path(sys.argv[1]), sys.argv[2])
lock.record(sys.argv[2])
print("held", flush=True)
time.sleep(120)
"""


def _cli(argv, capsys) -> tuple[int, str]:
    code = main([str(a) for a in argv])
    return code, capsys.readouterr().err.strip()


def _snapshot(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in folder.rglob("*") if p.is_file()}


def _dead_pid() -> int:
    child = subprocess.Popen([sys.executable, "-c", "pass"])
    child.wait()
    return child.pid


@pytest.fixture
def holder(tmp_path):
    """Start a process that holds a folder's lock: ``start(folder, kind)`` -> the process."""
    started = []

    def start(folder: Path, kind: str) -> subprocess.Popen:
        child = subprocess.Popen(
            [sys.executable, "-c", HOLD, str(folder), kind],
            cwd=ROOT,
            env={**os.environ, "PYTHONPATH": str(ROOT)},
            stdout=subprocess.PIPE,
            text=True,
        )
        started.append(child)
        assert child.stdout.readline().strip() == "held"
        return child

    yield start
    for child in started:
        child.kill()
        child.wait()


# -- the lock --------------------------------------------------------------------------------


def _fake(tmp_path) -> Path:
    return make_dataset(tmp_path / "data")


COMMANDS = {  # kind of the folder, the command line (OUT: the folder)
    "detectability": ("detectability", ["detectability", "--quick", "--images", "2"]),
    "dataset": ("dataset", ["dataset", "--quick"]),
    "ladder": ("ladder", ["ladder", "--quick"]),
    "score": ("score", ["score", "DATA"]),
}


@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_a_second_command_on_a_locked_folder_is_refused_naming_the_holder(
    command, tmp_path, holder, capsys
):
    kind, argv = COMMANDS[command]
    out = tmp_path / "out"
    child = holder(out, kind)
    before = _snapshot(out)
    data = _fake(tmp_path) if "DATA" in argv else None
    argv = [data if a == "DATA" else a for a in argv] + ["--out", out]
    code, err = _cli(argv, capsys)
    assert code == 2 and len(err.splitlines()) == 1, err
    assert f"{out}: in use by pid {child.pid} on host {socket.gethostname()}" in err
    assert f"`whiskerbench holder --out {out}`" in err and "started 20" in err
    assert _snapshot(out) == before  # nothing written, the holder's record kept
    assert read_holder(out)["pid"] == child.pid


def test_a_dead_runs_lock_is_taken_over(tmp_path, holder) -> None:
    out = tmp_path / "out"
    child = holder(out, "detectability")
    child.send_signal(signal.SIGKILL)
    child.wait()
    assert read_holder(out)["pid"] == child.pid  # its record stays, its flock does not
    with open_folder(out, "detectability") as lock:
        assert lock.previous["pid"] == child.pid
        assert read_holder(out)["pid"] == os.getpid()


def test_the_lock_is_held_until_released_in_this_process_too(tmp_path) -> None:
    out = tmp_path / "out"
    busy = pytest.raises(ValueError, match=f"in use by pid {os.getpid()}")
    with open_folder(out, "score"), busy:
        open_folder(out, "score")
    open_folder(out, "score").release()


# -- settings kept with every unit ---------------------------------------------------------


def _cells(folder: Path, settings: str, names=("a", "b")) -> None:
    """Finished cells with their records, as a study of ``settings`` writes them."""
    (folder / "cells").mkdir(parents=True, exist_ok=True)
    for name in names:
        path = folder / "cells" / f"{name}.parquet"
        pd.DataFrame({"cell": [name, name], "image_index": [0, 1]}).to_parquet(path)
        record = {"unit": name, "settings_sha256": settings, "files": {path.name: sha256(path)}}
        write_unit(folder / "cells" / f"{name}.json", record)


@pytest.mark.parametrize("manifest", ["deleted", "truncated", "emptied"])
def test_a_lost_manifest_does_not_let_other_settings_reuse_the_cells(manifest, tmp_path) -> None:
    from bench.common.resumable import finish_run, open_run

    out = tmp_path / "study"
    with open_run(out, "detectability", {"seed": 1}, units="cells/*") as run:
        _cells(out, run.settings_sha256)
        finish_run(run)
    path = out / "manifest.json"
    if manifest == "deleted":
        path.unlink()
    else:
        text = path.read_bytes()
        path.write_bytes(text[: len(text) // 2] if manifest == "truncated" else b"")
    before = _snapshot(out)
    with pytest.raises(ValueError, match=r"another configuration \(cells/a.json\)"):
        open_run(out, "detectability", {"seed": 2}, units="cells/*")
    assert _snapshot(out) == before
    # the cells' records lost too: the lock file still holds the last run's settings
    for record in (out / "cells").glob("*.json"):
        record.unlink()
    with pytest.raises(ValueError, match="another configuration"):
        open_run(out, "detectability", {"seed": 2}, units="cells/*")
    # and its kind: another command is refused though no manifest says whose the folder is
    with pytest.raises(ValueError, match=f"`detectability` \\(its {LOCK}; its manifest.json"):
        open_run(out, "dataset", {"seed": 2}, units="*/sample.json")
    with open_run(out, "detectability", {"seed": 1}, units="cells/*"):
        pass  # the same settings resume it


@pytest.mark.parametrize("damage", ["swapped", "emptied", "tripled", "truncated", "record"])
def test_a_damaged_unit_is_found_and_never_reused(damage, tmp_path) -> None:
    from bench.study.cells import cell_state

    _cells(tmp_path, "s" * 64)
    a, b = tmp_path / "cells" / "a.parquet", tmp_path / "cells" / "b.parquet"
    data = a.read_bytes()
    if damage == "swapped":
        a.write_bytes(b.read_bytes())
        b.write_bytes(data)
    elif damage == "emptied":
        a.write_bytes(b"")
    elif damage == "tripled":
        a.write_bytes(data * 3)
    elif damage == "truncated":
        a.write_bytes(data[: len(data) // 2])
    else:  # the record itself cut short
        record = tmp_path / "cells" / "a.json"
        record.write_bytes(record.read_bytes()[:40])
    assert cell_state(tmp_path, "a", "s" * 64) == DAMAGED
    assert cell_state(tmp_path, "b", "s" * 64) == (DAMAGED if damage == "swapped" else DONE)
    assert cell_state(tmp_path, "c", "s" * 64) == MISSING


def test_a_record_swapped_in_from_another_unit_is_damaged(tmp_path) -> None:
    from bench.study.cells import cell_state

    _cells(tmp_path, "s" * 64)
    a, b = tmp_path / "cells" / "a", tmp_path / "cells" / "b"
    for suffix in (".parquet", ".json"):  # both files of a swapped for b's
        a.with_suffix(suffix).write_bytes(b.with_suffix(suffix).read_bytes())
    assert cell_state(tmp_path, "a", "s" * 64) == DAMAGED  # the record names b
    assert cell_state(tmp_path, "b", "s" * 64) == DONE
    with pytest.raises(ValueError, match="made with other settings"):
        cell_state(tmp_path, "b", "t" * 64)


# -- write only what is yours ---------------------------------------------------------------


def test_an_out_that_is_an_input_is_refused(tmp_path, capsys) -> None:
    calib = tmp_path / "camchain.yaml"
    calib.write_text("cam0: {}\n")
    before = calib.read_bytes()
    code, err = _cli(["camera", "import", calib, "--format", "kalibr", "--out", calib], capsys)
    assert code == 2 and len(err.splitlines()) == 1
    assert f"--out: {calib}: is one of the command's inputs" in err
    assert calib.read_bytes() == before
    data = _fake(tmp_path)
    code, err = _cli(["score", data, "--out", data], capsys)
    assert code == 2 and "holds the output of `dataset`" in err


@pytest.mark.parametrize("special", ["/dev/null", "fifo"])
@pytest.mark.parametrize("command", ["camera import", "detectability", "dataset"])
def test_a_special_file_as_out_is_refused(command, special, tmp_path, capsys) -> None:
    if special == "fifo":
        special = tmp_path / "pipe"
        os.mkfifo(special)
    if command == "camera import":
        argv = ["camera", "import", tmp_path / "c.yaml", "--format", "kalibr"]
    else:
        argv = [command, "--quick"]
    code, err = _cli([*argv, "--out", special], capsys)
    assert code == 2 and len(err.splitlines()) == 1, err
    kind = "a character device" if special == "/dev/null" else "a named pipe"
    assert f"--out: {special}: is {kind}, not a" in err
    assert Path(special).exists() and not Path(special).is_file()


def test_symbolic_links_out_of_the_folder_are_refused(tmp_path, capsys) -> None:
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    (elsewhere / "keep.csv").write_text("the user's")
    out = tmp_path / "out"
    out.mkdir()
    (out / "cells").symlink_to(elsewhere)  # the study would write its cells there
    code, err = _cli(["detectability", "--quick", "--images", "2", "--out", out], capsys)
    assert code == 2 and f"{out / 'cells'}: a symbolic link out of the run folder" in err
    (out / "cells").unlink()
    (out / "summary.csv").symlink_to(elsewhere / "keep.csv")
    with pytest.raises(ValueError, match="summary.csv: a symbolic link out of the run folder"):
        open_folder(out, "detectability")
    assert sorted(p.name for p in elsewhere.iterdir()) == ["keep.csv"]

    link = tmp_path / "profile.json"  # a file --out that is a link to another folder's file
    link.symlink_to(elsewhere / "keep.csv")
    argv = ["camera", "import", tmp_path / "c.yaml", "--format", "kalibr", "--out", link]
    code, err = _cli(argv, capsys)
    assert code == 2 and "a symbolic link out of its folder" in err
    dangling = tmp_path / "gone"
    dangling.symlink_to(tmp_path / "nowhere")
    code, err = _cli(["detectability", "--quick", "--out", dangling], capsys)
    assert code == 2 and "which does not exist" in err
    assert (elsewhere / "keep.csv").read_text() == "the user's"


def test_a_file_or_folder_of_another_run_is_refused(tmp_path, capsys) -> None:
    data = _fake(tmp_path)
    sample = next(p for p in sorted(data.iterdir()) if p.is_dir())
    before = _snapshot(data)
    argv = ["camera", "import", tmp_path / "c.yaml", "--format", "kalibr"]
    for target in (sample / "camera.json", sample / "sample.json", data / "manifest.json"):
        code, err = _cli([*argv, "--out", target], capsys)
        assert code == 2 and f"{target}: is part of the output of `dataset` in {data}" in err
    code, err = _cli(["score", data, "--out", sample], capsys)
    assert code == 2 and f"{sample}: is part of the output of `dataset`" in err
    study = tmp_path / "study"
    study.mkdir()
    (study / "manifest.json").write_text(json.dumps({"kind": "detectability", "outputs": {}}))
    code, err = _cli(["dataset", "--quick", "--out", study / "cells"], capsys)
    assert code == 2 and "is part of the output of `detectability`" in err
    assert _snapshot(data) == before and sorted(p.name for p in study.iterdir()) == [
        "manifest.json"
    ]


def test_new_paths_in_a_dataset_folder_stay_allowed(tmp_path) -> None:
    """``score``'s default output, and ``detect``'s beside a sample's video, replace nothing."""
    from bench.cli.args import check_out_folder

    data = _fake(tmp_path)
    sample = next(p for p in sorted(data.iterdir()) if p.is_dir())
    for allowed in (data / "scores" / "paper", sample / "video.paper"):
        assert check_out_folder(allowed) == allowed


def test_stale_temporary_files_go_at_the_top_level_only(tmp_path) -> None:
    out = tmp_path / "out"
    (out / "notes").mkdir(parents=True)
    dead = _dead_pid()
    stale = out / f".summary.csv.{OTHER_RUN}-{dead}.tmp-abc123.csv"
    users = [
        out / "notes" / f".draft.txt.{OTHER_RUN}-{dead}.tmp-abc123.txt",  # below: not ours
        out / "notes" / f".draft.txt.{dead}.tmp-abc123.txt",  # the old pattern, anywhere
        out / f".draft.txt.{dead}.tmp-abc123.txt",
        out / "my.tmp-file",
    ]
    for path in [stale, *users]:
        path.write_text("x")
    with open_folder(out, "detectability", written=("", "cells")):
        pass
    assert not stale.exists()
    assert all(path.exists() for path in users)


# -- end to end ----------------------------------------------------------------------------

TINY = dict(sizes_mm=(13.2,), alphas_deg=(0.0, 85.0), phis_deg=(0.0,), images=6)


@pytest.fixture(scope="module")
def tiny_study(tmp_path_factory, variant):
    """A finished two-cell study (a passing and a failing cell)."""
    from bench.study.config import StudyConfig
    from bench.study.run import run_study

    config = StudyConfig(**TINY)
    out = tmp_path_factory.mktemp("study") / "run"
    manifest = run_study(config, out, progress=False)
    return config, out, manifest


@pytest.mark.slow
@pytest.mark.parametrize("damage", ["swapped", "emptied", "tripled", "truncated"])
def test_a_damaged_cell_file_is_computed_again(damage, tiny_study, tmp_path) -> None:
    from bench.study.run import run_study

    config, clean, first = tiny_study
    out = tmp_path / "run"
    shutil.copytree(clean, out)
    a, b = sorted((out / "cells").glob("*.parquet"))
    data = a.read_bytes()
    if damage == "swapped":
        a.write_bytes(b.read_bytes())
        b.write_bytes(data)
    else:
        a.write_bytes({"emptied": b"", "tripled": data * 3, "truncated": data[:100]}[damage])
    manifest = run_study(config, out, progress=False)
    redone = [a.stem, b.stem] if damage == "swapped" else [a.stem]
    assert manifest["units_redone"] == sorted(redone)
    assert manifest["cells_computed"] == len(redone)
    for name in ("summary.csv", "max_phi.csv", "cells/" + a.name, "cells/" + b.name):
        assert (out / name).read_bytes() == (clean / name).read_bytes(), name


@pytest.mark.slow
@pytest.mark.parametrize(
    "manifest, change",
    [("deleted", {"seed": 1}), ("truncated", {"camera": "ideal"})],
)
def test_a_lost_manifest_and_other_settings_reuse_no_cell(
    manifest, change, tiny_study, tmp_path, capsys
) -> None:
    config, clean, _ = tiny_study
    out = tmp_path / "run"
    shutil.copytree(clean, out)
    path = out / "manifest.json"
    if manifest == "deleted":
        path.unlink()
    else:
        path.write_bytes(path.read_bytes()[:200])
    before = _snapshot(out)
    argv = ["detectability", "--sizes", "13.2", "--alphas", "0,85", "--phis", "0"]
    argv += ["--images", "6", "--out", out]
    argv += ["--seed", "1"] if "seed" in change else ["--camera", "ideal"]
    code, err = _cli(argv, capsys)
    assert code == 2 and len(err.splitlines()) == 1, err
    assert "holds a detectability run with another configuration (cells/" in err
    assert _snapshot(out) == before


@pytest.mark.slow
def test_two_real_commands_on_one_out(tmp_path, variant) -> None:
    out = tmp_path / "run"
    argv = ["detectability", "--sizes", "13.2", "--alphas", "0,30,60,85", "--phis", "0,30"]
    first = subprocess.Popen(
        [sys.executable, "-m", "bench.cli", *argv, "--images", "30", "--out", str(out)],
        cwd=ROOT,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        deadline = time.monotonic() + 120
        while (read_holder(out) or {}).get("pid") != first.pid:
            assert first.poll() is None and time.monotonic() < deadline, first.stderr.read()
            time.sleep(0.05)
        second = subprocess.run(
            [sys.executable, "-m", "bench.cli", *argv, "--images", "20", "--out", str(out)],
            cwd=ROOT,
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert second.returncode == 2, second.stderr
        err = second.stderr.strip()
        assert len(err.splitlines()) == 1 and f"in use by pid {first.pid}" in err
        assert "`whiskerbench detectability --sizes 13.2" in err
    finally:
        first.kill()
        first.wait()


@pytest.mark.slow
def test_a_partial_dataset_rerun_keeps_the_other_samples(rendered_pair, pair_config, tmp_path):
    import dataclasses

    from bench.dataset.config import DatasetConfigError
    from bench.dataset.generate import run_dataset
    from bench.dataset.verify import verify_dataset

    data = tmp_path / "data"
    copy_pair(rendered_pair, data)
    both = json.loads((data / "manifest.json").read_text())["samples"]
    twin_only = dataclasses.replace(pair_config, branches=((),))
    manifest = run_dataset(twin_only, data, progress=False)
    assert manifest["skipped"] == 1 and sorted(manifest["samples"]) == sorted(both)
    assert sorted(verify_dataset(data).records) == sorted(both)

    branch = next(s for s in both if "none" not in s)
    video = data / branch / "video.mp4"
    video.write_bytes(video.read_bytes()[:1000])  # damaged, and outside the rerun's grid
    before = _snapshot(data)
    with pytest.raises(DatasetConfigError, match=f"{branch}: a damaged sample outside"):
        run_dataset(twin_only, data, progress=False)
    assert _snapshot(data) == before
