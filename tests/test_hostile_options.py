"""Hostile option values, generated (issue 24, part 9): every option of every command, read from
the command line's own parser, is given each value of :data:`VALUES` (not a number, infinities,
a number or an integer beyond floats, a denormal, nothing, a list with a hole, ...).

Every variant must be refused as input (exit code 2, one line naming the culprit, nothing
written) or accepted; never an internal error, a traceback or another exit code. Accepted
values stop at the command's work, which is replaced by a sentinel: nothing here renders or
scores. A new option or command is probed without a line here; a command with required
arguments needs its line in :data:`BASES`. The suite found the 400-digit ``--workers``,
``--spp``, ``--subframes``, ``--frames-step`` and ``--seeds``, ``--speed 1e-320`` and a
``--camera`` name too long for a file, each an internal error before.
"""

from __future__ import annotations

import argparse
import importlib
import shutil
from pathlib import Path

import pytest
from fake_dataset import make_dataset

from bench.cli.main import _parser, main

pytestmark = [pytest.mark.slow, pytest.mark.usefixtures("figures_not_drawn")]

BIG = "9" * 400  # an integer no float holds
VALUES = ("nan", "inf", "-1", "0", "1e309", "1e-320", BIG, "-" + BIG, "", "abc", "1,,2")
NOT_FINITE = ("nan", "inf", "1e309")
ACCEPTED = "accepted"
#: Options not probed here: the output (every command's own tests), a scheduler's address
#: (contacting it takes seconds: tests/test_scheduler_check.py), help.
SKIP = {"--out", "--scheduler", "--help"}
#: The work each command hands over to once its input is checked.
WORK = (
    ("bench.study.run", "run_study"),
    ("bench.dataset.generate", "run_dataset"),
    ("bench.evaluate.score", "score_dataset"),
    ("bench.evaluate.compare", "run_compare"),
    ("bench.evaluate.detect", "run_detect"),
    ("bench.evaluate.images", "run_detect_images"),
    ("bench.ladder.run", "run_ladder"),
    ("bench.lens.measure", "footage_files"),  # after measure_lens checks its settings
    ("bench.twin.run", "run_calibration"),
    ("bench.twin.evidence", "evidence_of"),
    ("bench.benchmarks.pipeline", "bench_pipeline"),
    ("bench.benchmarks.render", "bench_render"),
    ("bench.benchmarks.scale", "bench_scale"),
    ("bench.benchmarks.loader", "bench_loader"),
    ("bench.benchmarks.study", "bench_detectability"),
    ("bench.benchmarks.dataset", "bench_dataset"),
    ("bench.benchmarks.targets", "bench_targets"),
)
PHOTOS = Path(__file__).parent / "data" / "real_markers"
OBSERVATIONS = Path(__file__).parents[1] / "scenes" / "observations" / "prototype.json"


class Accepted(BaseException):
    """The command reached its work: the value was accepted."""


def _leaves(parser: argparse.ArgumentParser, path: tuple[str, ...] = ()):
    """(command path, parser) of every command that runs (no subcommands of its own)."""
    subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    if not subs:
        yield path, parser
        return
    for name, sub in subs[0].choices.items():
        yield from _leaves(sub, (*path, name))


LEAVES = dict(_leaves(_parser()))


def _bases(data: Path) -> dict[tuple[str, ...], list[str]]:
    """The arguments each command needs besides the probed option."""
    sample = data / "soft-far-none-outdoor-lab"
    return {
        ("score",): [str(data), "--pipeline", "paper"],
        ("compare",): [str(data)],
        ("replot",): [str(data)],
        ("detect",): [str(sample / "video.mp4"), "--camera", str(sample / "camera.json")],
        ("detect-images",): [str(PHOTOS), "--pipelines", "paper"],
        ("lens", "measure"): [str(sample / "video.mp4"), "--camera", "prototype"],
        ("camera", "show"): ["prototype"],
        ("camera", "project"): ["prototype", "--theta-deg", "10"],
        ("camera", "import"): [str(data.parent / "calib.json"), "--format", "basalt"],
        ("camera", "calibrate"): ["prototype", "--observations", str(OBSERVATIONS)],
        ("camera", "check"): ["prototype", "--observations", str(OBSERVATIONS)],
        ("bench", "loader"): [str(data), "--sample", sample.name],
    }


@pytest.fixture(scope="module")
def data(tmp_path_factory) -> Path:
    from test_calibration_import import basalt_calib, basalt_entry
    from test_lens_models import TUM_KB4

    folder = make_dataset(tmp_path_factory.mktemp("options") / "data")
    basalt_calib(folder.parent, [basalt_entry("kb4", TUM_KB4, ("k1", "k2", "k3", "k4"))])
    return folder


def _without(argv: list[str], option: str) -> list[str]:
    """``argv`` without ``option`` and its value (the probe gives its own)."""
    if option not in argv:
        return argv
    i = argv.index(option)
    return argv[:i] + argv[i + 2 :]


def _answer(argv: list[str], out: Path, capsys) -> str | None:
    """None when the command refused ``argv`` well; ACCEPTED when it took it to its work (or
    ran); else what went wrong."""
    if out.is_dir():  # what an accepted value wrote (camera import runs for real)
        shutil.rmtree(out)
    out.unlink(missing_ok=True)
    capsys.readouterr()
    try:
        code = main(argv)
    except Accepted:
        return ACCEPTED
    except SystemExit as exc:
        code = exc.code
    except BaseException as exc:  # noqa: BLE001 - any escape is the finding
        return f"raised {type(exc).__name__}: {exc}"[:200]
    err = capsys.readouterr().err.strip().splitlines()
    if code == 0:
        return ACCEPTED
    if code != 2:
        return f"exit {code}: {' | '.join(err)[:200]}"
    if len(err) != 1 or not err[0].startswith("whiskerbench ") or "Traceback" in err[0]:
        return f"exit 2 with {len(err)} lines: {' | '.join(err)[:200]}"
    if out.exists():
        return "refused but wrote its output"
    return None


@pytest.mark.parametrize("path", list(LEAVES), ids=" ".join)
def test_every_option_meets_every_hostile_value(path, data, tmp_path, capsys, monkeypatch):
    for module, name in WORK:
        monkeypatch.setattr(importlib.import_module(module), name, _accept)
    monkeypatch.chdir(tmp_path)  # a default output lands here
    parser = LEAVES[path]
    takes_out = any("--out" in a.option_strings for a in parser._actions)
    base = [*path, *_bases(data).get(path, [])]
    out = tmp_path / "out.json" if path[0] in ("camera", "lens") else tmp_path / "out"

    def argv(*extra: str) -> list[str]:
        return [*extra, *(["--out", str(out)] if takes_out else [])]

    options = {
        next(s for s in a.option_strings if s.startswith("--")): _numeric(a)
        for a in parser._actions
        if a.option_strings and a.nargs != 0 and not SKIP & set(a.option_strings)
    }
    base_answer = _answer(argv(*base), out, capsys)
    assert base_answer == ACCEPTED or (base_answer is None and not options), base
    found = []
    for option, numeric in options.items():
        for value in VALUES:
            wrong = _answer(argv(*_without(base, option), option, value), out, capsys)
            if wrong == ACCEPTED:  # a number that is not finite is no input anywhere
                must_refuse = numeric and value in NOT_FINITE
                wrong = "a number that is not finite accepted" if must_refuse else None
            if wrong:
                found.append(f"{' '.join(path)} {option} {value[:12]!r}: {wrong}")
    assert not found, "\n".join(found)


def _numeric(action: argparse.Action) -> bool:
    """Whether the option reads numbers (a float or a list of them)."""
    kind = getattr(action.type, "__qualname__", "")
    return action.type is float or kind.startswith(("float_list", "psf_scales_option"))


def _accept(*args, **kwargs):
    raise Accepted
