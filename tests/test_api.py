"""``import whiskerbench``: every public name resolves, says what it is, is in docs/api.md, and
the import stays light (no Mitsuba or Dr.Jit until something renders)."""

from __future__ import annotations

import dataclasses
import importlib.util
import inspect
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

import whiskerbench

ROOT = Path(__file__).resolve().parents[1]
NAMES = list(whiskerbench._API)
HEAVY = ("mitsuba", "drjit")


def resolve(name: str):
    module = whiskerbench._API[name].partition(":")[0]
    assert importlib.util.find_spec(module) is not None, f"{name}: no module {module}"
    return getattr(whiskerbench, name)


def test_all_is_the_table_and_dir_offers_it():
    assert whiskerbench.__all__ == NAMES and len(set(NAMES)) == len(NAMES)
    assert set(NAMES) <= set(dir(whiskerbench))


def test_an_unknown_name_is_an_attribute_error_in_one_line():
    with pytest.raises(AttributeError, match=r"^module 'whiskerbench' has no attribute 'nope'$"):
        whiskerbench.nope  # noqa: B018
    assert not hasattr(whiskerbench, "run_studies")


@pytest.mark.parametrize("name", NAMES)
def test_every_public_name_says_what_it_is(name):
    """A class or function has its own docstring (not a dataclass's generated signature);
    a value (``PRESETS``) has a ``#:`` comment on the line above its assignment."""
    value = resolve(name)
    attribute = whiskerbench._API[name].partition(":")[2]
    assert value is getattr(whiskerbench, name)  # kept after the first access
    if inspect.isclass(value) or inspect.isroutine(value):
        doc = inspect.getdoc(value) or ""
        assert doc.strip(), f"{name} has no docstring"
        if dataclasses.is_dataclass(value):
            assert not doc.startswith(f"{value.__name__}("), f"{name}: generated docstring only"
    else:
        source = inspect.getsource(sys.modules[whiskerbench._API[name].partition(":")[0]])
        assert re.search(rf"^#: \S.*\n{attribute}\b", source, re.M), f"{name}: no #: comment"


def test_every_public_name_has_a_line_in_the_api_docs():
    """docs/api.md lists each name once, as ``- `name`...``, and the README links it."""
    text = (ROOT / "docs" / "api.md").read_text()
    listed = re.findall(r"^- `(\w+)", text, re.M)
    assert sorted(listed) == sorted(NAMES)
    assert "(docs/api.md)" in (ROOT / "README.md").read_text()


def modules_after(code: str) -> tuple[str, list[str]]:
    """Run ``code`` after ``import whiskerbench`` in a fresh interpreter: the file it imported
    and which of the heavy packages (and OpenCV, pandas, matplotlib) it left loaded."""
    probe = (
        "import json, sys\nimport whiskerbench\n"
        f"{code}\n"
        "print(json.dumps([whiskerbench.__file__, [m for m in "
        "('mitsuba', 'drjit', 'cv2', 'pandas', 'matplotlib') if m in sys.modules]]))"
    )
    path = os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))
    done = subprocess.run(
        [sys.executable, "-c", probe],
        cwd=ROOT,
        env=dict(os.environ, PYTHONPATH=path),
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0, done.stderr
    file, loaded = json.loads(done.stdout.splitlines()[-1])
    return file, loaded


def test_import_whiskerbench_loads_nothing_heavy():
    """The bare import reads only whiskerbench/__init__.py: not even OpenCV or pandas."""
    file, loaded = modules_after("")
    assert Path(file) == ROOT / "whiskerbench" / "__init__.py"
    assert loaded == []


@pytest.mark.slow
def test_resolving_every_name_loads_no_mitsuba_or_drjit():
    """Even ``run_study`` and the other functions that render, resolved (not called), leave
    Mitsuba and Dr.Jit out: the variant is chosen when they run, before Dr.Jit loads."""
    present = [n for n in NAMES if importlib.util.find_spec(whiskerbench._API[n].split(":")[0])]
    _, loaded = modules_after(f"for name in {present!r}: getattr(whiskerbench, name)")
    assert "pandas" in loaded  # the probe did import the homes
    assert not set(HEAVY) & set(loaded), loaded
