"""Shared fixtures: the Mitsuba variant is chosen once per test session."""

import pytest


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


@pytest.fixture(scope="session")
def rendered_pair(tmp_path_factory, variant, pair_config, worker_id):
    """The dataset of :func:`pair_config`, rendered once per run (about 15 s): under xdist the
    first worker to ask renders it into the run's shared folder, under a lock, and every worker
    takes its own copy (tests write scores into it)."""
    if variant.startswith("scalar"):
        pytest.skip("frame rendering needs a JIT variant")
    import fcntl
    import shutil

    from bench.dataset.generate import run_dataset

    out = tmp_path_factory.mktemp("pair")
    if worker_id == "master":  # no xdist: nothing to share
        run_dataset(pair_config, out, variant=variant, progress=False)
    else:
        shared = tmp_path_factory.getbasetemp().parent / "rendered-pair"  # this run's, all workers'
        shared.mkdir(exist_ok=True)
        with open(shared / "lock", "w") as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)
            if not (shared / "done").exists():
                run_dataset(pair_config, shared / "data", variant=variant, progress=False)
                (shared / "done").touch()
        shutil.copytree(shared / "data", out, dirs_exist_ok=True)
    assert (out / pair_config.samples()[1].sample_id).name == "soft-intermediate-100-outdoor-lab"
    return out


@pytest.fixture
def figures_not_drawn(monkeypatch):
    """Figures written as a 1-pixel PNG without drawing them, for tests of what a command
    accepts or refuses: drawing is most of a small run's time, and the figures themselves are
    tested in test_figures.py, test_replot.py and beside each command."""
    import io

    import numpy as np
    from matplotlib.figure import Figure
    from matplotlib.image import imsave

    buffer = io.BytesIO()
    imsave(buffer, np.zeros((1, 1)), format="png")
    pixel = buffer.getvalue()

    def savefig(self, fname, *args, **kwargs):
        if hasattr(fname, "write"):
            fname.write(pixel)
        else:
            with open(fname, "wb") as file:
                file.write(pixel)

    monkeypatch.setattr(Figure, "savefig", savefig)
