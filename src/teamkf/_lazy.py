"""Attributes of a package imported on first use (PEP 562), so that ``import teamkf`` and ``teamkf --help`` stay fast.

``__getattr__, __dir__ = attach(__name__, {"design_mtmse": ".estimators", ...})`` in a package's
``__init__`` makes ``package.design_mtmse`` import ``package.estimators`` the first time it is used, then
caches it in the package's namespace. The same idea as scientific Python's SPEC 1 (``lazy_loader.attach``).
"""

from __future__ import annotations

import importlib
import sys
from typing import Any, Callable, Mapping


def attach(package: str, names: Mapping[str, str]) -> tuple[Callable[[str], Any], Callable[[], list[str]]]:
    """``(__getattr__, __dir__)`` for ``package``: each of ``names`` comes from its (relative) module on first use."""

    def __getattr__(name: str) -> Any:
        where = names.get(name)
        if where is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(where, package), name)
        setattr(sys.modules[package], name, value)
        return value

    def __dir__() -> list[str]:
        return sorted(set(names) | set(vars(sys.modules[package])))

    return __getattr__, __dir__


class _LazyModule:
    """A stand-in for a module that imports it on first attribute access (``sla.solve`` imports scipy.linalg)."""

    def __init__(self, name: str) -> None:
        self._name = name

    def __getattr__(self, attr: str) -> Any:
        return getattr(importlib.import_module(self._name), attr)

    def __repr__(self) -> str:
        return f"<lazy module {self._name!r}>"


def lazy_module(name: str) -> Any:
    """``name`` imported when first used; for the heavy libraries the family modules need only inside functions."""
    return _LazyModule(name)


#: SciPy and networkx, imported on first use (``teamkf --help`` lists the families without loading them)
scipy_linalg: Any = lazy_module("scipy.linalg")
scipy_optimize: Any = lazy_module("scipy.optimize")
scipy_sparse: Any = lazy_module("scipy.sparse")
scipy_sparse_linalg: Any = lazy_module("scipy.sparse.linalg")
scipy_csgraph: Any = lazy_module("scipy.sparse.csgraph")
networkx: Any = lazy_module("networkx")
