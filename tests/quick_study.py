"""The multi-worker study the signal and kill tests interrupt (tests/test_faults.py,
tests/test_hostile_races.py); its uninterrupted run, the fixture ``clean_quick_study``, is their
shared reference."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: The smallest multi-worker run that lasts a few seconds after its first cell is written (one
#: size: 2.5-4 s from the first cell to the summary at a load average of 5, the signal lands
#: 0.1-0.3 s after the first cell is seen).
QUICK_STUDY = ("detectability", "--quick", "--sizes", "13.2", "--images", "10", "--workers", "2")


def quick_study_argv(out: Path) -> list[str]:
    """The command line of :data:`QUICK_STUDY` into ``out``, run from :data:`ROOT`."""
    return [sys.executable, "-m", "bench.cli", *QUICK_STUDY, "--out", str(out)]


def run_quick_study(out: Path) -> None:
    """:data:`QUICK_STUDY` into ``out`` as a user runs it: a process of its own."""
    result = subprocess.run(
        quick_study_argv(out),
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert result.returncode == 0, result.stderr[-2000:]
