"""The command line: bad input gives one line naming the option, exit code 2, nothing written."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

from bench.cli.main import main

ROOT = Path(__file__).resolve().parents[1]


def call(argv):
    try:
        return main(argv)
    except SystemExit as exc:  # argparse's own errors (unparseable values)
        return exc.code


@pytest.mark.parametrize(
    "arg, option",
    [
        ("--sizes=0", "--sizes"),
        ("--sizes=-3,13.2", "--sizes"),
        ("--sizes=big", "--sizes"),
        ("--alphas=96", "--alphas"),
        ("--alphas=-1", "--alphas"),
        ("--phis=90", "--phis"),
        ("--phis=-5", "--phis"),
        ("--dictionary=9x9_50", "--dictionary"),
        ("--lighting=moon", "--lighting"),
        ("--lighting=sun,fog", "--lighting"),
        ("--images=0", "--images"),
        ("--images=many", "--images"),
        ("--distance=0", "--distance"),
        ("--workers=0", "--workers"),
        ("--variant=cpu", "--variant"),
    ],
)
def test_bad_options(tmp_path, capsys, arg, option):
    out = tmp_path / "run"
    assert call(["detectability", arg, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and option in err[0], err
    assert not out.exists()


def test_error_names_the_allowed_range(tmp_path, capsys):
    call(["detectability", "--phis=95", "--out", str(tmp_path / "x")])
    assert "0..89" in capsys.readouterr().err


def test_unwritable_out(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    assert call(["detectability", "--quick", "--out", str(blocker / "run")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--out" in err[0]
    assert blocker.read_text() == "not a folder"


def test_detect_reads_a_profile_by_name_or_file(tmp_path, capsys):
    """``--camera`` of detect takes a shipped profile name or a profile JSON: a bad one is
    refused naming the option and the profile field; a good one gets as far as the video."""
    import json

    from scenes.profile import CameraProfile

    video = tmp_path / "missing.mp4"
    bad = CameraProfile().to_json()
    bad["stream"]["quality"] = 0
    (tmp_path / "bad.json").write_text(json.dumps(bad))
    for camera, says in (("nosuch", "--camera"), (str(tmp_path / "bad.json"), "stream.quality")):
        assert call(["detect", str(video), "--camera", camera]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "--camera" in err[0] and says in err[0], err
    (tmp_path / "good.json").write_text(json.dumps(CameraProfile().to_json()))
    assert call(["detect", str(video), "--camera", str(tmp_path / "good.json")]) == 2
    err = capsys.readouterr().err
    assert "no such file" in err and "--camera" not in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.json", "good.json"]


@pytest.mark.slow
@pytest.mark.parametrize(
    ("argv", "unbuffered"),
    [
        (["camera", "show", "prototype"], ""),  # the print overflows the buffer, or the flush
        (["camera", "show", "prototype"], "1"),  # every print writes
        (["--help"], ""),  # argparse exits (SystemExit) with the help still buffered
    ],
)
def test_a_reader_closing_stdout_early_ends_the_command_quietly(argv, unbuffered):
    """``whiskerbench camera show prototype | head -1``: no traceback, no internal error."""
    env = {**os.environ, "PYTHONUNBUFFERED": unbuffered}  # empty: Python's default buffering
    proc = subprocess.Popen(
        [sys.executable, "-m", "bench.cli", *argv],
        cwd=ROOT,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    proc.stdout.close()  # the reader is gone before the command writes a byte
    err = proc.stderr.read().decode()
    assert proc.wait(timeout=120) in (0, 141) and err == ""


def test_a_broken_pipe_elsewhere_is_still_a_bug(monkeypatch, capsys):
    """Only stdout's reader going away is quiet; a worker's broken pipe is reported."""

    def crash(*args, **kwargs):
        raise BrokenPipeError(32, "Broken pipe")

    monkeypatch.setattr("bench.study.run.run_study", crash)
    assert main(["detectability", "--quick"]) == 1
    assert "internal error: BrokenPipeError" in capsys.readouterr().err


def test_help_and_a_refused_option_load_no_table_or_mesh_library():
    """The command line answers --help and refuses bad options before pandas, trimesh and
    matplotlib are imported (about 0.3 s of a 0.6 s start on this machine)."""
    code = """
import sys
from bench.cli.main import main
def loaded():
    return [m for m in ("pandas", "trimesh", "matplotlib") if m in sys.modules]
assert not loaded(), loaded()
refused = (["dataset", "--quick", "--frames-step", "0"], ["detectability", "--images", "0"],
           ["score", "no-such-dataset", "--pipeline", "paper"])
for argv in refused:
    assert main(argv) == 2
    assert not loaded(), (argv, loaded())
"""
    done = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "--frames-step" in done.stderr and "--images" in done.stderr
    assert "no-such-dataset: not a dataset folder" in done.stderr


def test_a_pools_worker_loads_no_plotting_library():
    """A study's or score's pool worker imports the module of its task (``_run_task``,
    ``_score_sample``) and draws nothing: pyplot stays out of it (0.2-0.3 s of each worker's
    start); the parent loads it where it draws."""
    code = """
import sys
import bench.evaluate.score, bench.study.run
assert "matplotlib.pyplot" not in sys.modules, "pyplot loaded"
"""
    done = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-2000:]
