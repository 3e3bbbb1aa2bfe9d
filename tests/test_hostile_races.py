"""Races and signals against real processes (issue 24, part 9): two commands with different
settings started together on one ``--out``, and a study interrupted by SIGINT (Ctrl-C, sent to
its whole process group as a terminal does) or SIGTERM (``kill``, to the parent alone).

Two commands started together: one finishes, the other is refused in one line naming the
holder (or, when the first was already done, naming the other configuration); never an internal
error, never a folder holding parts of both. An interrupted study leaves no process behind and
its rerun writes the very bytes of an uninterrupted one.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from fake_dataset import SAMPLES, make_dataset
from quick_study import quick_study_argv, run_quick_study
from test_faults import _alive, _descendants, _finished_cells, _tables

from bench.common.manifest import sha256

ROOT = Path(__file__).resolve().parents[1]
LONG, SHORT = SAMPLES


def _start(argv: list[str], **kwargs) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "bench.cli", *map(str, argv)],
        cwd=ROOT,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        **kwargs,
    )


def _together(a: list[str], b: list[str]) -> list[tuple[int, int, str]]:
    """Start both command lines at once; [(pid, exit code, stderr)] of each."""
    started = [_start(a), _start(b)]
    return [(p.pid, p.wait(timeout=600), p.stderr.read()) for p in started]


def _one_refused(results: list[tuple[int, int, str]], out: Path) -> bool:
    """Check the pair's answers: each exit code 0 or 2, a refusal in one line naming the
    holder or the other configuration; whether one was refused."""
    codes = sorted(code for _, code, _ in results)
    assert codes in ([0, 0], [0, 2]), results
    for _, code, err in results:
        assert "Traceback" not in err and "internal error" not in err, err
        if code == 2:
            line = err.strip().splitlines()
            assert len(line) == 1, err
            winner = next(pid for pid, c, _ in results if c == 0)
            assert f"{out}: in use by pid {winner}" in line[0] or "another configuration" in line[0]
    return codes == [0, 2]


@pytest.mark.slow  # two real commands, up to four times
def test_two_scores_started_together_on_one_out(tmp_path):
    """``score --branches`` with two branch files on one ``--out``: the folder holds one of
    the two runs whole (its manifest names the file whose outcomes samples.csv holds)."""
    data = make_dataset(tmp_path / "data")
    files = []
    for k, gap in enumerate(("5,6", "1,2")):
        path = tmp_path / f"branches{k}.csv"
        path.write_text(f"sample_id,whisker_left,whisker_right\n{LONG},,\n{SHORT},{gap}\n")
        files.append(path)
    out = tmp_path / "out"
    argvs = [["score", data, "--branches", f, "--name", "m", "--out", out] for f in files]
    overlapped = False
    for _ in range(4):  # started together, they nearly always overlap; sequential is legal too
        overlapped |= _one_refused(_together(*argvs), out)
        manifest = json.loads((out / "manifest.json").read_text())
        used = [f for f in files if str(f) in manifest["inputs"]]
        assert len(used) == 1 and manifest["inputs"][str(used[0])] == sha256(used[0])
        gaps = "[[5, 6]]" if used[0] == files[0] else "[[1, 2]]"
        assert gaps in (out / "samples.csv").read_text()  # the outcomes of that file
        if overlapped:
            return
    pytest.skip("the two commands never overlapped on this machine: nothing raced")


@pytest.mark.slow  # two real studies
def test_two_studies_started_together_on_one_out(tmp_path, variant):
    """With other settings, the second study is refused whether or not the first is done."""
    out = tmp_path / "run"
    base = ["detectability", "--sizes", "13.2", "--alphas", "0,85", "--phis", "0", "--out", out]
    base += ["--workers", "1"]  # the race is on the folder, claimed by the parent: no pool
    results = _together([*base, "--images", "4"], [*base, "--images", "6"])
    codes = sorted(code for _, code, _ in results)
    assert codes == [0, 2], "\n".join(f"pid {p} exit {c}:\n{err}" for p, c, err in results)
    _one_refused(results, out)


# --- signals ------------------------------------------------------------------------------


def _hear_ctrl_c() -> None:
    """Undo an ignored SIGINT inherited from a background shell (``cmd &``), under which
    Python installs no handler and Ctrl-C could never be tested."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


@pytest.mark.slow  # a real study, interrupted, and its rerun
@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs Linux /proc")
@pytest.mark.parametrize(
    ("name", "group", "expected"),
    [("SIGINT", True, 130), ("SIGTERM", False, -signal.SIGTERM)],
    ids=["ctrl-c to the group", "kill to the parent"],
)
def test_an_interrupted_study_leaves_no_process_and_resumes_to_the_same_bytes(
    name, group, expected, clean_quick_study, tmp_path
):
    out = tmp_path / "run"
    log = tmp_path / "log"
    with log.open("w") as sink:
        parent = subprocess.Popen(
            quick_study_argv(out),
            cwd=ROOT,
            stdout=sink,
            stderr=subprocess.STDOUT,
            start_new_session=True,  # its own process group, as a terminal's job
            preexec_fn=_hear_ctrl_c,
        )
    tree: dict[int, int] = {}
    try:
        deadline = time.monotonic() + 240
        while not _finished_cells(out):
            assert parent.poll() is None, log.read_text()[-2000:]
            assert time.monotonic() < deadline, "no cell written in 240 s"
            time.sleep(0.05)
        tree = _descendants(parent.pid)
        sig = getattr(signal, name)
        os.killpg(parent.pid, sig) if group else parent.send_signal(sig)
        code = parent.wait(timeout=60)
        assert not (out / "summary.csv").exists(), "the run finished before it was stopped"
        assert code == expected, log.read_text()[-2000:]
        if name == "SIGINT":
            last = log.read_text().strip().splitlines()[-1]
            assert "interrupted: finished cells are kept" in last, last
        deadline = time.monotonic() + 10
        while any(_alive(pid, start) for pid, start in tree.items()):
            assert time.monotonic() < deadline, f"processes outlived the {name}: {tree}"
            time.sleep(0.1)
    finally:
        if parent.poll() is None:
            parent.kill()
            parent.wait()
        for pid, start in tree.items():  # a failed test leaves nothing running
            if _alive(pid, start):
                os.kill(pid, signal.SIGKILL)
    run_quick_study(out)
    assert _tables(out) == _tables(clean_quick_study)
    assert {p.relative_to(out) for p in out.rglob("*")} == {
        p.relative_to(clean_quick_study) for p in clean_quick_study.rglob("*")
    }
