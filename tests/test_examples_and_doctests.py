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


def test_readme_python_blocks_run(tmp_path, monkeypatch, capsys):
    """Every ```python block of the README, in order, in one namespace (as a reader would paste them)."""
    import re

    text = (Path(__file__).parent.parent / "README.md").read_text(encoding="utf-8")
    blocks = re.findall(r"```python\n(.*?)```", text, re.S)
    assert len(blocks) >= 3
    monkeypatch.chdir(tmp_path)
    namespace: dict = {}
    for block in blocks:
        exec(compile(block, "README.md", "exec"), namespace)
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
