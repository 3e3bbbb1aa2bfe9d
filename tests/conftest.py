"""Shared fixtures: the Mitsuba variant is chosen once per test session."""

import pytest


@pytest.fixture(scope="session")
def variant():
    from renderers.variant import select_variant

    return select_variant()
