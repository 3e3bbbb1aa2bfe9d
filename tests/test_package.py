"""What a user of the package sees first: its version, its licence, how to cite it."""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

import pytest
import yaml

from bench.cli.main import main
from bench.common import manifest

ROOT = Path(__file__).resolve().parents[1]
PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
PAPER = "Whisker-based Haptic Perception System for Branch Detection in Dense Vegetation"


def test_version_prints_the_package_version(capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["--version"])
    assert exit_.value.code == 0
    out = capsys.readouterr().out
    assert out == f"whiskerbench {manifest.whiskerbench_version()}\n"
    assert re.fullmatch(r"whiskerbench \d+(\.\d+)+\S*\n", out), out


def test_a_source_tree_without_install_reads_pyproject(monkeypatch):
    """Run from a clone by PYTHONPATH, no distribution is installed: pyproject's version."""

    def not_installed(name):
        raise manifest.metadata.PackageNotFoundError(name)

    assert PYPROJECT["name"] == manifest.DISTRIBUTION
    monkeypatch.setattr(manifest.metadata, "version", not_installed)
    assert manifest.whiskerbench_version() == PYPROJECT["version"]
    assert manifest.package_versions()["whiskerbench"] == PYPROJECT["version"]


def test_citation_names_the_software_and_the_paper():
    cff = yaml.safe_load((ROOT / "CITATION.cff").read_text())
    assert cff["cff-version"] == "1.2.0" and cff["type"] == "software"
    assert (cff["version"], cff["license"]) == (PYPROJECT["version"], PYPROJECT["license"])
    assert [(r["type"], r["title"]) for r in cff["references"]] == [("article", PAPER)]
    licence = (ROOT / PYPROJECT["license-files"][0]).read_text()
    assert licence.startswith("BSD 3-Clause License\n\nCopyright (c) 2026, the whiskerbench")
