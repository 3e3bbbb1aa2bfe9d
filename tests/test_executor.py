"""The task pool: a per-worker context handed to every task, workers that die with their
parent, SIGKILL included, and Ctrl-C answered by the parent alone."""

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from bench.common.executor import TaskPool

ROOT = Path(__file__).resolve().parents[1]


def _setup(tag: str) -> dict:
    return {"tag": tag, "pid": os.getpid(), "built": time.monotonic_ns()}


def _task(n: int, context: dict) -> tuple[int, str, int, int]:
    return n * n, context["tag"], context["pid"], context["built"]


def test_in_process_every_task_gets_the_one_context():
    with TaskPool(1, _setup, ("here",)) as pool:
        results = list(pool.map(_task, range(5), progress=False))
    assert sorted(r[0] for r in results) == [0, 1, 4, 9, 16]
    assert {(r[1], r[2], r[3]) for r in results} == {("here", os.getpid(), results[0][3])}


def test_without_setup_the_context_is_none():
    with TaskPool() as pool:
        results = list(pool.map(lambda n, context: (n, context), [1, 2], progress=False))
    assert results == [(1, None), (2, None)]


@pytest.mark.slow
def test_each_worker_builds_its_context_once_and_reuses_it():
    with TaskPool(2, _setup, ("pool",)) as pool:
        results = list(pool.map(_task, range(8), progress=False))
    assert sorted(r[0] for r in results) == [n * n for n in range(8)]
    workers = {r[2] for r in results}
    assert os.getpid() not in workers and 1 <= len(workers) <= 2
    for pid in workers:  # one context per worker process, built once
        assert len({r[3] for r in results if r[2] == pid}) == 1
    assert {r[1] for r in results} == {"pool"}


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    try:  # a zombie (exited, not yet reaped by its adoptive parent) counts as gone
        return Path(f"/proc/{pid}/stat").read_text().split(")")[-1].split()[0] != "Z"
    except OSError:
        return not sys.platform.startswith("linux")


POOL_PARENT = """
import os, sys, time
from pathlib import Path

from bench.common.executor import TaskPool


def sleep_forever(_task, _context):
    Path(sys.argv[1], str(os.getpid())).touch()
    time.sleep(600)


if __name__ == "__main__":
    with TaskPool(2) as pool:
        list(pool.map(sleep_forever, range(2), progress=False))
"""

# Children that arm the watch thread alone (as where there is no prctl), under a plain parent.
WATCHED_PARENT = """
import subprocess, sys, time

CHILD = (
    "import os, sys, time; from pathlib import Path; sys.platform = 'no-prctl'; "
    "from pipeline.lifetime import exit_with_parent; exit_with_parent(os.getppid()); "
    "Path(sys.argv[1], str(os.getpid())).touch(); time.sleep(600)"
)

if __name__ == "__main__":
    for _ in range(2):
        subprocess.Popen([sys.executable, "-c", CHILD, sys.argv[1]])
    time.sleep(600)
"""


@pytest.mark.slow
@pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals")
@pytest.mark.parametrize("parent_code", [POOL_PARENT, WATCHED_PARENT], ids=["pool", "watch"])
def test_workers_die_when_their_parent_is_killed(tmp_path, parent_code):
    script = tmp_path / "parent.py"
    script.write_text(textwrap.dedent(parent_code))
    marks = tmp_path / "pids"
    marks.mkdir()
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    parent = subprocess.Popen([sys.executable, str(script), str(marks)], env=env)
    try:
        deadline = time.monotonic() + 60
        while len(list(marks.iterdir())) < 2:
            assert time.monotonic() < deadline, "the workers never started"
            assert parent.poll() is None, "the parent ended early"
            time.sleep(0.05)
        workers = [int(p.name) for p in marks.iterdir()]
        assert all(_alive(pid) for pid in workers)
        parent.send_signal(signal.SIGKILL)
        parent.wait()
        deadline = time.monotonic() + 5
        while any(_alive(pid) for pid in workers) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not [pid for pid in workers if _alive(pid)], "a worker outlived its parent"
    finally:
        parent.kill()
        for mark in marks.iterdir():
            if _alive(int(mark.name)):
                os.kill(int(mark.name), signal.SIGKILL)


INTERRUPTED_PARENT = """
import sys, time
from pathlib import Path

from bench.common.executor import TaskPool


def work(task, _context):
    Path(sys.argv[1], f"started-{task}").touch()
    end = time.monotonic() + 3
    while time.monotonic() < end:
        time.sleep(0.01)
    Path(sys.argv[1], f"finished-{task}").touch()


if __name__ == "__main__":
    try:
        with TaskPool(2) as pool:
            list(pool.map(work, range(8), progress=False))
    except KeyboardInterrupt:
        sys.exit(130)
"""


@pytest.mark.slow
@pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals")
def test_ctrl_c_lets_running_tasks_finish_and_starts_no_other(tmp_path):
    """Ctrl-C reaches the whole group. A worker that took it as its task's error went on to the
    next task in whatever state the interruption left (a study cell was written after Ctrl-C
    with other column types); now the tasks running finish whole and no queued one starts."""
    script = tmp_path / "parent.py"
    script.write_text(textwrap.dedent(INTERRUPTED_PARENT))
    marks = tmp_path / "marks"
    marks.mkdir()
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    parent = subprocess.Popen(
        [sys.executable, str(script), str(marks)], env=env, start_new_session=True
    )
    try:
        deadline = time.monotonic() + 60
        while len(list(marks.glob("started-*"))) < 2:
            assert time.monotonic() < deadline, "the workers never started"
            assert parent.poll() is None, "the parent ended early"
            time.sleep(0.01)
        os.killpg(parent.pid, signal.SIGINT)  # a terminal's Ctrl-C
        assert parent.wait(timeout=60) == 130
        started = sorted(p.name.split("-")[1] for p in marks.glob("started-*"))
        finished = sorted(p.name.split("-")[1] for p in marks.glob("finished-*"))
        assert len(started) == 2, f"a task started after the Ctrl-C: {started}"
        assert finished == started, f"a running task was cut: {started} {finished}"
    finally:
        if parent.poll() is None:
            os.killpg(parent.pid, signal.SIGKILL)
            parent.wait()


@pytest.mark.skipif(sys.platform == "win32", reason="POSIX parent ids")
def test_a_worker_whose_parent_is_already_gone_exits_at_once():
    """The race the parent-death signal cannot cover: the parent died before it was armed."""
    code = "from pipeline.lifetime import exit_with_parent; exit_with_parent(-1); print('ran')"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    result = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True)
    assert result.returncode == 1 and "ran" not in result.stdout
