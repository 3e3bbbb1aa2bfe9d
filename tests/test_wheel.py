"""The wheel ``pip wheel .`` builds works away from the clone: installed into a fresh venv, run
from an empty folder, it finds its shipped profiles and observations and runs a tiny study.

The fresh venv gets only the wheel; the third-party packages it needs come from this
interpreter's own path (without PYTHONPATH) through a ``.pth`` file. A directory a ``.pth`` file
adds is not itself scanned for ``.pth`` files, so a development install's editable finder there
(which maps ``bench``, ``scenes``, ... back to a clone) stays inactive, and the venv's own
site-packages comes first: the test checks the imports come from the venv, not a checkout.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tomllib
import zipfile
from importlib import metadata
from pathlib import Path

import pytest
from packaging.requirements import Requirement

ROOT = Path(__file__).resolve().parents[1]
PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())
#: The data files the code reads beside its modules (scenes/profile.py, scenes/observations.py).
SHIPPED_DATA = {
    path.relative_to(ROOT).as_posix()
    for folder in ("scenes/profiles", "scenes/observations")
    for path in (ROOT / folder).glob("*.json")
}


def run(argv: list[str], cwd: Path, env: dict) -> str:
    done = subprocess.run(argv, cwd=cwd, env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, f"{argv[:4]} exit {done.returncode}:\n{done.stderr[-3000:]}"
    return done.stdout


def build_backend_is_here() -> bool:
    """Whether this interpreter has every build requirement (then the build needs no network;
    ``make``'s dev extra installs them), else pip fetches them into an isolated build env."""
    for text in PYPROJECT["build-system"]["requires"]:
        requirement = Requirement(text)
        try:
            version = metadata.version(requirement.name)
        except metadata.PackageNotFoundError:
            return False
        if not requirement.specifier.contains(version, prereleases=True):
            return False
    return True


def source_copy(dest: Path) -> Path:
    """The files the build reads, copied: building in the clone would leave ``build/`` there,
    whose stale modules setuptools ships, and two builds at once would share it."""
    project = PYPROJECT["project"]
    tops = [p.rstrip("*") for p in PYPROJECT["tool"]["setuptools"]["packages"]["find"]["include"]]
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc")
    for top in tops:
        shutil.copytree(ROOT / top, dest / top, ignore=ignore)
    for name in ["pyproject.toml", project["readme"], *project["license-files"]]:
        shutil.copy2(ROOT / name, dest / name)
    return dest


@pytest.mark.slow
def test_the_wheel_runs_a_study_from_another_folder(tmp_path):
    # Nothing may point back at a clone: on PYTHONPATH, a clone's whiskerbench.egg-info (left by
    # ``pip install -e``) reads as the distribution installed, and pip would skip the install.
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME")}
    env["PYTHONNOUSERSITE"] = "1"

    # --- Build: the JSON data travels in the wheel, beside the top-level packages.
    source = source_copy(tmp_path / "src")
    isolation = ["--no-build-isolation"] if build_backend_is_here() else []
    pip = [sys.executable, "-m", "pip", "--disable-pip-version-check", "-q"]
    run([*pip, "wheel", ".", "--no-deps", *isolation, "-w", str(tmp_path / "dist")], source, env)
    (wheel,) = (tmp_path / "dist").glob("whiskerbench-*.whl")
    names = set(zipfile.ZipFile(wheel).namelist())
    assert len(SHIPPED_DATA) >= 3 and names >= SHIPPED_DATA
    assert {"whiskerbench/__init__.py", "bench/cli/main.py"} <= names

    # --- Install into a fresh venv that sees this interpreter's dependencies, not the clone.
    venv = tmp_path / "venv"
    run([sys.executable, "-m", "venv", "--without-pip", str(venv)], tmp_path, env)
    python = venv / "bin" / "python"
    install = ["--python", str(python), "install", "--no-deps", "--no-index", str(wheel)]
    run([*pip, *install], tmp_path, env)
    purelib = run([str(python), "-c", "import sysconfig; print(sysconfig.get_path('purelib'))"],
                  tmp_path, env).strip()  # fmt: skip
    where_deps = run(
        [sys.executable, "-c", "import sys; print(*sys.path, sep='\\n')"], tmp_path, env
    )
    deps = [p for p in where_deps.splitlines() if p and Path(p).is_dir()]
    (Path(purelib) / "_deps.pth").write_text("\n".join(deps) + "\n")

    # --- Run from an empty folder outside the clone.
    work = tmp_path / "elsewhere"
    work.mkdir()
    where = run(
        [str(python), "-c", "import bench, whiskerbench, scenes.profile as p; "
         "print(bench.__file__, whiskerbench.__file__, p.PROFILES_DIR, "
         "whiskerbench.load_observations('prototype').sensor, sep='\\n')"],
        work, env,
    ).splitlines()  # fmt: skip
    assert all(Path(p).is_relative_to(purelib) for p in where[:3]), where
    assert where[3] == "prototype"
    assert run([str(python), "-m", "whiskerbench", "--version"], work, env).strip() == (
        f"whiskerbench {PYPROJECT['project']['version']}"
    )
    script = str(venv / "bin" / "whiskerbench")
    shown = run([script, "camera", "show", "prototype"], work, env)
    assert shown.startswith("profile: prototype\n")
    run(
        [script, "detectability", "--sizes", "17.6", "--alphas", "0", "--phis", "0",
         "--images", "4", "--spp", "1", "--lighting", "lab", "--workers", "1", "--out", "study"],
        work, env,
    )  # fmt: skip
    assert (work / "study" / "max_phi.csv").read_text().startswith("lighting,size_mm,")
