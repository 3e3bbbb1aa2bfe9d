"""Hostile files, generated: every leaf of a shipped input file replaced in turn by a value of
each hostile kind (not a number, an infinity, a huge or negative number, the wrong type, nothing),
and the whole file damaged (emptied, cut short, binary, not UTF-8, nested past the bound).

Every variant must be answered as input: accepted, or refused in one line naming the field
(exit code 2 at the command line); never an internal error, never a traceback, and a value that
is not a finite number is never accepted where a number stands. The suite grows by a line in
:data:`KINDS` for each new input format, and by a value in
``document_mutations.HOSTILE_VALUES``.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from pathlib import Path

import pytest
from document_mutations import HOSTILE_VALUES, paths, replaced, wrong_answer

from bench.cli.main import main
from scenes.observations import check_against_lens, load_observations
from scenes.profile import load_profile

pytestmark = pytest.mark.usefixtures("figures_not_drawn")  # answers, not figures

ROOT = Path(__file__).resolve().parents[1]
#: Whole-file damage: (what, bytes from the file's own text).
DAMAGE: tuple[tuple[str, Callable[[bytes], bytes]], ...] = (
    ("emptied", lambda text: b""),
    ("cut short", lambda text: text[: len(text) // 2]),
    ("binary", lambda text: bytes(range(256)) * 8),
    ("not UTF-8", lambda text: text.replace(b'"', b'"\xff', 1)),
    ("nested past the bound", lambda text: b"[" * 100_000 + b"]" * 100_000),
    ("a list, not an object", lambda text: b"[" + text + b"]"),
)


def _refusal(read: Callable[[], object]) -> tuple[int, str]:
    """A command's answer to what ``read`` reads: its FieldError is the command's exit code 2
    and one line (bench/cli/main.py); anything else escaping is an internal error."""
    from scenes.validation import FieldError

    try:
        read()
    except FieldError as exc:
        return 2, f"{exc.field}: {exc.detail}"
    except Exception as exc:  # noqa: BLE001 (what the test is looking for)
        return 1, f"internal error: {type(exc).__name__}: {exc}"
    return 0, ""


def _profile_answer(path: Path, capsys) -> tuple[int, str]:
    """What every command taking ``--camera FILE`` reads first."""
    return _refusal(lambda: load_profile(path))


def _observations_answer(path: Path, capsys) -> tuple[int, str]:
    """What ``camera calibrate`` reads before any work: the file, then its regions against the
    lens."""
    lens = load_profile("prototype").lens
    return _refusal(lambda: check_against_lens(load_observations(path), lens))


def _show_answer(path: Path, capsys) -> tuple[int, str]:
    """``camera show FILE`` end to end, for the whole-file damage."""
    code = main(["camera", "show", str(path)])
    return code, capsys.readouterr().err


#: An input format: (name, its shipped file, how a command answers a file of that format).
KINDS = (
    ("camera profile", ROOT / "scenes/profiles/prototype.json", _profile_answer),
    ("observations", ROOT / "scenes/observations/prototype.json", _observations_answer),
)
#: Whole-file damage also through a command end to end (its exit code and message).
WHOLE_FILE = (*KINDS, ("camera show", ROOT / "scenes/profiles/prototype.json", _show_answer))


@pytest.mark.slow
@pytest.mark.parametrize(("kind", "shipped", "answer"), KINDS, ids=[k[0] for k in KINDS])
def test_every_field_of_every_format_meets_every_hostile_value(
    kind, shipped, answer, tmp_path, capsys
):
    base = json.loads(shipped.read_text())
    target = tmp_path / shipped.name
    assert answer(shipped, capsys)[0] == 0  # the shipped file itself is accepted
    wrong, tried = [], 0
    for path in paths(base):
        for value in HOSTILE_VALUES:
            target.write_text(json.dumps(replaced(base, path, value)))
            code, err = answer(target, capsys)
            tried += 1
            nonfinite = isinstance(value, float) and not math.isfinite(value)
            why = wrong_answer(code, err, nonfinite)
            if why:
                wrong.append(f"{'.'.join(map(str, path))} = {value!r}: {why}: {err.strip()[:200]}")
    assert tried > 300
    assert not wrong, f"{len(wrong)} of {tried}:\n" + "\n".join(wrong[:20])


@pytest.mark.parametrize(("kind", "shipped", "answer"), WHOLE_FILE, ids=[k[0] for k in WHOLE_FILE])
@pytest.mark.parametrize(("what", "damage"), DAMAGE, ids=[d[0] for d in DAMAGE])
def test_a_damaged_file_is_refused_in_one_line(
    kind, shipped, answer, what, damage, tmp_path, capsys
):
    target = tmp_path / shipped.name
    target.write_bytes(damage(shipped.read_bytes()))
    code, err = answer(target, capsys)
    assert code == 2, (what, err)
    assert wrong_answer(code, err, False) is None, err
