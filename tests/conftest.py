"""Shared fixtures: the Mitsuba variant is chosen once per test session."""

import os

import pytest


def pytest_configure(config):
    """Each of N xdist workers renders with cores / N Dr.Jit threads: a pool of one thread per
    core in every worker puts N times as many threads as cores on the machine, and a parallel
    kernel then waits for threads the other workers descheduled (bench/dataset/core_share.py)."""
    workers = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))
    if workers > 1 and "PYTEST_XDIST_WORKER" in os.environ:
        from renderers.variant import set_threads

        set_threads(max(1, (os.cpu_count() or 1) // workers))


@pytest.hookimpl(trylast=True)  # after pytest's own reordering by fixture scope
def pytest_collection_modifyitems(items):
    """Tests marked ``start_early`` first, in their order; the rest as collected. xdist's
    ``load`` gives each worker a first chunk of the collection, then the rest in chunks to
    whichever worker is free: a test of minutes collected late (the README's quickstart, at
    "r") could be left running on one worker after the other has finished everything else."""
    items.sort(key=lambda item: item.get_closest_marker("start_early") is None)


@pytest.fixture(scope="session")
def variant():
    from renderers.variant import select_variant

    return select_variant()


@pytest.fixture(scope="session")
def pair_config():
    """The config of :func:`rendered_pair`: two short samples, a branch at 100 mm (between
    whiskers 8 and 9) and its no-branch twin, on the ideal camera."""
    from bench.dataset.config import DatasetConfig
    from scenes.profile import load_profile

    return DatasetConfig(
        camera=load_profile("ideal"),  # pipeline tests on exact pixels, not the twin
        foliage=("soft",),
        distances=("intermediate",),
        branches=((), (100.0,)),
        protocols=("outdoor",),
        lightings=("lab",),
        passes=1,
    )


_BUILT: dict[str, object] = {}  # this process's folders by name (built_once)


def built_once(tmp_path_factory, worker_id: str, name: str, build):
    """The folder ``build(folder)`` writes, built once per test run: under xdist the first
    worker to ask builds it in the run's folder shared by all workers, under a lock; the others
    wait and reuse it; within one process a second call returns the folder at once. Callers
    that write into it take a copy."""
    import fcntl

    if name in _BUILT:
        return _BUILT[name]
    if worker_id == "master":  # no xdist: nothing to share
        folder = tmp_path_factory.mktemp(name) / "out"
        build(folder)
        _BUILT[name] = folder
        return folder
    shared = tmp_path_factory.getbasetemp().parent / name  # this run's, all workers'
    shared.mkdir(exist_ok=True)
    with open(shared / "lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not (shared / "done").exists():
            build(shared / "out")
            (shared / "done").touch()
    _BUILT[name] = shared / "out"
    return shared / "out"


@pytest.fixture(scope="session")
def rendered_pair(tmp_path_factory, variant, pair_config, worker_id):
    """The dataset of :func:`pair_config`, rendered once per run (about 15 s); each worker
    takes its own copy, since tests write scores into it."""
    if variant.startswith("scalar"):
        pytest.skip("frame rendering needs a JIT variant")
    import shutil

    from bench.dataset.generate import run_dataset

    def render(out):
        run_dataset(pair_config, out, variant=variant, progress=False)

    out = tmp_path_factory.mktemp("pair") / "data"
    shutil.copytree(built_once(tmp_path_factory, worker_id, "rendered-pair", render), out)
    assert (out / pair_config.samples()[1].sample_id).name == "soft-intermediate-100-outdoor-lab"
    return out


def copy_pair(rendered_pair, dest):
    """A copy of the rendered pair's own files at ``dest`` (without the score and compare
    folders other tests wrote into the session's copy); ``dest``."""
    import shutil

    return shutil.copytree(rendered_pair, dest, ignore=shutil.ignore_patterns("scores", "compare"))


def compare_once(tmp_path_factory, worker_id, rendered_pair, name, methods, sweep, drawn=(),
                 prepare=None, cwd=None):  # fmt: skip
    """(folder, summary) of ``run_compare`` of ``methods`` (callable: folder -> the methods) on
    a copy of the pair, built once per run (:func:`built_once`): the report in
    ``folder / "report"``, each method's scores beside the copy in ``folder / "data" /
    "scores"``, the summary returned as it was (dtypes and all). Only the figures named by
    ``drawn`` are drawn (:func:`drawn_only`); ``prepare(folder)`` runs first (files the methods
    name), ``cwd`` is the folder the compare runs in. Read, never written."""
    import pandas as pd

    from bench.evaluate.compare import run_compare

    def build(folder):
        copy_pair(rendered_pair, folder / "data")
        if prepare is not None:
            prepare(folder)
        with pytest.MonkeyPatch.context() as monkeypatch:
            if cwd is not None:
                monkeypatch.chdir(cwd)
            drawn_only(monkeypatch, *drawn)
            summary = run_compare(
                folder / "data", methods(folder), folder / "report", sweep,
                speed_frames=2, speed_rounds=3,
            )  # fmt: skip
        summary.to_pickle(folder / "summary.pkl")

    folder = built_once(tmp_path_factory, worker_id, name, build)
    return folder, pd.read_pickle(folder / "summary.pkl")


@pytest.fixture(scope="session")
def clean_quick_study(tmp_path_factory, worker_id):
    """:data:`quick_study.QUICK_STUDY` run once, uninterrupted, for the whole run: the
    reference of the tests that interrupt it; read, never written."""
    from quick_study import run_quick_study

    return built_once(tmp_path_factory, worker_id, "clean-quick-study", run_quick_study)


def drawn_only(monkeypatch, *names: str) -> None:
    """Figures written as a 1-pixel PNG without drawing them, except the files whose name
    matches one of ``names`` (glob patterns), which a test checks: drawing is most of a small
    run's time, and the figures themselves are tested in test_figures.py, test_replot.py and
    beside each command."""
    import fnmatch
    import io
    import os

    import numpy as np
    from matplotlib.figure import Figure
    from matplotlib.image import imsave

    buffer = io.BytesIO()
    imsave(buffer, np.zeros((1, 1)), format="png")
    pixel = buffer.getvalue()
    draw = Figure.savefig

    def savefig(self, fname, *args, **kwargs):
        name = "" if hasattr(fname, "write") else os.path.basename(os.fspath(fname))
        # figures.save writes through a temporary ".<name>.<run>-<pid>.tmp-XXXX.png" first
        if any(fnmatch.fnmatch(name, p) or fnmatch.fnmatch(name, f".{p}.*") for p in names):
            return draw(self, fname, *args, **kwargs)
        if hasattr(fname, "write"):
            fname.write(pixel)
        else:
            with open(fname, "wb") as file:
                file.write(pixel)

    monkeypatch.setattr(Figure, "savefig", savefig)


@pytest.fixture
def figures_not_drawn(monkeypatch):
    """Figures written as a 1-pixel PNG without drawing them (:func:`drawn_only`), for tests
    of what a command accepts or refuses."""
    drawn_only(monkeypatch)
