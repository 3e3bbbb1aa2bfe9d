"""The suite's own order: the tests of minutes start first (tests/conftest.py)."""

import pytest


def test_tests_marked_start_early_run_before_every_other(request: pytest.FixtureRequest) -> None:
    early = [item.get_closest_marker("start_early") is not None for item in request.session.items]
    assert early == sorted(early, reverse=True), [
        item.nodeid for item, first in zip(request.session.items, early, strict=True) if first
    ]
