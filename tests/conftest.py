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
def rendered_pair(tmp_path_factory, variant, pair_config):
    """The dataset of :func:`pair_config`, rendered once per session (about 15 s)."""
    if variant.startswith("scalar"):
        pytest.skip("frame rendering needs a JIT variant")
    from bench.dataset.generate import run_dataset

    out = tmp_path_factory.mktemp("pair")
    run_dataset(pair_config, out, variant=variant, progress=False)
    assert (out / pair_config.samples()[1].sample_id).name == "soft-intermediate-100-outdoor-lab"
    return out
