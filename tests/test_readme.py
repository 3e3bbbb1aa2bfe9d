"""The README's first hour works as written: every relative link of the README and docs/ leads
to a file (and heading) that exists, and the quick start's commands run verbatim.

The quick start is the fenced block between ``<!-- quickstart -->`` and ``<!-- /quickstart -->``.
The rule for running it: each non-empty line is handed to bash as written, in order, in an empty
folder, with the folder of the interpreter running the tests first on ``PATH`` (where the
install put ``whiskerbench``) and this checkout on ``PYTHONPATH`` (so its code is what runs).
The commands are small already (``--quick``); nothing is substituted or appended.
"""

import os
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
DOCS = sorted((ROOT / "docs").glob("*.md"))
MAX_QUICKSTART_LINES = 15

QUICKSTART = re.compile(r"<!-- quickstart -->\s*```bash\n(.*?)```\s*<!-- /quickstart -->", re.S)
FENCE = re.compile(r"^```.*?^```", re.S | re.M)
LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)\)")
HEADING = re.compile(r"^#{1,6} +(.+?) *#*$", re.M)
#: A timing in a quick-start comment: "# 22 s", "# 22-69 s", "# 3 min".
TIME = re.compile(r"#\s*\d+(\.\d+)?(-\d+(\.\d+)?)?\s*(s|min)\b")
#: A path a quick-start comment names as the command's output.
OUTPUT = re.compile(r"\b((?:runs|data)/[\w./-]+)")


def slug(heading: str) -> str:
    """GitHub's anchor for a heading: lower case, punctuation dropped, spaces to hyphens."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def anchors(path: Path) -> set[str]:
    return {slug(h) for h in HEADING.findall(FENCE.sub("", path.read_text()))}


def relative_links(path: Path) -> list[str]:
    """Link and image targets of a Markdown file outside code blocks, not URLs."""
    text = FENCE.sub("", path.read_text())
    return [t for t in LINK.findall(text) if not re.match(r"^[a-z]+:", t)]


def quickstart_lines(text: str) -> list[str]:
    found = QUICKSTART.findall(text)
    assert len(found) == 1, "README.md needs one ```bash block inside <!-- quickstart --> marks"
    return [line for line in found[0].splitlines() if line.strip()]


@pytest.mark.parametrize("doc", [README, *DOCS], ids=lambda p: p.relative_to(ROOT).as_posix())
def test_relative_links_lead_to_existing_files(doc):
    links = relative_links(doc)
    broken = []
    for link in links:
        target, _, anchor = link.partition("#")
        path = (doc.parent / target).resolve() if target else doc
        if not path.exists():
            broken.append(f"{link} (no file {path.relative_to(ROOT)})")
        elif anchor and path.suffix == ".md" and anchor not in anchors(path):
            broken.append(f"{link} (no heading #{anchor} in {path.name})")
    assert not broken, f"{doc.name}: broken links: {broken}"


def test_readme_links_every_doc():
    linked = {(README.parent / t.partition("#")[0]).resolve() for t in relative_links(README)}
    assert [d.name for d in DOCS if d.resolve() not in linked] == []


def test_the_link_check_sees_a_broken_link(tmp_path):
    """The checks above could fail: a missing file and a missing heading are both caught."""
    doc = tmp_path / "a.md"
    doc.write_text("# Title here\n[ok](a.md#title-here) [gone](b.md) [bad](a.md#nope)\n")
    assert relative_links(doc) == ["a.md#title-here", "b.md", "a.md#nope"]
    assert anchors(doc) == {"title-here"}
    assert slug("Detector backends and peers (`pipeline/backends/`)") == (
        "detector-backends-and-peers-pipelinebackends"
    )


def test_quickstart_is_short_timed_and_parses():
    """At most 15 lines, each a whiskerbench command the parser accepts, with its measured time
    and the output it names."""
    from bench.cli.main import _parser

    lines = quickstart_lines(README.read_text())
    assert 0 < len(lines) <= MAX_QUICKSTART_LINES
    parser = _parser()
    for line in lines:
        command, _, comment = line.partition("#")
        words = shlex.split(command)
        assert words[0] == "whiskerbench", line
        parser.parse_args(words[1:])  # SystemExit (a test failure) on a bad option
        assert TIME.search("#" + comment), f"no measured time in: {line}"
        assert OUTPUT.search(comment), f"no output named in: {line}"


@pytest.mark.start_early
@pytest.mark.slow
def test_quickstart_runs_verbatim(tmp_path):
    """Renders a quick study, a quick dataset and scores and compares it (minutes)."""
    bin_dir = Path(sys.executable).parent
    if shutil.which("whiskerbench", path=str(bin_dir)) is None:
        pytest.skip(f"whiskerbench is not installed beside {sys.executable}")
    env = dict(os.environ)
    env["PATH"] = f"{bin_dir}{os.pathsep}{env.get('PATH', '')}"
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(ROOT), env.get("PYTHONPATH")]))
    for line in quickstart_lines(README.read_text()):
        done = subprocess.run(
            ["bash", "-c", line], cwd=tmp_path, env=env, capture_output=True, text=True
        )
        assert done.returncode == 0, f"{line}\n{done.stderr[-2000:]}"
        for output in OUTPUT.findall(line.partition("#")[2]):
            assert (tmp_path / output).exists(), f"{line}: wrote no {output}"
