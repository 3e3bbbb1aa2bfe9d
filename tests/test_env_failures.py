"""Failures of the environment are told as such (issue 24, part 5): a full disk, a permission,
an immutable file, a name over 255 bytes, a dangling symbolic link or a link loop as ``--out``,
a path that is not UTF-8 text, a closed pipe. Each is one line naming the path and the cause,
never "internal error"; exit code 2 where the culprit is an argument (found before any work),
1 where the system fails during the work; nothing is written either way.

The cases run ``camera import`` (fast, writes one file) and ``detect-images`` (writes a
folder) through ``main``; the ones that could crash the interpreter or need a closed stdout run
the command line in a subprocess.
"""

from __future__ import annotations

import errno
import os
import pathlib
import re
import shutil
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from bench.cli.main import main

ROOT = Path(__file__).resolve().parents[1]
CALIBRATION = (
    "cam0:\n  camera_model: pinhole\n  intrinsics: [300, 300, 320, 240]\n"
    "  distortion_model: equidistant\n  distortion_coeffs: [0, 0, 0, 0]\n"
    "  resolution: [640, 480]\n"
)


@pytest.fixture
def work(tmp_path, monkeypatch) -> Path:
    """A folder with a calibration file and a folder of one image; the working directory."""
    (tmp_path / "cal.yaml").write_text(CALIBRATION)
    (tmp_path / "photos").mkdir()
    cv2.imwrite(str(tmp_path / "photos" / "a.png"), np.full((48, 64), 128, np.uint8))
    monkeypatch.chdir(tmp_path)
    return tmp_path


def snapshot(folder: Path) -> dict[str, tuple[int, int]]:
    """Every entry under ``folder``; files and links with their size and time (a folder's own
    time moves when a temporary file comes and goes)."""
    out = {}
    for p in [folder, *folder.rglob("*")]:
        st = p.lstat()
        out[str(p)] = (0, 0) if p.is_dir() and not p.is_symlink() else (st.st_size, st.st_mtime_ns)
    return out


def one_line(argv: list, code: int, pattern: str, capsys, folder: Path) -> str:
    """Run the command: it must exit ``code`` with one stderr line matching ``pattern``, no
    bug report, and leave ``folder`` as it was."""
    before = snapshot(folder)
    try:
        got = main([os.fsdecode(a) if isinstance(a, bytes) else str(a) for a in argv])
    except SystemExit as exc:
        got = exc.code
    err = capsys.readouterr().err.strip().split("\n")
    assert got == code, err
    assert len(err) == 1 and "internal error" not in err[0], err
    assert re.search(pattern, err[0]), (pattern, err[0])
    assert snapshot(folder) == before, "something was written"
    return err[0]


def _import(out) -> list:
    return ["camera", "import", "cal.yaml", "--format", "kalibr", "--out", out]


# --- found before any work: the argument is at fault (exit code 2)


def test_name_over_255_bytes(work, capsys):
    long = "a" * 300
    one_line(
        _import(f"{long}.json"), 2, r"--out: a{16}\.\.\.: a name of 305 bytes; .* 255", capsys, work
    )
    argv = ["detect-images", "photos", "--pipelines", "paper", "--out", f"runs/{long}/x"]
    one_line(argv, 2, r"--out: .*a name of 300 bytes", capsys, work)


@pytest.mark.parametrize("out", ["gone.json", "gone/profile.json"])
def test_dangling_symlink_as_out(out, work, capsys):
    (work / "gone").symlink_to(work / "nowhere" / "x")
    (work / "gone.json").symlink_to(work / "nowhere.json")
    link = out.split("/")[0]
    one_line(
        _import(out),
        2,
        rf"--out: {link}: a symbolic link to .*, which does not exist",
        capsys,
        work,
    )
    assert (work / link).is_symlink()  # left as it was, not replaced by a file


def test_dangling_symlink_as_out_folder(work, capsys):
    (work / "run").symlink_to(work / "nowhere")
    argv = ["detect-images", "photos", "--pipelines", "paper", "--out", "run"]
    one_line(
        argv, 2, r"--out: run: a symbolic link to .*nowhere, which does not exist", capsys, work
    )


def test_symlink_loop(work, capsys):
    (work / "loop1").symlink_to("loop2")
    (work / "loop2").symlink_to("loop1")
    pattern = r"--out: loop1/p\.json: Too many levels of symbolic links"
    one_line(_import("loop1/p.json"), 2, pattern, capsys, work)


def test_read_only_folder(work, capsys, monkeypatch):
    (work / "locked").mkdir()
    (work / "locked").chmod(0o555)
    if os.geteuid() == 0:  # root writes anywhere: the system's answer for other users
        real = os.access
        monkeypatch.setattr(os, "access", lambda p, m: False if "locked" in str(p) else real(p, m))
    try:
        one_line(_import("locked/p.json"), 2, r"--out: locked: not writable", capsys, work)
    finally:
        (work / "locked").chmod(0o755)


def test_immutable_file(work, capsys):
    target = work / "fixed.json"
    target.write_text("{}")
    if shutil.which("chattr") is None:
        pytest.skip("no chattr")
    flagged = subprocess.run(["chattr", "+i", str(target)], capture_output=True)
    if flagged.returncode != 0:
        pytest.skip("chattr +i is not permitted here (needs CAP_LINUX_IMMUTABLE)")
    try:
        pattern = r"--out: fixed\.json: the file is immutable \(chattr\)"
        one_line(_import("fixed.json"), 2, pattern, capsys, work)
    finally:
        subprocess.run(["chattr", "-i", str(target)], check=True)


def test_non_utf8_arguments(work, capsys):
    odd = os.fsdecode(b"\xff.json")  # how Python hands over a Latin-1 name: with a surrogate
    one_line(_import(odd), 2, r"--out: '\\udcff\.json': not valid UTF-8 text", capsys, work)
    (work / odd).write_bytes((work / "cal.yaml").read_bytes())
    argv = ["camera", "import", odd, "--format", "kalibr", "--out", "p.json"]
    one_line(argv, 2, r"argument: '\\udcff\.json': not valid UTF-8 text", capsys, work)


@pytest.mark.slow
def test_non_utf8_name_inside_a_folder(work):
    """OpenCV crashes (SIGSEGV) on such a path: run in a subprocess so a crash fails the test
    instead of ending the session."""
    shutil.copy(work / "photos" / "a.png", os.fsencode(work / "photos") + b"/\xff.png")
    before = snapshot(work)
    for argv in (
        ["detect-images", "photos", "--pipelines", "paper", "--out", "o"],
        ["lens", "measure", "photos", "--camera", "ideal", "--out", "p.json"],
    ):
        proc = _cli(argv, work)
        lines = proc.stderr.strip().split("\n")
        assert proc.returncode == 2 and len(lines) == 1, proc.stderr
        assert re.search(r"photos/\\udcff\.png: the file name is not valid UTF-8", lines[0])
    assert snapshot(work) == before


# --- the system fails during the work (exit code 1), nothing is left behind


@pytest.mark.parametrize(
    "code, cause",
    [
        (errno.ENOSPC, r"No space left on device \(ENOSPC\); free some space"),
        (errno.EDQUOT, r"\(EDQUOT\); the disk quota"),
        (errno.EACCES, r"Permission denied \(EACCES\)"),
        (errno.EPERM, r"\(EPERM\); not permitted: an immutable"),
        (errno.EROFS, r"Read-only file system \(EROFS\)"),
        (errno.EIO, r"Input/output error \(EIO\)"),
    ],
)
def test_write_fails(code, cause, work, capsys, monkeypatch):
    """A write that fails as a full disk does: the error names no file; the line does."""

    def fail(self, data):
        raise OSError(code, os.strerror(code))

    monkeypatch.setattr(pathlib.Path, "write_bytes", fail)
    line = one_line(_import("p.json"), 1, rf"error: p\.json: .*{cause}", capsys, work)
    assert line.endswith("nothing was written")


def test_failure_deep_in_a_command_names_its_path(work, capsys, monkeypatch):
    """An OSError from anywhere in the work (here: reading an image) is one line with its
    path, exit code 1, and says what was kept."""
    from bench.evaluate import images

    def loop(path, max_pixels):
        raise OSError(errno.ELOOP, os.strerror(errno.ELOOP), str(path))

    monkeypatch.setattr(images, "read_grey", loop)
    argv = ["detect-images", "photos", "--pipelines", "paper", "--out", "o"]
    before = snapshot(work)
    assert main(argv) == 1
    err = capsys.readouterr().err.strip().split("\n")
    assert len(err) == 1 and re.search(r"photos/a\.png: Too many levels .*\(ELOOP\)", err[0]), err
    assert "nothing was written" in err[0]
    written = set(snapshot(work)) - set(before)
    assert all("/o" in p for p in written)  # at most the run's own claim on its folder


def test_ffmpeg_full_disk_is_enospc():
    from bench.common.video import _ffmpeg_failure

    class Log:
        def seek(self, at):
            pass

        def read(self):
            return b"[out] Error writing trailer: No space left on device"

    exc = _ffmpeg_failure(Path("v.mp4"), 1, Log())
    assert isinstance(exc, OSError) and exc.errno == errno.ENOSPC and exc.filename == "v.mp4"


# --- pipes


def _cli(argv: list, cwd: Path, **kwargs) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run(
        [sys.executable, "-m", "bench.cli", *argv],
        cwd=cwd,
        env=env,
        capture_output="stdout" not in kwargs,
        text=True,
        timeout=300,
        **kwargs,
    )


@pytest.mark.slow
def test_started_with_stdout_closed(work):
    """``whiskerbench camera show ideal >&-``: nothing to print to, no traceback."""
    proc = subprocess.run(
        f"{sys.executable} -m bench.cli camera show ideal >&-",
        shell=True,
        cwd=work,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
        stderr=subprocess.PIPE,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0 and proc.stderr == "", proc.stderr


@pytest.mark.slow
def test_reader_gone_early(work):
    """``camera project ... | head -1``: the reader closes the pipe; a quiet exit 141."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "bench.cli", "camera", "project", "ideal", "--theta-deg",
         ",".join(str(t / 100) for t in range(1, 9000))],
        cwd=work, env={**os.environ, "PYTHONPATH": str(ROOT)},
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    proc.stdout.readline()
    proc.stdout.close()
    err = proc.stderr.read()
    assert proc.wait(timeout=300) in (0, 141) and err == "", err
