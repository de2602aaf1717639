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

import warnings
from dataclasses import dataclass, field
from typing import Any, Callable, Literal, Mapping, Sequence

from ..exceptions import ArgumentError, GraphError, TeamkfError

__all__ = [
    "Family",
    "Option",
    "register_family",
    "unregister_family",
    "families",
    "get_family",
    "family_listing",
    "load_plugin",
    "plugin_identities",
    "ENTRY_POINT_GROUP",
    "PLUGINS_ENV",
]

#: environment variable with plugin modules or files to load (separated by os.pathsep), as ``teamkf --plugin``
PLUGINS_ENV = "TEAMKF_PLUGINS"

#: the entry-point group through which installed packages add families
ENTRY_POINT_GROUP = "teamkf.families"

Uses = Literal["structure", "graph", "none"]
Horizon = Literal["finite", "infinite"]


@dataclass(frozen=True, kw_only=True)
class Option:
    """One option of a family's scenario table (``[kcf] epsilon = 0.1``) and keyword of its design function.

    Parameters
    ----------
    name : str
        The key in the scenario table and the keyword of the design function.
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

    See Also
    --------
    Family : the record that lists a family's options.

    Examples
    --------
    >>> from teamkf import Option
    >>> def positive(value, key):
    ...     if value <= 0:
    ...         raise ValueError(f"{key}: expected a positive number, found {value}")
    ...     return float(value)
    >>> step = Option(name="step", default=0.5, check=positive, doc="the step size")
    >>> step.check(2, "avg.step")
    2.0
    """

    name: str
    default: Any
    check: Callable[[Any, str], Any]
    doc: str = ""
    choices: tuple[Any, ...] = ()

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name.isidentifier():
            raise ArgumentError(f"name: expected an option name (an identifier such as 'epsilon'), found {self.name!r}", argument="name")
        if not callable(self.check):
            raise ArgumentError(
                f"check: expected a function (value, key) -> value that validates option {self.name!r}, found {type(self.check).__name__}",
                argument="check",
            )
        if not isinstance(self.doc, str):
            raise ArgumentError(f"doc: expected a string, found {type(self.doc).__name__}", argument="doc")


#: names a family cannot take: the sections of a scenario file ([system], [graph], ...), whose tables a family's options would shadow
RESERVED_NAMES = (
    "name", "horizon", "description", "system", "agents", "graph", "cost", "information", "estimators", "control", "network", "population",
)  # fmt: skip


@dataclass(frozen=True, kw_only=True)
class Family:
    """The registry record of an estimator family.

    Parameters
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
    lossy_links : bool
        Capability: its agents run over links that drop, jitter or fail (each says what a missing message
        means: a tolerant step). A family without it is refused, in one line, by any command that simulates
        it over unreliable links.
    missing_data : bool
        Capability: its designs filter recorded measurements with gaps (NaN or absent rows: ``teamkf filter``).
    steady_form : bool
        Capability: its infinite-horizon designs have a time-invariant form (``Design.steady_form()``) that
        ``teamkf filter`` streams through a file of any length.
    example : str
        A short Python example (README, docs, ``teamkf --help``).

    See Also
    --------
    register_family : add a family to the registry.
    families : every registered family.

    Examples
    --------
    >>> import teamkf
    >>> fam = teamkf.get_family("kcf")
    >>> fam.uses, fam.analytic_cost, fam.option_names
    ('graph', True, ('epsilon', 'variant'))
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
    lossy_links: bool = False
    missing_data: bool = False
    steady_form: bool = False
    example: str = ""

    #: the capability fields, in the order :attr:`capabilities` lists them
    CAPABILITIES = ("analytic_cost", "lossy_links", "missing_data", "steady_form")

    def __post_init__(self) -> None:
        from .. import _validation as V  # imported here: listing the families (teamkf --help) needs no numpy

        if not isinstance(self.name, str) or not self.name.isidentifier() or self.name != self.name.lower():
            raise ArgumentError(f"name: expected a lower-case identifier such as 'my_filter', found {self.name!r}", argument="name")
        if self.name in RESERVED_NAMES:
            raise ArgumentError(
                f"name: expected a family name that is not a scenario section, found {self.name!r} "
                f"(reserved: {', '.join(RESERVED_NAMES)}); a [{self.name}] table would be ambiguous: choose another name",
                argument="name",
            )
        if not callable(self.design):
            raise ArgumentError(f"design: expected a design function, found {type(self.design).__name__}", argument="design")
        V.choice(self.uses, "uses", ("structure", "graph", "none"))
        hz = frozenset(self.horizons)
        if not hz or not hz <= {"finite", "infinite"}:
            raise ArgumentError(f"horizons: expected a non-empty subset of {{'finite', 'infinite'}}, found {set(self.horizons)}", argument="horizons")
        object.__setattr__(self, "horizons", hz)
        object.__setattr__(self, "options", tuple(self.options))
        for flag in ("analytic_cost", "unit_delays", "strongly_connected", *self.CAPABILITIES):
            if not isinstance(getattr(self, flag), bool):
                raise ArgumentError(f"{flag}: expected True or False, found {V.describe(getattr(self, flag))}", argument=flag)
        for o in self.options:
            if not isinstance(o, Option):
                raise ArgumentError(f"options: expected Option records, found {type(o).__name__}", argument="options")

    def __repr__(self) -> str:
        cost = "analytic" if self.analytic_cost else "monte-carlo"
        opts = ", ".join(self.option_names)
        return f"Family({self.name!r}, uses={self.uses!r}, horizons={sorted(self.horizons)}, cost={cost!r}, options=[{opts}])"

    @property
    def capabilities(self) -> tuple[str, ...]:
        """The capabilities the record declares, e.g. ``("analytic_cost", "lossy_links")``."""
        return tuple(c for c in self.CAPABILITIES if getattr(self, c))

    def require(self, capability: str, what: str) -> None:
        """Raise :class:`~teamkf.exceptions.UnsupportedOperationError` (one line) unless the family declares ``capability``."""
        from ..exceptions import UnsupportedOperationError

        if capability not in self.CAPABILITIES:
            raise ArgumentError(f"capability: expected one of {', '.join(self.CAPABILITIES)}, found {capability!r}", argument="capability")
        if not getattr(self, capability):
            raise UnsupportedOperationError(
                self.name, what, f"its registry record does not declare {capability}=True (declared: {', '.join(self.capabilities) or 'none'})"
            )

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
        import difflib

        from .. import _validation as V

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
        if isinstance(horizon, int) and horizon > 10**5 and getattr(self.design, "__module__", "").startswith("teamkf."):
            from .._budget import DESIGN_STEP_LOOPS, check_steps

            check_steps(horizon, what=f"the {self.name} design", per_step=DESIGN_STEP_LOOPS)  # teamkf's designs step through T in Python
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
            "capabilities": list(self.capabilities),
            "options": {o.name: {"default": o.default, "doc": o.doc, **({"choices": list(o.choices)} if o.choices else {})} for o in self.options},
        }


# ---------------------------------------------------------------------------
# the registry
# ---------------------------------------------------------------------------
_REGISTRY: dict[str, Family] = {}
#: other accepted spellings of a family's name (``"mtmse-lossy"`` for ``mtmse_lossy``): alias -> name
_ALIASES: dict[str, str] = {}
_BUILTINS_LOADED = False
_ENTRY_POINTS_LOADED = False


def register_family(family: Family | None = None, /, *, replace: bool = False, **fields: Any) -> Family:
    """Add an estimator family to the registry; returns its record.

    Call it with a :class:`Family`, or with the fields of one. The family then
    works in scenario files, every ``teamkf`` command, Monte Carlo, sweeps and
    the runtime, as a built-in one does.

    Parameters
    ----------
    family : Family, optional
        The record to register; leave it out and give its fields as keywords instead.
    replace : bool, default False
        Replace a family of the same name (a built-in one too); otherwise that is an error.
    **fields
        The fields of a :class:`Family` (``name``, ``design``, ``title``, ``uses``, ...),
        when ``family`` is not given.

    Returns
    -------
    Family
        The registered record.

    Raises
    ------
    ArgumentError
        When the name is taken (and ``replace`` is False), or both a record and fields are given.

    See Also
    --------
    unregister_family, families, get_family

    Examples
    --------
    >>> import teamkf
    >>> def design_avg(system, cost, graph, horizon=None):
    ...     return teamkf.design_local(system, cost, graph, horizon)
    >>> fam = teamkf.register_family(name="avg", design=design_avg, title="my filter", uses="graph")
    >>> "avg" in teamkf.families()
    True
    >>> teamkf.unregister_family("avg")
    """
    if family is None:
        family = Family(**fields)
    elif fields:
        raise ArgumentError("register_family: give a Family or its fields, not both", argument="register_family")
    if not isinstance(family, Family):
        raise ArgumentError(f"family: expected a Family record, found {type(family).__name__}", argument="family")
    _load_builtins()
    if family.name in _REGISTRY and not replace and _REGISTRY[family.name] is not family:
        held, new = _REGISTRY[family.name], _origin(family)
        by = f" by {_origin(held)}" if _origin(held) != new else ""
        where = f" on {_WHERE[0]}" if _WHERE[0] else ""
        fix = (
            "give the family another name, or restart that cluster's workers (client.restart()) to forget the other plug-in"
            if where
            else "choose another name, unregister the other one first (teamkf.unregister_family), or pass replace=True"
        )
        raise ArgumentError(
            f"name: a family called {family.name!r} is already registered{by}{where}; {new} registers it again: {fix}", argument="name"
        )
    _REGISTRY[family.name] = family
    return family


#: where this process is, for messages (set on a Dask worker while it loads plug-ins: "the Dask worker ADDRESS of the cluster at ADDRESS")
_WHERE = [""]


def plugin_of(module: str) -> str | None:
    """The file (or module name) of the loaded plug-in that defines ``module``, or None for teamkf's own code and the rest."""
    for name, path, _ in _PLUGINS:
        if module == name or module.startswith(name + "."):
            return path or name
    return None


def _origin(family: Family) -> str:
    """``plug-in FILE (sha256 0123456789ab)``, ``module M`` or ``Python code``: where a family's record comes from."""
    mod = getattr(family.design, "__module__", "") or ""
    for name, path, _ in _PLUGINS:
        if mod == name or mod.startswith(name + "."):
            return f"plug-in {path or name} (sha256 {_HASHES.get(name, '?')[:12]})"
    if mod.startswith("teamkf."):
        return f"teamkf's module {mod}"
    return f"module {mod}" if mod and mod != "__main__" else "Python code (register_family)"


def unregister_family(name: str) -> None:
    """Remove a family from the registry (tests, interactive work).

    Parameters
    ----------
    name : str
        The family's registry name; a name that is not registered is ignored.

    See Also
    --------
    register_family

    Examples
    --------
    >>> import teamkf
    >>> teamkf.unregister_family("no-such-family")
    >>> "mtmse" in teamkf.families()
    True
    """
    if not isinstance(name, str):
        raise ArgumentError(
            f"name: expected a family name (a string), found {type(name).__name__}; e.g. unregister_family('my_filter')", argument="name"
        )
    _REGISTRY.pop(name, None)


def _register_builtin(family: Family) -> Family:
    """Used by teamkf's own family modules at import; the record must match its declaration in :mod:`._builtin`."""
    from ._builtin import check_declared

    check_declared(family)
    _REGISTRY.setdefault(family.name, family)
    return family


def _load_builtins() -> None:
    global _BUILTINS_LOADED
    if not _BUILTINS_LOADED:
        _BUILTINS_LOADED = True
        from . import _builtin

        _builtin.load()  # imports every family module, which registers itself
        # the built-in families in the order of their modules (whatever was imported first), then every other
        order = [f"{__package__}.{m}" for m in _builtin.MODULES]

        def rank(fam: Family) -> int:
            mod = getattr(fam.design, "__module__", "") or ""
            return next((k for k, m in enumerate(order) if mod == m or mod.startswith(m + ".")), len(order))

        records = sorted(_REGISTRY.values(), key=rank)  # stable: registration order within a module
        _REGISTRY.clear()
        _REGISTRY.update({f.name: f for f in records})


def _load_entry_points() -> None:
    global _ENTRY_POINTS_LOADED
    if _ENTRY_POINTS_LOADED:
        return
    _ENTRY_POINTS_LOADED = True
    from importlib.metadata import entry_points

    load_env_plugins()
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        _load_builtins()  # an installed family never shadows a built-in one
        try:
            obj = ep.load()
            fam = obj() if callable(obj) and not isinstance(obj, Family) else obj
            if fam.name not in _REGISTRY:
                register_family(fam)
        except (TeamkfError, ImportError, AttributeError, TypeError, ValueError) as exc:
            warnings.warn(f"teamkf: the family entry point {ep.name!r} ({ep.value}) could not be loaded: {exc}", stacklevel=2)


def register_alias(alias: str, name: str) -> None:
    """Accept ``alias`` wherever the family ``name`` is named (scenario files, the CLI, :func:`get_family`)."""
    if not isinstance(alias, str) or not alias or not isinstance(name, str):
        raise ArgumentError(f"alias: expected two names, found {alias!r} -> {name!r}", argument="alias")
    _ALIASES[alias] = name


def families() -> dict[str, Family]:
    """Every registered family, name -> record.

    Built-in families come first, then those of installed packages (the
    ``teamkf.families`` entry points) and of ``TEAMKF_PLUGINS``, then the
    user's :func:`register_family` calls.

    Returns
    -------
    dict of str to Family
        A new dictionary: changing it leaves the registry as it is.

    Examples
    --------
    >>> import teamkf
    >>> list(teamkf.families())[:5]
    ['centralized', 'mtmse', 'mmse', 'kcf', 'cikf']
    """
    _load_builtins()
    _load_entry_points()
    return dict(_REGISTRY)


def family_listing() -> dict[str, Any]:
    """Every registered family as plain data, name -> :class:`~teamkf.estimators._builtin.Declared`, in the order of :func:`families`.

    What ``teamkf --help`` prints. Until a family record is asked for, the built-in families come from
    their declarations (:data:`teamkf.estimators._builtin.DECLARED`) and no family module is imported;
    the plug-ins (``TEAMKF_PLUGINS``, entry points, ``register_family``) are loaded and listed as
    :func:`families` lists them.

    Returns
    -------
    dict of str to Declared
        ``(name, module, title, analytic_cost, capabilities, example)`` of each family.

    Examples
    --------
    >>> from teamkf.estimators.registry import families, family_listing
    >>> list(family_listing()) == list(families())
    True
    """
    from ._builtin import DECLARED, declaration_of

    _load_entry_points()  # a plug-in registers through register_family, which loads the built-in modules first
    if _BUILTINS_LOADED:
        return {name: declaration_of(fam) for name, fam in families().items()}
    return {d.name: d for d in DECLARED}


def get_family(name: Any, key: str = "estimator") -> Family:
    """The registry record of the family called ``name``.

    Parameters
    ----------
    name : str
        The registry name (``"mtmse"``, ``"kcf"``, ...).
    key : str, default "estimator"
        The argument or scenario key that gave the name, for the error message.

    Returns
    -------
    Family
        The record.

    Raises
    ------
    ArgumentError
        When no family has that name; the message names ``key``, the families
        available and the closest name.

    Examples
    --------
    >>> import teamkf
    >>> teamkf.get_family("mtmse").title.startswith("minimum team MSE")
    True
    >>> teamkf.get_family("mtmes")
    Traceback (most recent call last):
    ...
    teamkf.exceptions.ArgumentError: estimator: unknown estimator 'mtmes'; did you mean 'mtmse'? available: ...
    """
    import difflib

    from .. import _validation as V

    fams = families()
    if isinstance(name, str) and name in fams:
        return fams[name]
    if isinstance(name, str) and _ALIASES.get(name) in fams:
        return fams[_ALIASES[name]]
    avail = ", ".join(fams)
    if not isinstance(name, str):
        raise ArgumentError(f"{key}: expected an estimator name (a string), found {V.describe(name)}; available: {avail}", argument=key)
    close = difflib.get_close_matches(name, list(fams), n=1)
    hint = f"did you mean {close[0]!r}? " if close else ""
    raise ArgumentError(
        f"{key}: unknown estimator {name!r}; {hint}available: {avail}; a family of your own registers with --plugin FILE.py, "
        "the TEAMKF_PLUGINS variable, the 'teamkf.families' entry point or teamkf.register_family (docs: plugins.html)",
        argument=key,
    )


#: the plug-ins this process loaded, in order: (module name, file path or None, source text or None)
_PLUGINS: list[tuple[str, str | None, str | None]] = []
#: module name -> sha256 (hex) of each loaded plug-in's source: its identity, with the name
_HASHES: dict[str, str] = {}


def _sha256(data: str | bytes) -> str:
    import hashlib

    return hashlib.sha256(data.encode("utf-8") if isinstance(data, str) else data).hexdigest()


def _module_hash(module: Any) -> str:
    """sha256 of an imported plug-in module's source file(s): every ``.py`` of a package, in path order; "" when it has none."""
    from pathlib import Path

    files: list[Path] = []
    for root in getattr(module, "__path__", None) or ():
        files.extend(sorted(Path(root).rglob("*.py")))
    if not files and getattr(module, "__file__", None):
        files = [Path(module.__file__)]
    if not files:
        return ""
    import hashlib

    h = hashlib.sha256()
    for f in files:
        try:
            h.update(f.name.encode() + b"\0" + f.read_bytes())
        except OSError:
            return ""
    return h.hexdigest()


def plugin_identities() -> dict[str, str]:
    """The identity of every plug-in loaded in this process: module name -> sha256 of its source.

    A ``.py`` plug-in is hashed from the source it was loaded from; an importable module from its file
    (a package: every ``.py`` file in it). teamkf sends the identities with every Dask task: a worker that
    holds another version of a plug-in is updated from the shipped source, or the task is refused in one
    line naming the worker, the scheduler and both hashes, never run with the stale version.

    Returns
    -------
    dict of str to str
        ``{module name: sha256 hex digest}``, in loading order ("" for a module without a source file).

    Examples
    --------
    >>> import teamkf
    >>> from teamkf.estimators.registry import plugin_identities
    >>> all(len(h) in (0, 64) for h in plugin_identities().values())
    True
    """
    return {name: _HASHES.get(name, "") for name, _, _ in _PLUGINS}


def loaded_plugins() -> tuple[tuple[str, str | None, str | None], ...]:
    """The plug-ins loaded in this process, in the order they were loaded.

    A Dask worker, a process pool or an agent process loads the same plug-ins with :func:`load_plugins_into`
    before it unpickles a design of a plug-in family (:mod:`teamkf.simulation.parallel` does it for every Dask
    client teamkf opens); a file's source travels with it, so the workers need not see the file.

    Returns
    -------
    tuple of (str, str or None, str or None)
        ``(module name, file path or None, source text or None)`` per plug-in (path and source for a ``.py``
        file, None for an importable module).

    Examples
    --------
    >>> import teamkf
    >>> all(len(p) == 3 for p in teamkf.loaded_plugins())
    True
    """
    return tuple(_PLUGINS)


def load_plugins_into(plugins: Sequence[tuple[str, str | None, str | None]], identities: Mapping[str, str] | None = None, where: str = "") -> None:
    """Load ``plugins`` (from :func:`loaded_plugins` of another process) here, under the same module names.

    A plug-in already loaded here with the same source is kept; one loaded with another source (the file was
    edited since) is replaced: its families are unregistered, the shipped source runs in its place. An
    importable module cannot be shipped: when its file here hashes otherwise than ``identities`` says, the
    load is refused. ``where`` (e.g. ``"the Dask worker tcp://... of the cluster at tcp://..."``) goes into every message.
    """
    import sys

    _WHERE[0] = where
    try:
        for name, path, source in plugins:
            if source is None:
                if name not in sys.modules:
                    load_plugin(name)
                elif name not in _HASHES:  # imported here before (a preload): its identity is its file here
                    _PLUGINS.append((name, None, None))
                    _HASHES[name] = _module_hash(sys.modules[name])
            elif name not in sys.modules or _HASHES.get(name) != _sha256(source):
                _replace_plugin(name, path or f"<plugin {name}>", source)
        if identities is not None:
            check_plugin_identities(identities, where)
    finally:
        _WHERE[0] = ""


def check_plugin_identities(identities: Mapping[str, str], where: str = "") -> None:
    """Refuse (one :class:`~teamkf.exceptions.ArgumentError`) unless this process holds exactly these plug-in versions.

    Parameters
    ----------
    identities : mapping of str to str
        ``{module name: sha256}`` of the driver (:func:`plugin_identities`).
    where : str
        Where this process is, for the message (``"the Dask worker ADDRESS of the cluster at ADDRESS"``).
    """
    import sys

    for name, want in identities.items():
        held = _HASHES.get(name) if name in sys.modules else None
        if held == want:
            continue
        path = next((p for n, p, _ in _PLUGINS if n == name and p), name)
        if held is None:
            found = f"holds no plug-in {name!r}"
            fix = "rerun; if it persists, restart the workers (client.restart())"
        else:
            found = f"holds plug-in {path} with sha256 {held[:12]}"
            fix = (
                "install the same version of the module on every worker"
                if not any(n == name and src for n, _, src in _PLUGINS)
                else "another run loaded another version there meanwhile; rerun when it is done, or use a cluster of your own"
            )
        raise ArgumentError(
            f"plugin: {where or 'this process'} {found}, this run's {name!r} has sha256 {want[:12]}; teamkf never runs a stale plug-in: {fix}",
            argument="plugin",
        )


def _unload_plugin(name: str) -> list[Family]:
    """Forget the plug-in module ``name``: its families leave the registry (returned), it leaves sys.modules."""
    import sys

    gone = [f for f in _REGISTRY.values() if _is_from(f, name)]
    for f in gone:
        _REGISTRY.pop(f.name, None)
    sys.modules.pop(name, None)
    _PLUGINS[:] = [p for p in _PLUGINS if p[0] != name]
    _HASHES.pop(name, None)
    return gone


def _is_from(family: Family, name: str) -> bool:
    mod = getattr(family.design, "__module__", "") or ""
    return mod == name or mod.startswith(name + ".")


def _replace_plugin(name: str, path: str, source: str) -> Any:
    """Run ``source`` as plug-in ``name``, in place of the version loaded now (if any); the old one is restored if the new one fails."""
    import sys

    old_module, old_entry = sys.modules.get(name), [p for p in _PLUGINS if p[0] == name]
    old_hash = _HASHES.get(name)
    gone = _unload_plugin(name) if old_module is not None else []
    try:
        return _exec_plugin(name, path, source)
    except BaseException:
        if old_module is not None:
            sys.modules[name] = old_module
            _PLUGINS.extend(old_entry)
            if old_hash is not None:
                _HASHES[name] = old_hash
            for f in gone:
                _REGISTRY.setdefault(f.name, f)
        raise


def _plugin_error(spec: str, what: str, exc: BaseException) -> ArgumentError:
    text = " ".join(str(exc).split()) or type(exc).__name__
    return ArgumentError(
        f"plugin: {spec!r} raised {type(exc).__name__} while {what}: {text}; fix the plug-in or drop it (--debug shows the traceback)",
        argument="plugin",
    )


def _exec_plugin(name: str, path: str, source: str) -> Any:
    import sys
    import types

    module = types.ModuleType(name)
    module.__file__ = path
    sys.modules[name] = module
    _HASHES[name] = _sha256(source)  # known while it registers its families (messages name it)
    _PLUGINS.append((name, path, source))
    try:
        exec(compile(source, path, "exec"), module.__dict__)
    except BaseException as exc:
        for fam in [f for f in _REGISTRY.values() if _is_from(f, name)]:  # what it registered before it failed
            _REGISTRY.pop(fam.name, None)
        sys.modules.pop(name, None)
        _PLUGINS[:] = [p for p in _PLUGINS if p[0] != name]
        _HASHES.pop(name, None)
        if isinstance(exc, (KeyboardInterrupt, TeamkfError)):
            raise
        raise _plugin_error(path, "importing", exc) from exc  # SystemExit too: a plug-in's sys.exit() must not end teamkf silently
    try:
        import cloudpickle

        cloudpickle.register_pickle_by_value(module)
    except (ImportError, ValueError):  # no cloudpickle: the workers load the plug-in themselves
        pass
    return module


def load_plugin(spec: str) -> Any:
    """Import a module that registers families: a module name (``mypkg.filters``) or a ``.py`` file path.

    A file is imported under the name ``teamkf_plugin_<stem>``; its source and its sha256 are remembered
    (:func:`loaded_plugins`, :func:`plugin_identities`) so that Dask workers load the same version. Loading
    a file again after it was edited replaces the old version (its families are re-registered from the new
    source). An exception while importing it becomes one :class:`~teamkf.exceptions.ArgumentError` naming
    the plug-in (the original is chained).

    Parameters
    ----------
    spec : str
        A ``.py`` file path or an importable module name; loading the same (unchanged) plug-in twice is a no-op.

    Returns
    -------
    module
        The imported module (its families are registered).

    Examples
    --------
    >>> import teamkf
    >>> teamkf.load_plugin("teamkf.estimators.kcf").__name__
    'teamkf.estimators.kcf'
    """
    import importlib
    import sys
    from pathlib import Path

    from .. import _validation as V

    if not isinstance(spec, str) or not spec:
        raise ArgumentError(f"plugin: expected a module name or a .py file, found {V.describe(spec)}", argument="plugin")
    path = Path(spec)
    if spec.endswith(".py") or path.exists():
        if not path.is_file():
            raise ArgumentError(f"plugin: no such file {spec!r}; give a .py file or an importable module name", argument="plugin")
        name = f"teamkf_plugin_{path.stem}"
        try:
            source = path.read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as exc:
            raise ArgumentError(f"plugin: cannot read {spec!r} as UTF-8 Python source ({exc})", argument="plugin") from None
        if name in sys.modules and _HASHES.get(name) == _sha256(source):
            return sys.modules[name]
        held = next((p for n, p, _ in _PLUGINS if n == name), None)
        if name in sys.modules and held is not None and held != str(path.resolve()):
            raise ArgumentError(
                f"plugin: {spec!r} would load as module {name!r}, which plug-in {held} (sha256 {_HASHES.get(name, '?')[:12]}) "
                "already is; rename one of the two files",
                argument="plugin",
            )
        return _replace_plugin(name, str(path.resolve()), source)  # a file edited since it was loaded: the new version replaces it
    if spec in sys.modules:
        if spec not in _HASHES and any(n == spec for n, _, _ in _PLUGINS):
            _HASHES[spec] = _module_hash(sys.modules[spec])
        return sys.modules[spec]
    try:
        module = importlib.import_module(spec)
    except ModuleNotFoundError as exc:
        if exc.name and spec.startswith(exc.name):
            raise ArgumentError(f"plugin: cannot import module {spec!r} ({exc}); check the name or give a .py file", argument="plugin") from None
        raise _plugin_error(spec, "importing", exc) from exc
    except (KeyboardInterrupt, SystemExit, TeamkfError):
        raise
    except BaseException as exc:
        raise _plugin_error(spec, "importing", exc) from exc
    _PLUGINS.append((spec, None, None))
    _HASHES[spec] = _module_hash(module)
    return module


def load_env_plugins() -> None:
    """Load the plugins named in the ``TEAMKF_PLUGINS`` environment variable (once per process)."""
    import os

    for spec in filter(None, os.environ.get(PLUGINS_ENV, "").split(os.pathsep)):
        load_plugin(spec)
