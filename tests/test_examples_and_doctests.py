"""The examples run, and the docstring examples are correct."""

import doctest
import importlib
import pkgutil
import runpy
from pathlib import Path

import pytest

import teamkf

EXAMPLES = sorted((Path(__file__).parent.parent / "examples").glob("*.py"))


@pytest.mark.parametrize("path", EXAMPLES, ids=lambda p: p.name)
def test_example_runs(path, capsys):
    runpy.run_path(str(path), run_name="__main__")
    assert capsys.readouterr().out.strip()


MODULES = [m.name for m in pkgutil.walk_packages(teamkf.__path__, "teamkf.") if not m.name.endswith("__main__")]


@pytest.mark.parametrize("name", MODULES)
def test_doctests(name):
    mod = importlib.import_module(name)
    res = doctest.testmod(mod, optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    assert res.failed == 0


def test_public_api_is_curated():
    for name in teamkf.__all__:
        assert hasattr(teamkf, name), name
