"""A real run killed mid-way: its workers die with it, and the rerun resumes to the very bytes of
an uninterrupted run (issue 10, part 6).

The parent is killed with SIGKILL, which no handler sees: the workers must notice on their own.
Processes are found through /proc (Linux), so no extra dependency is needed.
"""

import os
import signal
import subprocess
import time
from pathlib import Path

import pytest
from quick_study import ROOT, quick_study_argv, run_quick_study

pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs Linux /proc"),
]

#: Outputs that must be byte-identical; manifest.json differs by its timings and is left out.
TABLES = ("*.csv", "*.parquet", "config.json", "cells/*.parquet")


def _stat(pid: int) -> tuple[str, int, int] | None:
    """(state, parent pid, start time) of a process, or None once it is gone."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
    except (FileNotFoundError, ProcessLookupError):
        return None
    fields = text[text.rindex(")") + 2 :].split()  # the name in parentheses may hold spaces
    return fields[0], int(fields[1]), int(fields[19])


def _descendants(root: int) -> dict[int, int]:
    """Every living process below ``root``, by pid, with its start time (to survive pid reuse)."""
    children: dict[int, list[int]] = {}
    starts = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit() and (stat := _stat(int(entry.name))) is not None:
            children.setdefault(stat[1], []).append(int(entry.name))
            starts[int(entry.name)] = stat[2]
    found, todo = {}, [root]
    while todo:
        for child in children.get(todo.pop(), ()):
            found[child] = starts[child]
            todo.append(child)
    return found


def _alive(pid: int, start: int) -> bool:
    stat = _stat(pid)
    return stat is not None and stat[2] == start and stat[0] not in ("Z", "X")  # zombie = dead


def _cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
    except OSError:
        return ""


def _tables(out: Path) -> dict[str, bytes]:
    return {
        str(path.relative_to(out)): path.read_bytes()
        for pattern in TABLES
        for path in sorted(out.glob(pattern))
    }


def _finished_cells(folder: Path) -> list[Path]:
    """The study's finished cells: not a killed writer's temporary file, which also ends in
    .parquet (``.<name>.<run>-<pid>.tmp-<random>.parquet``) and which the rerun deletes."""
    return [p for p in folder.glob("cells/*.parquet") if not p.name.startswith(".")]


def test_killed_parent_takes_its_workers_and_the_rerun_is_identical(clean_quick_study, tmp_path):
    clean, killed = clean_quick_study, tmp_path / "killed"

    log = (tmp_path / "killed.log").open("w")
    parent = subprocess.Popen(
        quick_study_argv(killed),
        cwd=ROOT,
        stdout=log,
        stderr=subprocess.STDOUT,
    )
    tree: dict[int, int] = {}
    try:
        deadline = time.monotonic() + 240
        while not _finished_cells(killed):
            assert parent.poll() is None, (tmp_path / "killed.log").read_text()[-2000:]
            assert time.monotonic() < deadline, "no cell written in 240 s"
            time.sleep(0.05)
        tree = _descendants(parent.pid)
        workers = [pid for pid in tree if "spawn_main" in _cmdline(pid)]
        parent.send_signal(signal.SIGKILL)
        parent.wait(timeout=10)
        assert not (killed / "summary.csv").exists(), "the run finished before it was killed"
        assert len(workers) >= 2, f"expected 2 workers below the parent, found {tree}"

        deadline = time.monotonic() + 10
        while any(_alive(pid, start) for pid, start in tree.items()):
            if time.monotonic() > deadline:
                survivors = [p for p, s in tree.items() if _alive(p, s)]
                pytest.fail(f"processes outlived their killed parent: {survivors}")
            time.sleep(0.1)
    finally:
        log.close()
        if parent.poll() is None:
            parent.kill()
            parent.wait()
        for pid, start in tree.items():  # a failed test must not leave them running
            if _alive(pid, start):
                os.kill(pid, signal.SIGKILL)

    kept = {path: path.stat().st_mtime_ns for path in _finished_cells(killed)}
    run_quick_study(killed)

    expected, got = _tables(clean), _tables(killed)
    assert got.keys() == expected.keys()
    assert not [name for name in expected if got[name] != expected[name]], "tables differ"
    assert {p.relative_to(killed) for p in killed.rglob("*")} == {
        p.relative_to(clean) for p in clean.rglob("*")
    }, "the rerun left other files than a clean run (a killed run's temporary files?)"
    rewritten = [path.name for path, mtime in kept.items() if path.stat().st_mtime_ns != mtime]
    assert not rewritten, f"finished cells were computed again instead of resumed: {rewritten}"
