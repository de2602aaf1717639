"""Reproductions of the papers' figures and tables: marked ``slow`` (``make test`` still runs them)."""

import pytest


def pytest_collection_modifyitems(items):
    for item in items:
        if "tests/reproduction/" in str(item.fspath).replace("\\", "/"):
            item.add_marker(pytest.mark.slow)
