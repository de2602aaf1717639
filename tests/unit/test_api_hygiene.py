"""API hygiene: every public name documented, one argument order for every family, one keyword per concept."""

from __future__ import annotations

import importlib
import inspect
import pkgutil

import pytest

import teamkf

PUBLIC = [n for n in teamkf.__all__ if n != "__version__"]


def _modules():
    for info in pkgutil.walk_packages(teamkf.__path__, "teamkf."):
        if info.name.rsplit(".", 1)[-1].startswith("_"):
            continue
        yield importlib.import_module(info.name)


@pytest.mark.parametrize("name", PUBLIC)
def test_public_names_are_documented(name):
    obj = getattr(teamkf, name)
    doc = inspect.getdoc(obj)
    assert doc and len(doc.split()) >= 3, f"teamkf.{name} needs a docstring"


def test_design_contract_methods_are_documented():
    for meth in ("errors", "graph_agents", "filter", "summary", "arrays", "cost_summary", "total_cost", "cost_value", "agents"):
        assert inspect.getdoc(getattr(teamkf.Design, meth)), meth


@pytest.mark.parametrize("name", list(teamkf.families()))
def test_one_argument_order_for_every_family(name):
    """design_X(system, cost, graph_or_structure, horizon=None, *, options)."""
    fam = teamkf.get_family(name)
    params = list(inspect.signature(fam.design).parameters.values())
    assert [p.name for p in params[:2]] == ["system", "cost"], name
    assert params[2].name in ("graph_or_structure", "graph", "structure"), name
    assert params[3].name == "horizon" and params[3].default is None, name
    for opt in fam.options:  # every scenario option is a keyword of the design function
        p = inspect.signature(fam.design).parameters.get(opt.name)
        assert p is not None and p.kind is inspect.Parameter.KEYWORD_ONLY, (name, opt.name)


def test_one_keyword_per_concept():
    """Randomness is ``rng``; counts are ``n_runs`` / ``n_steps`` / ``n_agents`` (never seed=, runs=, T= in a public signature)."""
    offenders = []
    for mod in _modules():
        for fname, fn in inspect.getmembers(mod, inspect.isfunction):
            if fname.startswith("_") or fn.__module__ != mod.__name__:
                continue
            names = set(inspect.signature(fn).parameters)
            for bad in ("random_state", "random_seed", "nruns", "num_runs", "num_steps", "numagents"):
                if bad in names:
                    offenders.append(f"{mod.__name__}.{fname}({bad})")
    assert not offenders, offenders


def test_every_public_module_function_has_a_docstring():
    missing = []
    for mod in _modules():
        for fname, fn in inspect.getmembers(mod, inspect.isfunction):
            if not fname.startswith("_") and fn.__module__ == mod.__name__ and fname in getattr(mod, "__all__", ()):
                if not inspect.getdoc(fn):
                    missing.append(f"{mod.__name__}.{fname}")
    assert not missing, missing
