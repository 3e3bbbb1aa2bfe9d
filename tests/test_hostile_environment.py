"""Hostile environments (issue 24, part 9): a command runs to its end under a locale or
stream encoding that lacks the characters of its paths, a missing temporary folder, no home
folder or an unwritable Matplotlib cache; an environment it cannot work in is told as such,
never as an internal error.

Each case runs ``score --branches`` (reads a dataset, writes a table and figures, prints paths)
into a folder whose name is not ASCII, in a process of its own.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from fake_dataset import SAMPLES, make_dataset

ROOT = Path(__file__).resolve().parents[1]
LONG, SHORT = SAMPLES

#: name: (variables set, variables removed). A new environment is a new line.
ENVIRONMENTS = {
    "stdout in ASCII": ({"PYTHONIOENCODING": "ascii"}, ()),
    "C locale": ({"LC_ALL": "C", "LANG": "C"}, ()),
    "Latin-1 stdout": ({"PYTHONIOENCODING": "latin-1"}, ()),
    "TMPDIR missing": ({"TMPDIR": "/nonexistent/tmp"}, ()),
    "no HOME": ({}, ("HOME",)),
    "Matplotlib cache unwritable": ({"MPLCONFIGDIR": "/proc/no-such-folder"}, ()),
}
#: One case stays in the fast tests (it was a bug: an internal error after all the work).
FAST = ("stdout in ASCII",)


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    return make_dataset(tmp_path_factory.mktemp("environment") / "data")


@pytest.mark.parametrize(
    "name", [pytest.param(n, marks=[] if n in FAST else [pytest.mark.slow]) for n in ENVIRONMENTS]
)
def test_a_command_runs_to_its_end_in_a_hostile_environment(name, dataset, tmp_path):
    branches = tmp_path / "branches.csv"
    branches.write_text(f"sample_id,whisker_left,whisker_right\n{LONG},,\n{SHORT},5,6\n")
    out = tmp_path / "résultats-測試"
    variables, removed = ENVIRONMENTS[name]
    env = {k: v for k, v in os.environ.items() if k not in removed}
    env.update(variables, PYTHONPATH=str(ROOT))
    argv = ["score", dataset, "--branches", branches, "--name", "m", "--out", out]
    done = subprocess.run(
        [sys.executable, "-m", "bench.cli", *map(str, argv)],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        timeout=300,
    )
    err = done.stderr.decode("utf-8", "replace")
    assert done.returncode == 0, err
    assert "Traceback" not in err and "internal error" not in err, err
    assert b"wrote " in done.stdout and (out / "samples.csv").is_file()
