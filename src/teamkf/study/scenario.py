"""Scenario files: a model, a graph, a cost and the estimators to compare, without Python.

A scenario is a TOML file (or a JSON file with the same keys, recognised by the
``.json`` extension). The keys are a contract (``design/scenario-and-cli.md``):

=================  ============================================================
key                meaning
=================  ============================================================
name               scenario name (default: the file's stem)
horizon            T; omit it for the infinite-horizon (steady-state) design
description        free text (optional)
[system]           ``A``, ``Q``, ``Sigma_x`` (required)
[[agents]]         one table per agent, in agent order: ``C``, ``R``
[graph]            ``edges = [[from, to, delay], ...]`` or
                   ``kind = "complete" | "line" | "ring" | "star"`` with
                   ``delay`` (default 1); ``directed`` (ring), ``center`` (star)
[cost]             ``kind = "average" | "platoon" | "ring" | "mse"`` with
                   ``lambda`` (not for "mse"), or explicit ``S`` and ``L``
[information]      optional reduced structure: ``common_lag`` and ``local``
estimators         names to compare: "mtmse", "mmse", "centralized"
=================  ============================================================

Matrices are nested lists (rows); a covariance written as a number q means
q·I of the right size (also ``S`` when ``L`` fixes the size). Agents are
numbered from 0. Every matrix may be time-varying: a list of matrices indexed
by the step.

Every problem is reported as a :class:`~teamkf.exceptions.ScenarioError`
whose message starts with the key path, e.g.
``agents[2].R: expected a 4x4 symmetric positive definite matrix, found 3x3``.

Examples
--------
>>> from teamkf.study.scenario import load_packaged, set_dotted
>>> sc = load_packaged("platoon-4")
>>> sc.name, sc.horizon, sc.estimators
('platoon-4', 100, ('mtmse', 'mmse', 'centralized'))
>>> sc2 = sc.updated({"cost.lambda": 10.0, "horizon": 20})
>>> round(sc2.design("mtmse").total_cost, 2) <= round(sc2.design("mmse").total_cost, 2)
True
"""

from __future__ import annotations

import copy
import difflib
import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar, Mapping, Sequence

import numpy as np

from .. import _validation as V
from ..estimators.base import Design
from ..exceptions import ArgumentError, ScenarioError, TeamkfError
from ..models import LinearGaussianSystem, TeamCost
from ..network import CommGraph, InformationStructure
from .datafile import check_depth, read_data_file  # noqa: F401  (public here too)
from .dotted import _parse_path, _path_str, set_dotted  # noqa: F401  (set_dotted: public here too)
from .protocol import ScenarioBase

__all__ = [
    "Scenario",
    "load_scenario",
    "scenario_from_dict",
    "set_dotted",
    "packaged_scenarios",
    "load_packaged",
]


_BASE_KEYS = ("name", "horizon", "description", "system", "agents", "graph", "cost", "information", "estimators", "control", "network")
_SYSTEM_KEYS = ("A", "Q", "Sigma_x")
_AGENT_KEYS = ("C", "R")
#: optional known means (prior mean, inputs, offsets), read by teamkf.study.measurements.known_inputs
_SYSTEM_OPTIONAL = ("x0_mean", "B", "u", "b")
_AGENT_OPTIONAL = ("D", "d")
_GRAPH_KINDS = ("complete", "line", "ring", "star")
_COST_KINDS = ("average", "platoon", "ring", "mse")
_INFO_KEYS = ("common_lag", "local")


def _fail(key: str, message: str) -> ScenarioError:
    err = ScenarioError(f"{key}: {message}")
    err.key = key  # type: ignore[attr-defined]
    return err


# ---------------------------------------------------------------------------
# the scenario
# ---------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class Scenario(ScenarioBase):
    """A validated team scenario (kind ``"team"``): everything needed to design and compare estimators.

    Read one with :func:`~teamkf.load_scenario` (a TOML or JSON file) or
    :func:`~teamkf.scenario_from_dict` (plain data); the format is in the guide's
    "Scenario files and the command line" page.

    Parameters
    ----------
    name : str
        The scenario's name (tables and file names use it).
    horizon : int or None
        T, or None for the infinite-horizon (steady-state) design.
    system : LinearGaussianSystem
        The process x(k+1) = A x(k) + w(k) and the agents' measurements y_i(k) = C_i x(k) + v_i(k).
    cost : TeamCost
        The team cost c(x, ẑ) = (L x - ẑ)ᵀ S (L x - ẑ).
    graph : CommGraph
        The communication graph: agent i hears agent j over edge (j, i) after its integer delay τ_ji.
    information : InformationStructure
        From ``[information]`` (checked against the graph) or the graph's full structure.
    estimators : tuple of str
        The registered families compared by ``teamkf evaluate``.
    raw : dict
        The scenario as read (plain data); :meth:`updated` starts from it.
    source : str
        Where it came from (a path, or ``"<dict>"``).
    options : mapping
        Each family's checked options (its scenario table, defaults filled in).
    families : mapping
        The family records of the estimators, carried so that a Dask worker can design them.

    Examples
    --------
    >>> from teamkf import scenario_from_dict
    >>> sc = scenario_from_dict({
    ...     "name": "two-sensors", "horizon": 20,
    ...     "system": {"A": [[0.9]], "Q": 1.0, "Sigma_x": 1.0},
    ...     "agents": [{"C": [[1.0]], "R": 0.5}, {"C": [[1.0]], "R": 2.0}],
    ...     "graph": {"kind": "complete", "delay": 1},
    ...     "cost": {"kind": "mse"},
    ...     "estimators": ["mtmse", "mmse", "centralized"],
    ... })
    >>> sc.n_agents, sc.estimators, sc.graph.n_agents
    (2, ('mtmse', 'mmse', 'centralized'), 2)
    """

    name: str
    horizon: int | None
    system: LinearGaussianSystem
    cost: TeamCost
    graph: CommGraph
    information: InformationStructure
    estimators: tuple[str, ...]
    raw: dict[str, Any] = field(repr=False, default_factory=dict)
    source: str = "<dict>"
    options: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)
    families: Mapping[str, Any] = field(repr=False, default_factory=dict)

    kind: ClassVar[str] = "team"

    def __repr__(self) -> str:
        """One short paragraph: name, size, horizon, graph, estimators and source (never the matrices)."""
        from .._repr import short_repr

        fields = [
            ("name", self.name),
            ("agents", self.n_agents),
            ("d_x", self.system.dx),
            ("horizon", self.horizon),
            ("graph", self.graph),
            ("estimators", self.estimators),
            ("source", self.source),
        ]
        return short_repr(self, fields)

    def _repr_html_(self) -> str:
        from .._repr import html_table

        rows: list[dict[str, Any]] = [
            {"field": "name", "value": self.name},
            {"field": "agents", "value": self.n_agents},
            {"field": "state dimension d_x", "value": self.system.dx},
            {"field": "horizon T", "value": "∞ (steady state)" if self.horizon is None else self.horizon},
            {"field": "graph", "value": repr(self.graph)},
            {"field": "common lag", "value": self.information.common_lag},
            {"field": "estimators", "value": ", ".join(self.estimators)},
            {"field": "source", "value": self.source},
        ]
        return html_table(["field", "value"], rows, caption=f"teamkf scenario: {self.name}")

    @property
    def n_agents(self) -> int:
        return self.system.n_agents

    @property
    def has_reduced_information(self) -> bool:
        """True when the scenario gives its own ``[information]`` structure."""
        return "information" in self.raw

    def design(self, estimator: str, horizon: Any = "scenario") -> Any:
        """Design one estimator (default horizon: the scenario's; None for the steady state).

        The family comes from the registry; its options from the scenario's
        ``[<estimator>]`` table (defaults otherwise).
        """
        T = self.horizon if horizon == "scenario" else horizon
        fam = self.family(estimator)
        opts = self.options.get(estimator)
        if opts is None:
            opts = _family_options(fam, {})
        if "p_drop" in fam.option_names and opts.get("p_drop") is None and "network" in self.raw:  # drop-aware families
            lm = self.links
            table = self.raw.get(fam.name)
            mine = isinstance(table, dict) and "jitter" in table  # the family's own table sets it: that value is designed for
            opts = {**opts, "p_drop": lm.p_drop, **({"jitter": lm.jitter} if "jitter" in fam.option_names and not mine else {})}
        try:
            out = fam.build(self.system, self.cost, graph=self.graph, structure=self.information, horizon=T, options=opts)
        except ScenarioError:
            raise
        except TeamkfError as exc:
            if exc.argument in ("horizon", "graph"):
                raise _fail(exc.argument, f"{estimator}: {exc.detail}") from exc
            if exc.argument == "common_lag":  # the design's name for the scenario key
                raise exc.rekeyed("information.common_lag" if "information" in self.raw else "graph") from exc
            raise
        if not isinstance(out, Design):
            fn = getattr(fam.design, "__qualname__", repr(fam.design))
            raise ArgumentError(
                f"{estimator}: its design function {fn}() returned {V.describe(out)}; a family's design function must return a "
                "teamkf Design (subclass teamkf.estimators.base.Design; see the guide's 'Writing your own family')",
                argument=estimator,
            )
        return out

    def family(self, name: str) -> Any:
        """The registry record of estimator ``name`` (the scenario's own records first: they travel with it to Dask workers)."""
        return self.families.get(name) or _family(name, "estimator")

    def designs(self, estimators: Sequence[str] | None = None, horizon: Any = "scenario") -> dict[str, Any]:
        """Design every estimator of the scenario (or of ``estimators``), in order: name -> design."""
        names = self.estimators if estimators is None else tuple(estimators)
        return {name: self.design(name, horizon) for name in names}

    @property
    def control(self) -> Any:
        """The decentralized LQG problem of a ``[control]`` table (B, Q_x, R_u), or None."""
        return _control(self.raw["control"], self.system, self.horizon) if "control" in self.raw else None

    @property
    def links(self) -> Any:
        """The ``[network]`` table as a :class:`~teamkf.simulation.links.LinkModel`, or None (reliable links)."""
        return _links(self.raw["network"], self.graph) if "network" in self.raw else None

    @property
    def has_lossy_links(self) -> bool:
        """True when the ``[network]`` table makes links drop, jitter or fail."""
        lm = self.links
        return lm is not None and not lm.trivial

    def monte_carlo_options(self) -> dict[str, Any]:
        """Keywords for ``monte_carlo``: with unreliable links, the runtime path over the scenario's graph."""
        lm = self.links
        return {} if lm is None or lm.trivial else {"path": "runtime", "graph": self.graph, "links": lm}

    def updated(self, values: Mapping[str, Any]) -> "Scenario":
        """A new scenario with dotted keys replaced, e.g. ``{"cost.lambda": 10.0, "graph.delay": 2}``."""
        if not isinstance(values, Mapping):
            raise ArgumentError(
                f"values: expected a mapping of dotted keys to values, e.g. {{'cost.lambda': 10.0}}, found {V.describe(values)}", argument="values"
            )
        d = self.raw
        for key, value in values.items():
            d = set_dotted(d, key, value)
        return scenario_from_dict(d, source=self.source, families=self.families)


# ---------------------------------------------------------------------------
# loading
# ---------------------------------------------------------------------------
def load_scenario(path: str | Path) -> Scenario:
    """Read and validate a scenario file (TOML, or JSON when the name ends in ``.json``).

    Parameters
    ----------
    path : str or Path
        The file. The packaged scenarios (``teamkf --help`` lists them) are in ``teamkf/scenarios/``.

    Returns
    -------
    Scenario
        The validated scenario.

    Raises
    ------
    FileNotFoundError
        If there is no such file.
    ScenarioError
        On a syntax error (with the file name, line and column) or an invalid
        scenario (the message starts with the key path).

    Examples
    --------
    >>> from importlib.resources import files
    >>> from teamkf import load_scenario
    >>> sc = load_scenario(files("teamkf") / "scenarios" / "platoon-4.toml")
    >>> sc.name, sc.n_agents, sc.horizon
    ('platoon-4', 4, 100)
    """
    V.instance(path, "path", (str, Path), "the path of a scenario file (a string or a Path)")
    p = Path(path)
    if not p.is_file():
        if not p.exists():
            raise FileNotFoundError(2, "no such scenario file", str(p))
        raise ScenarioError(f"{p}: is not a file; expected a scenario file (.toml or .json)", argument=str(p))
    data = read_data_file(p)
    if "name" not in data:
        data = {"name": p.stem, **data}
    return scenario_from_dict(data, source=str(p))


def scenario_from_dict(d: Mapping[str, Any], source: str = "<dict>", *, families: Mapping[str, Any] | None = None) -> Scenario:
    """Validate plain data (as read from TOML or JSON) into a :class:`Scenario`.

    Parameters
    ----------
    d : mapping
        The scenario's tables, as a TOML or JSON file would give them.
    source : str
        Where the data came from, for error messages.
    families : mapping of str to Family, optional
        Family records added to the registry's for this scenario (a scenario
        carries the records of its estimators, so that a Dask worker without
        the user's registrations can still design them).

    Returns
    -------
    Scenario
        The validated scenario.

    Raises
    ------
    ScenarioError
        On an invalid scenario; the message starts with the key path (``system.A: ...``).

    Examples
    --------
    >>> from teamkf import scenario_from_dict
    >>> sc = scenario_from_dict({
    ...     "name": "two-sensors", "horizon": 20,
    ...     "system": {"A": [[0.9]], "Q": 1.0, "Sigma_x": 1.0},
    ...     "agents": [{"C": [[1.0]], "R": 0.5}, {"C": [[1.0]], "R": 2.0}],
    ...     "graph": {"kind": "complete", "delay": 1},
    ...     "cost": {"kind": "mse"},
    ...     "estimators": ["mtmse", "mmse", "centralized"],
    ... })
    >>> sc.name, sc.horizon, sc.system.dx
    ('two-sensors', 20, 1)
    """
    if not isinstance(d, Mapping):
        raise ScenarioError(f"scenario: expected a table of keys, found {type(d).__name__}")
    check_depth(d)
    if "population" not in d:  # sized from the raw tables, before copying them or building the n^2 graph and information structure
        from ._size import check_team_size

        try:
            h = _horizon(d.get("horizon"))
        except TeamkfError:
            h = None  # reported below, in the order of the checks
        check_team_size(d, h, {**_families(), **(families or {})})
    raw = copy.deepcopy(dict(d))
    if "population" in raw:  # an interference-coupled population (the bulk-filter paper)
        from .population import population_from_dict

        return population_from_dict(raw)  # type: ignore[return-value]
    _hoist_estimators(raw)
    fams = {**_families(), **(families or {})}
    _check_keys(raw, _BASE_KEYS + tuple(fams), "")
    for key in ("system", "agents", "graph", "cost", "estimators"):
        if key not in raw:
            raise _fail(key, f"missing required key; {_HINTS[key]}")

    name = raw.get("name", Path(source).stem if source != "<dict>" else "scenario")
    if not isinstance(name, str) or not name.strip():
        raise _fail("name", f"expected a non-empty string, found {name!r}")
    _printable(name, "name")
    if "description" in raw:
        if not isinstance(raw["description"], str):
            raise _fail("description", f"expected free text (a string), found {_describe(raw['description'])}; quote it")
        _printable(raw["description"], "description", newlines=True)
    horizon = _horizon(raw.get("horizon"))
    system = _system(raw["system"], raw["agents"])
    n = system.n_agents
    graph = _graph(raw["graph"], n)
    cost = _cost(raw["cost"], system)
    if "information" in raw:
        information = _information(raw["information"], n, graph)
    else:
        information = InformationStructure.from_graph(graph)
    _check_horizon(system, cost, horizon)
    estimators = _estimators(raw["estimators"], fams)
    options = {name: _family_options(fam, raw[name]) for name, fam in fams.items() if name in raw}
    for k, est in enumerate(estimators):
        _check_requirements(fams[est], k, horizon, graph)
        options.setdefault(est, _family_options(fams[est], {}))
    if "control" in raw:
        _control(raw["control"], system, horizon)
    if "network" in raw:  # unreliable links (teamkf.simulation.links), checked against the graph
        _links(raw["network"], graph)
    used = {name: fams[name] for name in (*estimators, *options)}  # carried along, so Dask workers need no registry
    sc = Scenario(name, horizon, system, cost, graph, information, estimators, raw, source, options, used)
    _check_known_inputs(sc)
    return sc


def _printable(text: str, key: str, *, newlines: bool = False) -> None:
    """Refuse NUL and other control characters in a name (they truncate file names and terminal output)."""
    bad = [c for c in text if (ord(c) < 32 and not (newlines and c in "\n\t\r")) or ord(c) == 127]
    if bad:
        raise _fail(key, f"expected printable text, found the control character {bad[0]!r} in {text!r}; remove it")


def _check_known_inputs(sc: Scenario) -> None:
    """``[system] x0_mean, B, u, b`` and ``[[agents]] D, d``: numbers of the right shapes, checked when the scenario is read.

    (They act only in ``teamkf filter``; a wrong one must not pass silently through ``evaluate``.)
    """
    s = sc.raw.get("system", {})
    agents = sc.raw.get("agents", [])
    for k in _SYSTEM_OPTIONAL:
        if k in s:
            _numeric(s[k], f"system.{k}", scalar_ok=k not in ("B",))
    for i, a in enumerate(agents):
        for k in _AGENT_OPTIONAL:
            if k in a:
                _numeric(a[k], f"agents[{i}].{k}", scalar_ok=k != "D")
    if "u" in s and "B" not in s and not any("D" in a for a in agents):
        raise _fail("system.u", "inputs u need system.B (or agents[i].D) to act on; add B or drop u")
    from .measurements import known_inputs

    known_inputs(sc)


def _links(tab: Any, graph: CommGraph) -> Any:
    from ..simulation.links import LinkModel

    try:
        return LinkModel.from_dict(tab, graph, "network")
    except TeamkfError as exc:
        raise _fail(exc.argument or "network", exc.detail) from exc


def _families() -> dict[str, Any]:
    from ..estimators.registry import families

    return families()


def _family(name: Any, key: str) -> Any:
    from ..estimators.registry import get_family

    try:
        return get_family(name, key)
    except TeamkfError as exc:
        raise _fail(key, exc.detail) from None


def _family_options(fam: Any, table: Any) -> dict[str, Any]:
    """A family's ``[name]`` table, validated by the family's option schema (key paths ``name.option``)."""
    try:
        return dict(fam.check_options(table, fam.name))
    except TeamkfError as exc:
        raise _fail(exc.argument or fam.name, exc.detail) from None


def _check_requirements(fam: Any, k: int, horizon: int | None, graph: CommGraph) -> None:
    """The family's horizon and graph requirements (CIKF: unit delays), checked when the scenario is read."""
    try:
        fam.check_horizon(horizon, "horizon")
        if fam.uses != "none":
            fam.check_graph(graph, "graph")
    except TeamkfError as exc:
        key = exc.argument or f"estimators[{k}]"
        raise _fail(key, f"{exc.detail} (estimators[{k}] = {fam.name!r}: remove it or change {key})") from None


def _hoist_estimators(raw: dict[str, Any]) -> None:
    """Accept ``estimators = [...]`` written after the last table header.

    In TOML a key written after ``[cost]`` (or ``[information]``) belongs to
    that table; the contract's example is written that way, so a top-level
    ``estimators`` missing from the top but present in exactly one table is
    moved to the top (in ``raw`` too).
    """
    if "estimators" in raw:
        return
    holders = [k for k in ("system", "graph", "cost", "information") if isinstance(raw.get(k), Mapping) and "estimators" in raw[k]]
    if len(holders) == 1:
        table = dict(raw[holders[0]])
        raw["estimators"] = table.pop("estimators")
        raw[holders[0]] = table


_HINTS = {
    "system": "add a [system] table with A, Q and Sigma_x",
    "agents": "add one [[agents]] table (C, R) per agent",
    "graph": 'add a [graph] table with edges = [[from, to, delay], ...] or kind = "complete" | "line" | "ring" | "star"',
    "cost": 'add a [cost] table with kind = "average" | "platoon" | "ring" | "mse" (and lambda), or S and L',
    "estimators": 'add estimators = ["mtmse", "mmse", "centralized"]',
    "system.A": "the state transition matrix, as nested lists (rows)",
    "system.Q": "the process-noise covariance (a number q means q*I)",
    "system.Sigma_x": "the covariance of the initial state (a number q means q*I)",
}


# ---------------------------------------------------------------------------
# pieces
# ---------------------------------------------------------------------------
def _check_keys(table: Mapping[str, Any], allowed: Sequence[str], prefix: str) -> None:
    for k in table:
        if k not in allowed:
            key = f"{prefix}{k}"
            close = difflib.get_close_matches(str(k), list(allowed), n=1, cutoff=0.6)
            hint = f"did you mean {close[0]!r}? " if close else ""
            raise _fail(key, f"unknown key; {hint}expected one of: {', '.join(allowed)}")


def _table(x: Any, key: str, example: str) -> dict[str, Any]:
    if not isinstance(x, Mapping):
        raise _fail(key, f"expected a table ({example}), found {_describe(x)}")
    return dict(x)


from .._validation import describe as _describe  # noqa: E402


def _numeric(x: Any, key: str, *, scalar_ok: bool = True) -> Any:
    """Check that ``x`` is a number or a (possibly 3-D) rectangular nested list of numbers."""

    def walk(v: Any, where: str) -> tuple[int, ...]:
        if isinstance(v, bool) or not isinstance(v, (int, float, list)):
            raise _fail(key, f"expected a number or nested lists of numbers, found {_describe(v)}{' at ' + where if where else ''}")
        if not isinstance(v, list):
            return ()
        if not v:
            raise _fail(key, f"expected a non-empty list{' at ' + where if where else ''}; write matrices as nested lists (rows)")
        shapes = [walk(e, f"{where}[{i}]") for i, e in enumerate(v)]
        for i, s in enumerate(shapes):
            if s != shapes[0]:

                def size(sh: tuple[int, ...]) -> str:
                    return "a number" if not sh else (f"{sh[0]} entries" if len(sh) == 1 else f"shape {V.shape_str(sh)}")

                raise _fail(
                    key,
                    f"expected rows of equal length, found {where}[0] with {size(shapes[0])} and {where}[{i}] with {size(s)}"
                    if where
                    else f"expected rows of equal length, found row 0 with {size(shapes[0])} and row {i} with {size(s)}",
                )
        return (len(v), *shapes[0])

    shape = walk(x, "")
    if len(shape) > 3:
        raise _fail(key, f"expected a matrix or a time sequence of matrices (at most 3 levels of lists), found {len(shape)} levels")
    if len(shape) == 3 and shape[0] == 1:
        raise _fail(
            key,
            f"expected a matrix, or a time sequence of one matrix per step, found a sequence of a single {V.shape_str(shape[1:])} matrix; "
            "write the matrix itself (remove the outer brackets)",
        )
    if not scalar_ok and not isinstance(x, list):
        raise _fail(key, f"expected a matrix (nested lists of rows), found {_describe(x)}")
    return x


# the model constructors name the offending argument (TeamkfError.argument) as they call it;
# these rules map that name to the scenario's key path (the error's detail is kept as it is)
_SYSTEM_RULES = [
    (re.compile(r"^R\[(\d+)\]"), r"agents[\1].R"),
    (re.compile(r"^C\[(\d+)\]"), r"agents[\1].C"),
    (re.compile(r"^[RC]$"), "agents"),
    (re.compile(r"^(A|Q|Sigma_x)(?=$|\[)"), r"system.\1"),
    (re.compile(r"^system\b"), r"\g<0>"),
]
_COST_RULES = [
    (re.compile(r"^(S|L)(?=$|\[)"), r"cost.\1"),
    (re.compile(r"^lambda$"), "cost.lambda"),
    (re.compile(r"^n_agents$"), "cost"),
    (re.compile(r"^cost\b"), r"\g<0>"),
]
_GRAPH_RULES = [
    (re.compile(r"^edges\b"), r"graph.\g<0>"),
    (re.compile(r"^(delay|center|directed|n)$"), r"graph.\1"),
    (re.compile(r"^graph\b"), r"\g<0>"),
]
_INFO_RULES = [
    (re.compile(r"^(local|common_lag)\b"), r"information.\g<0>"),
    (re.compile(r"^graph\b"), r"\g<0>"),
]


def _rekey(exc: TeamkfError, section: str, rules: Sequence[tuple[re.Pattern[str], str]]) -> ScenarioError:
    """The error as a ScenarioError whose key path comes from the error's ``argument`` field."""
    arg = exc.argument
    if arg:
        for pat, repl in rules:
            if pat.search(arg):
                return _fail(pat.sub(repl, arg, count=1), exc.detail)
    return _fail(section, str(exc))


def _control(c_tab: Any, system: LinearGaussianSystem, horizon: int | None) -> Any:
    """``[control]``: B (d_x x n d_u), Q_x (state weight), R_u (control weight) -> an LQGProblem (Appendix D)."""
    from ..control.lqg import LQGProblem

    c = _table(c_tab, "control", "B, Q_x and R_u")
    _check_keys(c, ("B", "Q_x", "R_u"), "control.")
    for k in ("B", "Q_x", "R_u"):
        if k not in c:
            raise _fail(f"control.{k}", "missing required key; [control] needs B (d_x x n d_u), Q_x and R_u (a number q means q*I)")
    if horizon is None or horizon < 2:
        raise _fail("horizon", "a [control] scenario needs a finite horizon T >= 2 (decentralized LQG over T steps)")
    B = _numeric(c["B"], "control.B", scalar_ok=False)
    try:
        return LQGProblem(system, B=B, Q_x=_numeric(c["Q_x"], "control.Q_x"), R_u=_numeric(c["R_u"], "control.R_u"))
    except TeamkfError as exc:
        raise _rekey(exc, "control", [(re.compile(r"^(B|Q_x|R_u)$"), r"control.\1"), (re.compile(r"^system\b"), "system")]) from exc


def _horizon(h: Any) -> int | None:
    if h is None:
        return None
    if isinstance(h, bool) or not isinstance(h, (int, float)) or (isinstance(h, float) and not h.is_integer()) or h < 1:
        raise _fail("horizon", f"expected an integer number of steps >= 1, found {_describe(h)}; omit horizon for the steady-state design")
    return int(h)


def _system(sys_tab: Any, agents: Any) -> LinearGaussianSystem:
    s = _table(sys_tab, "system", "[system] with A, Q, Sigma_x")
    _check_keys(s, _SYSTEM_KEYS + _SYSTEM_OPTIONAL, "system.")
    for k in _SYSTEM_KEYS:
        if k not in s:
            raise _fail(f"system.{k}", f"missing required key; {_HINTS['system.' + k]}")
    A = _numeric(s["A"], "system.A", scalar_ok=False)
    Q = _numeric(s["Q"], "system.Q")
    Sx = _numeric(s["Sigma_x"], "system.Sigma_x")
    if not isinstance(agents, list) or not agents:
        raise _fail("agents", f"expected a non-empty list of agent tables ([[agents]] with C and R), found {_describe(agents)}")
    C, R = [], []
    for i, a in enumerate(agents):
        at = _table(a, f"agents[{i}]", "[[agents]] with C and R")
        _check_keys(at, _AGENT_KEYS + _AGENT_OPTIONAL, f"agents[{i}].")
        for k in _AGENT_KEYS:
            if k not in at:
                what = "the measurement matrix C_i (rows x d_x)" if k == "C" else "the measurement-noise covariance R_i (a number r means r*I)"
                raise _fail(f"agents[{i}].{k}", f"missing required key; {what}")
        C.append(_numeric(at["C"], f"agents[{i}].C", scalar_ok=False))
        R.append(_numeric(at["R"], f"agents[{i}].R"))
    try:
        return LinearGaussianSystem(A=A, Q=Q, Sigma_x=Sx, C=C, R=R)
    except TeamkfError as exc:
        err = _rekey(exc, "system", _SYSTEM_RULES)
        if re.match(r"agents\[\d+\]\.C: expected a kx\d+ matrix", str(err)):
            err = ScenarioError(f"{err} (every C_i needs d_x columns; d_x is the size of system.A)")
            err.key = str(err).split(":")[0]  # type: ignore[attr-defined]
        raise err from exc


def _graph(g_tab: Any, n: int) -> CommGraph:
    g = _table(g_tab, "graph", 'edges = [[from, to, delay], ...] or kind = "line"')
    if "edges" in g and "kind" in g:
        raise _fail("graph", "give either edges or kind (a builder), not both")
    try:
        if "edges" in g:
            _check_keys(g, ("edges",), "graph.")
            edges = g["edges"]
            if not isinstance(edges, list):
                raise _fail("graph.edges", f"expected a list of [from, to, delay] triples, found {_describe(edges)}")
            for k, e in enumerate(edges):  # agent ids are labels: whole numbers as written, never 1.0
                if isinstance(e, list) and len(e) == 3 and any(isinstance(v, float) for v in e[:2]):
                    raise _fail(
                        "graph.edges", f"edges[{k}]: expected integer agent ids (0, 1, ...), found {e[:2]!r}; write them without a decimal point"
                    )
            graph = CommGraph(n, edges)  # type: ignore[arg-type]
        elif "kind" in g:
            kind = g["kind"]
            if kind not in _GRAPH_KINDS:
                close = difflib.get_close_matches(str(kind), _GRAPH_KINDS, n=1)
                hint = f"did you mean {close[0]!r}? " if close else ""
                raise _fail("graph.kind", f"unknown graph kind {kind!r}; {hint}expected one of: {', '.join(_GRAPH_KINDS)}")
            extra = {"ring": ("directed",), "star": ("center",)}.get(kind, ())
            for opt, owner in (("directed", "ring"), ("center", "star")):
                if opt in g and kind != owner:
                    raise _fail(f"graph.{opt}", f'only used with kind = "{owner}", found kind = "{kind}"; remove it')
            _check_keys(g, ("kind", "delay", *extra), "graph.")
            delay = g.get("delay", 1)
            if isinstance(delay, bool) or not isinstance(delay, (int, float)):
                raise _fail("graph.delay", f"expected an integer delay >= 1, found {_describe(delay)}")
            if kind == "ring":
                directed = g.get("directed", False)
                if not isinstance(directed, bool):
                    raise _fail("graph.directed", f"expected true or false, found {_describe(directed)}")
                graph = CommGraph.ring(n, delay, directed=directed)  # type: ignore[arg-type]
            elif kind == "star":
                graph = CommGraph.star(n, delay, center=g.get("center", 0))  # type: ignore[arg-type]
            else:
                graph = getattr(CommGraph, kind)(n, delay)
        else:
            raise _fail("graph", f"expected edges = [[from, to, delay], ...] or kind = {' | '.join(map(repr, _GRAPH_KINDS))}, found neither")
        graph.require_strongly_connected("graph")
    except ScenarioError:
        raise
    except TeamkfError as exc:
        raise _rekey(exc, "graph", _GRAPH_RULES) from exc
    return graph


def _cost(c_tab: Any, system: LinearGaussianSystem) -> TeamCost:
    c = _table(c_tab, "cost", 'kind = "platoon" with lambda, or S and L')
    n, dx = system.n_agents, system.dx
    if "kind" in c and ("S" in c or "L" in c):
        raise _fail("cost", "give either kind (a builder, with lambda) or explicit S and L, not both")
    try:
        if "kind" in c:
            kind = c["kind"]
            if kind not in _COST_KINDS:
                close = difflib.get_close_matches(str(kind), _COST_KINDS, n=1)
                hint = f"did you mean {close[0]!r}? " if close else ""
                raise _fail("cost.kind", f"unknown cost kind {kind!r}; {hint}expected one of: {', '.join(_COST_KINDS)}")
            if kind == "mse":
                if "lambda" in c:
                    raise _fail("cost.lambda", "the 'mse' cost (S = I, every agent estimates the whole state) has no lambda; remove it")
                _check_keys(c, ("kind",), "cost.")
                cost = TeamCost.mse(n, dx)
            else:
                _check_keys(c, ("kind", "lambda"), "cost.")
                if "lambda" not in c:
                    raise _fail("cost.lambda", f"missing required key; cost kind {kind!r} needs a coupling weight lambda >= 0")
                lam = c["lambda"]
                if isinstance(lam, bool) or not isinstance(lam, (int, float)):
                    raise _fail("cost.lambda", f"expected a non-negative number, found {_describe(lam)}")
                builder = {"average": TeamCost.average_tracking, "platoon": TeamCost.platoon, "ring": TeamCost.ring}[kind]
                if dx % n:
                    raise _fail(
                        "cost.kind",
                        f"cost kind {kind!r} needs d_x to be a multiple of the number of agents (agent i estimates its own "
                        f"block of d_x/n states), found d_x = {dx} for {n} agents; give explicit S and L instead",
                    )
                cost = builder(n, lam, dx // n)
        elif "S" in c or "L" in c:
            _check_keys(c, ("S", "L"), "cost.")
            for k in ("S", "L"):
                if k not in c:
                    raise _fail(f"cost.{k}", "missing required key; explicit costs need both S (n*dz x n*dz) and L (n*dz x d_x)")
            L = _numeric(c["L"], "cost.L", scalar_ok=False)
            S = _numeric(c["S"], "cost.S")
            if not isinstance(S, list):
                rows = np.asarray(L, dtype=float).shape[-2]
                S = float(S) * np.eye(rows)
            cost = TeamCost(S=S, L=L, n_agents=n)
        else:
            raise _fail("cost", f"expected kind = {' | '.join(map(repr, _COST_KINDS))} or explicit S and L, found neither")
        cost.check_system(dx, n)
    except ScenarioError:
        raise
    except TeamkfError as exc:
        raise _rekey(exc, "cost", _COST_RULES) from exc
    return cost


def _information(i_tab: Any, n: int, graph: CommGraph) -> InformationStructure:
    t = _table(i_tab, "information", "common_lag and local")
    _check_keys(t, _INFO_KEYS, "information.")
    for k in _INFO_KEYS:
        if k not in t:
            what = "the common part is y(1 : t - common_lag)" if k == "common_lag" else "local[i] = [[j, newest, oldest], ...] for each agent i"
            raise _fail(f"information.{k}", f"missing required key; {what}")
    local = t["local"]
    if not isinstance(local, list):
        raise _fail("information.local", f"expected one list of [source, newest, oldest] windows per agent, found {_describe(local)}")
    if len(local) != n:
        raise _fail("information.local", f"expected one list of windows per agent ({n}), found {len(local)}")
    for i, wins in enumerate(local):
        if not isinstance(wins, list):
            raise _fail(f"information.local[{i}]", f"expected a list of [source, newest, oldest] windows, found {_describe(wins)}")
        for w, win in enumerate(wins):
            if not isinstance(win, list):
                raise _fail(f"information.local[{i}][{w}]", f"expected a [source, newest, oldest] triple, found {_describe(win)}")
    try:
        st = InformationStructure(n, t["common_lag"], local)
        st.validate_on(graph)
    except TeamkfError as exc:
        raise _rekey(exc, "information", _INFO_RULES) from exc
    return st


def _check_horizon(system: LinearGaussianSystem, cost: TeamCost, horizon: int | None) -> None:
    try:
        if horizon is None:
            system.require_time_invariant()
            cost.require_time_invariant()
        else:
            system.require_horizon(horizon)
            cost.require_horizon(horizon)
    except TeamkfError as exc:
        if exc.argument == "horizon":  # sized (teamkf._budget): already named after the scenario key
            raise
        raise _rekey(exc, "horizon", _SYSTEM_RULES + _COST_RULES) from exc


def _estimators(x: Any, fams: Mapping[str, Any] | None = None) -> tuple[str, ...]:
    fams = fams if fams is not None else _families()
    if not isinstance(x, list) or not x:
        raise _fail("estimators", f'expected a non-empty list of names such as ["mtmse", "mmse", "centralized"], found {_describe(x)}')
    names = tuple(e if isinstance(e, str) and e in fams else _family(e, f"estimators[{k}]").name for k, e in enumerate(x))
    for k, e in enumerate(names):
        if e in names[:k]:
            raise _fail(f"estimators[{k}]", f"{e!r} is listed twice; list each estimator once")
    return names


# ---------------------------------------------------------------------------
# dotted keys (sweeps)
# ---------------------------------------------------------------------------
# ---------------------------------------------------------------------------
# packaged scenarios
# ---------------------------------------------------------------------------
def packaged_scenarios() -> dict[str, Any]:
    """The example scenarios shipped with teamkf: name -> path (a Traversable); see :func:`teamkf.study.catalog.packaged_scenarios`."""
    from .catalog import packaged_scenarios as listed

    return listed()


def load_packaged(name: str) -> Scenario:
    """Load a packaged scenario by name (``"platoon-4"``, ``"uav-10"``, ...)."""
    found = packaged_scenarios()
    if name not in found:
        raise ScenarioError(f"{name}: no packaged scenario of that name; available: {', '.join(found)}")
    entry = found[name]
    try:
        data = tomllib.loads(entry.read_text(encoding="utf-8"))
    except tomllib.TOMLDecodeError as exc:  # pragma: no cover - shipped files are tested
        raise ScenarioError(f"{entry.name}: invalid TOML: {exc}") from None
    return scenario_from_dict(data, source=f"teamkf/scenarios/{entry.name}")
