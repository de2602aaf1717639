"""The estimator-family registry: one :class:`Family` record per family, and nothing else lists them.

Scenario files, ``teamkf evaluate/design/sweep``, Monte Carlo, the runtime and
the documentation read this registry. teamkf's own families register when
:mod:`teamkf.estimators` is imported; a user's family registers with
:func:`register_family` (in Python) or through the entry-point group
``teamkf.families`` (an installed package), and then works everywhere a
built-in family does.

Every family's design function has the signature::

    design_X(system, cost, graph_or_structure, horizon=None, **options) -> Design

where the third argument is what :attr:`Family.uses` says: the scenario's
information structure (``"structure"``), its communication graph
(``"graph"``), or nothing (``"none"``, the centralized bound).

Examples
--------
>>> import teamkf
>>> {"centralized", "mtmse", "mmse", "kcf", "cikf"} <= set(teamkf.families())
True
>>> teamkf.get_family("mtmse").analytic_cost
True
"""

from __future__ import annotations

import difflib
import warnings
from dataclasses import dataclass, field
from typing import Any, Callable, Literal, Mapping

from .. import _validation as V
from ..exceptions import ArgumentError, GraphError, TeamkfError

__all__ = ["Family", "Option", "register_family", "unregister_family", "families", "get_family", "load_plugin", "ENTRY_POINT_GROUP", "PLUGINS_ENV"]

#: environment variable with plugin modules or files to load (separated by os.pathsep), as ``teamkf --plugin``
PLUGINS_ENV = "TEAMKF_PLUGINS"

#: the entry-point group through which installed packages add families
ENTRY_POINT_GROUP = "teamkf.families"

Uses = Literal["structure", "graph", "none"]
Horizon = Literal["finite", "infinite"]


@dataclass(frozen=True, kw_only=True)
class Option:
    """One option of a family's scenario table (``[kcf] epsilon = 0.1``) and keyword of its design function.

    Attributes
    ----------
    name : str
    default : object
        The value used when the scenario does not give one.
    check : callable (value, key) -> value
        Validates and normalizes a value; raises a :class:`~teamkf.exceptions.TeamkfError`
        naming ``key`` (the key path in the scenario, e.g. ``"kcf.epsilon"``).
    doc : str
        One line for the documentation and error messages.
    choices : tuple
        The allowed values when the option is a choice (``variant``: every variant of the
        family; the property tests run each of them); empty otherwise.
    """

    name: str
    default: Any
    check: Callable[[Any, str], Any]
    doc: str = ""
    choices: tuple[Any, ...] = ()


@dataclass(frozen=True, kw_only=True)
class Family:
    """The registry record of an estimator family.

    Attributes
    ----------
    name : str
        Registry name used in scenario files (``estimators = [...]``) and on the CLI.
    design : callable
        ``design(system, cost, graph_or_structure, horizon, **options) -> Design``.
    title : str
        One line: what the family is, with its reference.
    uses : "structure", "graph" or "none"
        What the design function takes as its third argument.
    options : tuple of Option
        The keys of the family's scenario table ``[name]`` (and design keywords).
    horizons : frozenset of "finite", "infinite"
        Horizons the family can design for.
    analytic_cost : bool
        True when designs carry the exact team cost; False: Monte Carlo.
    unit_delays : bool
        The family exchanges once per step over edges of delay 1 (CIKF).
    strongly_connected : bool
        The family needs a strongly connected graph.
    example : str
        A short Python example (README, docs, ``teamkf --help``).
    """

    name: str
    design: Callable[..., Any]
    title: str
    uses: Uses = "structure"
    options: tuple[Option, ...] = ()
    horizons: frozenset[Horizon] = field(default_factory=lambda: frozenset({"finite", "infinite"}))
    analytic_cost: bool = True
    unit_delays: bool = False
    strongly_connected: bool = False
    example: str = ""

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name.isidentifier() or self.name != self.name.lower():
            raise ArgumentError(f"name: expected a lower-case identifier such as 'my_filter', found {self.name!r}", argument="name")
        if not callable(self.design):
            raise ArgumentError(f"design: expected a design function, found {type(self.design).__name__}", argument="design")
        V.choice(self.uses, "uses", ("structure", "graph", "none"))
        hz = frozenset(self.horizons)
        if not hz or not hz <= {"finite", "infinite"}:
            raise ArgumentError(f"horizons: expected a non-empty subset of {{'finite', 'infinite'}}, found {set(self.horizons)}", argument="horizons")
        object.__setattr__(self, "horizons", hz)
        object.__setattr__(self, "options", tuple(self.options))
        for o in self.options:
            if not isinstance(o, Option):
                raise ArgumentError(f"options: expected Option records, found {type(o).__name__}", argument="options")

    def __repr__(self) -> str:
        cost = "analytic" if self.analytic_cost else "monte-carlo"
        opts = ", ".join(self.option_names)
        return f"Family({self.name!r}, uses={self.uses!r}, horizons={sorted(self.horizons)}, cost={cost!r}, options=[{opts}])"

    # --- checks ---------------------------------------------------------------------
    @property
    def option_names(self) -> tuple[str, ...]:
        return tuple(o.name for o in self.options)

    @property
    def variants(self) -> tuple[str, ...]:
        """Every value of the family's ``variant`` option (its ``choices``), or ``()`` for a family without variants."""
        for o in self.options:
            if o.name == "variant":
                return tuple(o.choices) if o.choices else (o.default,)
        return ()

    def check_options(self, table: Any, prefix: str | None = None) -> dict[str, Any]:
        """Validate an options table (from a scenario or keywords): known keys, checked values, defaults filled."""
        key = self.name if prefix is None else prefix
        if table is None:
            table = {}
        if not isinstance(table, Mapping):
            raise ArgumentError(
                f"{key}: expected a table of options ({', '.join(self.option_names) or 'none'}), found {V.describe(table)}", argument=key
            )
        out: dict[str, Any] = {}
        known = {o.name: o for o in self.options}
        for k in table:
            if k not in known:
                close = difflib.get_close_matches(str(k), list(known), n=1, cutoff=0.6)
                hint = f"did you mean {close[0]!r}? " if close else ""
                allowed = ", ".join(known) if known else "none (this family has no options)"
                raise ArgumentError(f"{key}.{k}: unknown option of the {self.name!r} family; {hint}expected one of: {allowed}", argument=f"{key}.{k}")
        for name, o in known.items():
            out[name] = o.check(table[name], f"{key}.{name}") if name in table else o.default
        return out

    def check_horizon(self, horizon: int | None, key: str = "horizon") -> None:
        """Raise when the family cannot design for this horizon."""
        want: Horizon = "finite" if horizon is not None else "infinite"
        if want not in self.horizons:
            fix = "give horizon = T" if want == "infinite" else "omit horizon for the steady-state design"
            raise ArgumentError(f"{key}: the {self.name!r} family has no {want}-horizon design; {fix}", argument=key)

    def check_graph(self, graph: Any, key: str = "graph") -> None:
        """Raise when the graph does not meet the family's requirements."""
        if self.unit_delays:
            slow = [(i, j, d) for (i, j, d) in graph.edges if d != 1]
            if slow:
                raise GraphError(
                    f"{key}: the {self.name!r} family exchanges once per step and needs every edge to have delay 1, "
                    f"found {len(slow)} edges with other delays, e.g. {list(slow[0])}; set the delays to 1",
                    argument=key,
                )
        if self.strongly_connected:
            graph.require_strongly_connected(key)

    def build(self, system: Any, cost: Any, *, graph: Any, structure: Any, horizon: int | None, options: Mapping[str, Any] | None = None) -> Any:
        """Design this family for a scenario's pieces (the third argument chosen by :attr:`uses`)."""
        self.check_horizon(horizon)
        if self.uses != "none":
            self.check_graph(graph)
        third = {"structure": structure, "graph": graph, "none": None}[self.uses]
        opts = self.check_options(options or {})
        return self.design(system, cost, third, horizon, **opts)

    def describe(self) -> dict[str, Any]:
        """Plain data for listings (``teamkf families``, the docs)."""
        return {
            "name": self.name,
            "title": self.title,
            "uses": self.uses,
            "horizons": sorted(self.horizons),
            "cost": "analytic" if self.analytic_cost else "monte-carlo",
            "unit_delays": self.unit_delays,
            "options": {o.name: {"default": o.default, "doc": o.doc, **({"choices": list(o.choices)} if o.choices else {})} for o in self.options},
        }


# ---------------------------------------------------------------------------
# the registry
# ---------------------------------------------------------------------------
_REGISTRY: dict[str, Family] = {}
_BUILTINS_LOADED = False
_ENTRY_POINTS_LOADED = False


def register_family(family: Family | None = None, /, *, replace: bool = False, **fields: Any) -> Family:
    """Add an estimator family to the registry; returns its record.

    Call it with a :class:`Family`, or with the fields of one::

        teamkf.register_family(name="avg", design=design_avg, title="...", uses="graph",
                               horizons={"finite"})

    ``replace=True`` replaces a family of the same name (a built-in one too).
    """
    if family is None:
        family = Family(**fields)
    elif fields:
        raise ArgumentError("register_family: give a Family or its fields, not both", argument="register_family")
    if not isinstance(family, Family):
        raise ArgumentError(f"family: expected a Family record, found {type(family).__name__}", argument="family")
    _load_builtins()
    if family.name in _REGISTRY and not replace and _REGISTRY[family.name] is not family:
        raise ArgumentError(f"name: a family called {family.name!r} is already registered; choose another name or pass replace=True", argument="name")
    _REGISTRY[family.name] = family
    return family


def unregister_family(name: str) -> None:
    """Remove a family from the registry (tests, interactive work)."""
    _REGISTRY.pop(name, None)


def _register_builtin(family: Family) -> Family:
    """Used by teamkf's own family modules at import."""
    _REGISTRY.setdefault(family.name, family)
    return family


def _load_builtins() -> None:
    global _BUILTINS_LOADED
    if not _BUILTINS_LOADED:
        _BUILTINS_LOADED = True
        from . import _builtin  # noqa: F401  (imports every family module, which registers itself)


def _load_entry_points() -> None:
    global _ENTRY_POINTS_LOADED
    if _ENTRY_POINTS_LOADED:
        return
    _ENTRY_POINTS_LOADED = True
    from importlib.metadata import entry_points

    load_env_plugins()
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        try:
            obj = ep.load()
            fam = obj() if callable(obj) and not isinstance(obj, Family) else obj
            if fam.name not in _REGISTRY:
                register_family(fam)
        except (TeamkfError, ImportError, AttributeError, TypeError, ValueError) as exc:
            warnings.warn(f"teamkf: the family entry point {ep.name!r} ({ep.value}) could not be loaded: {exc}", stacklevel=2)


def families() -> dict[str, Family]:
    """Every registered family, name -> record (built-ins first, then entry points and plugins, then user registrations)."""
    _load_builtins()
    _load_entry_points()
    return dict(_REGISTRY)


def get_family(name: Any, key: str = "estimator") -> Family:
    """The family called ``name``; an :class:`~teamkf.exceptions.ArgumentError` naming ``key`` with a did-you-mean hint otherwise."""
    fams = families()
    if isinstance(name, str) and name in fams:
        return fams[name]
    avail = ", ".join(fams)
    if not isinstance(name, str):
        raise ArgumentError(f"{key}: expected an estimator name (a string), found {V.describe(name)}; available: {avail}", argument=key)
    close = difflib.get_close_matches(name, list(fams), n=1)
    hint = f"did you mean {close[0]!r}? " if close else ""
    raise ArgumentError(f"{key}: unknown estimator {name!r}; {hint}available: {avail}", argument=key)


def load_plugin(spec: str) -> Any:
    """Import a module that registers families: a module name (``mypkg.filters``) or a ``.py`` file path.

    A file is imported under the name ``teamkf_plugin_<stem>`` and, when
    cloudpickle is installed (it comes with Dask), its functions are pickled by
    value, so that the families it registers also run on Dask workers.
    Returns the module.
    """
    import importlib
    import importlib.util
    import sys
    from pathlib import Path

    if not isinstance(spec, str) or not spec:
        raise ArgumentError(f"plugin: expected a module name or a .py file, found {V.describe(spec)}", argument="plugin")
    path = Path(spec)
    if spec.endswith(".py") or path.exists():
        if not path.is_file():
            raise ArgumentError(f"plugin: no such file {spec!r}; give a .py file or an importable module name", argument="plugin")
        name = f"teamkf_plugin_{path.stem}"
        if name in sys.modules:
            return sys.modules[name]
        loader_spec = importlib.util.spec_from_file_location(name, path)
        if loader_spec is None or loader_spec.loader is None:
            raise ArgumentError(f"plugin: cannot import {spec!r} as a Python module", argument="plugin")
        module = importlib.util.module_from_spec(loader_spec)
        sys.modules[name] = module
        try:
            loader_spec.loader.exec_module(module)
        except BaseException:
            sys.modules.pop(name, None)
            raise
        try:
            import cloudpickle

            cloudpickle.register_pickle_by_value(module)
        except (ImportError, ValueError):  # no cloudpickle: in-process runs only
            pass
        return module
    try:
        return importlib.import_module(spec)
    except ImportError as exc:
        raise ArgumentError(f"plugin: cannot import module {spec!r} ({exc}); check the name or give a .py file", argument="plugin") from None


def load_env_plugins() -> None:
    """Load the plugins named in the ``TEAMKF_PLUGINS`` environment variable (once per process)."""
    import os

    for spec in filter(None, os.environ.get(PLUGINS_ENV, "").split(os.pathsep)):
        load_plugin(spec)
