"""Shared fixtures: the Mitsuba variant is chosen once per test session."""

import pytest


@pytest.fixture(scope="session")
def variant():
    from renderers.variant import select_variant

    return select_variant()


@pytest.fixture(scope="session")
def rendered_pair(tmp_path_factory, variant):
    """A rendered dataset of two short samples: a branch at 100 mm (between whiskers 8 and 9)
    and its no-branch twin. Rendered once per session (about 15 s)."""
    if variant.startswith("scalar"):
        pytest.skip("frame rendering needs a JIT variant")
    from bench.dataset.config import DatasetConfig
    from bench.dataset.generate import run_dataset
    from scenes.profile import load_profile

    config = DatasetConfig(
        camera=load_profile("ideal"),  # pipeline tests on exact pixels, not the twin
        foliage=("soft",),
        distances=("intermediate",),
        branches=((), (100.0,)),
        protocols=("outdoor",),
        lightings=("lab",),
        passes=1,
    )
    out = tmp_path_factory.mktemp("pair")
    run_dataset(config, out, variant=variant, progress=False)
    assert (out / config.samples()[1].sample_id).name == "soft-intermediate-100-outdoor-lab"
    return out
