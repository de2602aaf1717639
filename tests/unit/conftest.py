"""Fixtures shared by the unit tests: the two small CIKF instances of the reference and joint tests."""

from __future__ import annotations

import pytest

from teamkf.study.random_field import random_field


@pytest.fixture(scope="module")
def field12():
    return random_field(12, 12, rng=0)


@pytest.fixture(scope="module")
def field_singular():
    return random_field(15, 6, rng=1)  # G singular (some sites unobserved)
