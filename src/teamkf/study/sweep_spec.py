"""The sweep file: its keys, its grid and its points (parsed and checked; run by :mod:`teamkf.study.sweep`)."""

from __future__ import annotations

import copy
import difflib
import errno
import hashlib
import itertools
import json
import os
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from .._budget import check_sweep
from ..exceptions import ScenarioError
from .evaluate import is_analytic
from .results import _FIXED_COLUMNS as _ROW_COLUMNS  # columns of a row besides the grid keys, in order
from .results import SweepError
from .scenario import Scenario, _describe, _estimators, _families, load_packaged, load_scenario, packaged_scenarios, read_data_file

#: the special grid key that multiplies the scenario's A by its value
A_SCALE = "system.A_scale"


_SWEEP_KEYS = ("scenario", "runs", "seed", "estimators", "grid", "name", "description")
_FORMAT = "teamkf-sweep-results/2"  # 2: the rows of teamkf.study.evaluation (label, diverged; point 0 runs with the sweep's seed)
_MAX_SEED = 2**63 - 1


def _fail(key: str, message: str) -> ScenarioError:
    err = ScenarioError(f"{key}: {message}")
    err.key = key  # type: ignore[attr-defined]
    return err


def _gkey(key: str) -> str:
    return f"grid[{json.dumps(key)}]"


# ---------------------------------------------------------------------------
# the sweep
# ---------------------------------------------------------------------------
@dataclass(frozen=True)
class SweepPoint:
    """One grid point: its position in grid order, stable id, parameters and seed."""

    index: int
    point_id: str
    params: dict[str, Any]
    seed: int

    def describe(self) -> str:
        return ", ".join(f"{k} = {json.dumps(v)}" for k, v in self.params.items())


@dataclass(frozen=True, eq=False)
class SweepSpec:
    """A validated sweep (see the module docstring for the file format).

    Attributes
    ----------
    scenario : str
        The base scenario: the resolved path of its file, or a packaged name.
    runs : int
        Monte Carlo runs per point (0: analytic costs only).
    seed : int
        The sweep's seed; point ``k`` gets its own seed from it (see :attr:`points`).
    estimators : tuple of str
    grid : dict
        Dotted key -> tuple of values, in the order of the file (values normalised:
        integers among floats become floats). Treat it as read-only.
    base : Scenario
        The base scenario, loaded.
    name : str
    description : str
    source : str
        The sweep file (or ``"<dict>"``).
    """

    scenario: str
    runs: int
    seed: int
    estimators: tuple[str, ...]
    grid: dict[str, tuple[Any, ...]]
    base: Scenario = field(repr=False)
    name: str = "sweep"
    description: str = ""
    source: str = "<dict>"
    kinds: dict[str, str] = field(repr=False, default_factory=dict)
    cost_keys: tuple[str, ...] = field(repr=False, default=("total_cost",))

    @property
    def n_points(self) -> int:
        return int(np.prod([len(v) for v in self.grid.values()]))

    @property
    def grid_keys(self) -> tuple[str, ...]:
        return tuple(self.grid)

    @cached_property
    def points(self) -> tuple[SweepPoint, ...]:
        """Every grid point, in grid order (the last key varies fastest), with its id and seed."""
        keys = list(self.grid)
        combos = list(itertools.product(*(self.grid[k] for k in keys)))
        children = np.random.SeedSequence(self.seed).spawn(len(combos))
        out = []
        for k, (values, child) in enumerate(zip(combos, children)):
            params = dict(zip(keys, values))
            seed = self.seed if k == 0 else int(child.generate_state(1, dtype=np.uint64)[0] >> np.uint64(1))
            out.append(SweepPoint(k, point_id(params), params, seed))
        return tuple(out)

    def scenario_for(self, point: SweepPoint | Mapping[str, Any]) -> Scenario:
        """The base scenario with one point's parameters applied."""
        params = point.params if isinstance(point, SweepPoint) else point
        return apply_point(self.base, params)

    def fingerprint(self) -> dict[str, Any]:
        """What identifies the sweep's numbers (compared by ``resume``)."""
        return {
            "format": _FORMAT,
            "scenario_sha256": _sha256(_canonical(self.base.raw)),
            "runs": self.runs,
            "seed": self.seed,
            "estimators": list(self.estimators),
            "grid": {k: list(v) for k, v in self.grid.items()},
        }


def point_id(params: Mapping[str, Any]) -> str:
    """Stable id of a grid point: 12 hex digits of the SHA-256 of its canonical JSON.

    >>> point_id({"cost.lambda": 10.0, "graph.delay": 2}) == point_id({"graph.delay": 2, "cost.lambda": 10.0})
    True
    """
    return _sha256(_canonical(dict(params)))[:12]


def _canonical(x: Any) -> str:
    return json.dumps(x, sort_keys=True, separators=(",", ":"), allow_nan=True)


def _sha256(text: str) -> str:
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


def apply_point(base: Scenario, params: Mapping[str, Any]) -> Scenario:
    """``base`` with the dotted keys of ``params`` set (and ``system.A_scale`` applied last)."""
    values = {k: v for k, v in params.items() if k != A_SCALE}
    raw = base.raw
    from .scenario import scenario_from_dict, set_dotted

    for k, v in values.items():
        raw = set_dotted(raw, k, v)
    if A_SCALE in params:
        raw = _scale_A(raw, params[A_SCALE])
    return scenario_from_dict(raw, source=base.source)


def _scale_A(raw: Mapping[str, Any], s: Any) -> dict[str, Any]:
    if isinstance(s, bool) or not isinstance(s, (int, float)):
        raise _fail(A_SCALE, f"expected a number (A is multiplied by it), found {_describe(s)}")
    out = copy.deepcopy(dict(raw))
    system = out.get("system")
    if not isinstance(system, Mapping) or "A" not in system:
        raise _fail(A_SCALE, "the base scenario has no system.A to scale")
    try:
        A = np.asarray(system["A"], dtype=float)
    except (TypeError, ValueError):
        raise _fail("system.A", f"expected a matrix (nested lists of numbers) to scale by {A_SCALE}") from None
    system = dict(system)
    system["A"] = (float(s) * A).tolist()
    out["system"] = system
    return out


# ---------------------------------------------------------------------------
# loading and validation
# ---------------------------------------------------------------------------
def load_sweep(path: str | Path) -> SweepSpec:
    """Read and validate a sweep file (TOML, or JSON by its ``.json`` extension).

    The base scenario is resolved relative to the sweep file's folder, and
    every grid point is applied to it, before this returns.

    Raises
    ------
    FileNotFoundError
        If there is no such sweep file.
    ScenarioError
        On any problem with the sweep file or a grid point; the message starts
        with the key (``runs``, ``grid["cost.lambda"]``, ``cost.lamda``, ...).
    """
    p = Path(path)
    if not p.exists():
        raise FileNotFoundError(errno.ENOENT, "no such sweep file", str(p))
    if p.is_dir():
        raise ScenarioError(f"{p}: is a directory; expected a sweep file (.toml or .json)")
    data = read_data_file(p)
    data.setdefault("name", p.stem)
    return sweep_from_dict(data, base_dir=p.parent, source=str(p))


def sweep_from_dict(data: Mapping[str, Any], base_dir: str | Path = ".", source: str = "<dict>") -> SweepSpec:
    """Validate plain data (as read from a sweep file) into a :class:`SweepSpec`.

    ``scenario`` paths are resolved relative to ``base_dir``.
    """
    if not isinstance(data, Mapping):
        raise ScenarioError(f"sweep: expected a table of keys, found {type(data).__name__}")
    for k in data:
        if k not in _SWEEP_KEYS:
            close = difflib.get_close_matches(str(k), _SWEEP_KEYS, n=1, cutoff=0.6)
            hint = f"did you mean {close[0]!r}? " if close else ""
            raise _fail(str(k), f"unknown key in the sweep file; {hint}expected one of: {', '.join(_SWEEP_KEYS)}")
    for k in ("scenario", "grid"):
        if k not in data:
            what = (
                'the base scenario, e.g. scenario = "../scenarios/platoon-4.toml" (relative to the sweep file)'
                if k == "scenario"
                else 'a [grid] table of dotted keys and value lists, e.g. "cost.lambda" = [1.0, 10.0]'
            )
            raise _fail(k, f"missing required key; add {what}")

    name = data.get("name", "sweep")
    if not isinstance(name, str) or not name.strip():
        raise _fail("name", f"expected a non-empty string, found {_describe(name)}")
    if any(ord(c) < 32 or ord(c) == 127 for c in name):
        raise _fail("name", f"expected printable text, found a control character in {name!r}; remove it")
    description = data.get("description", "")
    if not isinstance(description, str):
        raise _fail("description", f"expected a string, found {_describe(description)}")
    runs = _int(data.get("runs", 0), "runs", 0)
    if runs == 1:
        raise _fail("runs", "expected 0 (analytic costs only) or at least 2 Monte Carlo runs (for a confidence interval), found 1")
    seed = _int(data.get("seed", 0), "seed", 0)
    if seed > _MAX_SEED:
        raise _fail("seed", f"expected an integer seed between 0 and 2**63 - 1, found {seed}")

    scenario, base = _base_scenario(data["scenario"], Path(base_dir))
    if not base.simulates:  # a [population] scenario: one exact filter, nothing simulated
        if runs:
            raise _fail("runs", f"expected 0 for a population scenario (evaluated exactly, nothing is simulated), found {runs}")
        if "estimators" in data:
            raise _fail(
                "estimators", "a population scenario has one estimator, the bulk filter (population.memory picks exact or memory-n); remove the key"
            )
        estimators: tuple[str, ...] = tuple(base.estimators)
    elif "estimators" in data:
        estimators = _estimators(data["estimators"], {**_families(), **base.families})
    else:
        estimators = tuple(base.estimators)
    if runs == 0 and base.simulates:
        for idx, e in enumerate(estimators):
            if not is_analytic(e):
                raise _fail(f"estimators[{idx}]", f"{e!r} has no analytic cost; set runs >= 2 to evaluate it by Monte Carlo")

    grid, kinds = _grid(data["grid"])
    sys_ = getattr(base, "system", None)  # sized before any point is built (teamkf._budget)
    dx, dy, n_agents = (sys_.dx, sys_.dy_total, sys_.n_agents) if sys_ is not None else (1, 1, 1)
    check_sweep([len(v) for v in grid.values()], runs if sys_ is not None else 0, base.horizon or 1, dx, dy, n_agents, len(estimators))
    spec = SweepSpec(scenario, runs, seed, estimators, grid, base, name=name, description=description, source=source, kinds=kinds)
    cost_keys = _check_points(spec)
    object.__setattr__(spec, "cost_keys", cost_keys)
    return spec


def _int(x: Any, key: str, minimum: int) -> int:
    if isinstance(x, bool) or not isinstance(x, int):
        raise _fail(key, f"expected an integer >= {minimum}, found {_describe(x)}")
    if x < minimum:
        raise _fail(key, f"expected an integer >= {minimum}, found {x}")
    if x > _MAX_SEED:
        raise _fail(key, f"expected an integer between {minimum} and 2**63 - 1, found {x:.3g}")
    return int(x)


def _base_scenario(s: Any, base_dir: Path) -> tuple[str, Scenario]:
    if not isinstance(s, str) or not s.strip():
        raise _fail(
            "scenario", f"expected the path of a scenario file (relative to the sweep file) or a packaged scenario name, found {_describe(s)}"
        )
    p = Path(os.path.normpath(base_dir / s))
    if p.is_file():
        try:
            return str(p), load_scenario(p)
        except ScenarioError as exc:
            msg = str(exc)
            err = ScenarioError(msg if msg.startswith(str(p)) else f"scenario {p}: {msg}")
            raise err from None
    packaged = packaged_scenarios()
    if s in packaged:
        return s, load_packaged(s)
    where = "is a directory" if p.is_dir() else "no such file"
    raise _fail("scenario", f"{p}: {where} (paths are relative to the sweep file's folder); packaged scenarios: {', '.join(packaged)}")


def _flatten(table: Mapping[str, Any], prefix: str, out: dict[str, Any]) -> None:
    for k, v in table.items():
        key = f"{prefix}.{k}" if prefix else str(k)
        if isinstance(v, Mapping):
            if not v:
                raise _fail(_gkey(key), "expected a list of values, found an empty table")
            _flatten(v, key, out)
        else:
            out[key] = v


def _kind(v: Any) -> str:
    if isinstance(v, bool):
        return "bool"
    if isinstance(v, int):
        return "int"
    if isinstance(v, float):
        return "float"
    if isinstance(v, str):
        return "string"
    if isinstance(v, (list, Mapping)):
        return "json"
    return type(v).__name__


def _grid(g: Any) -> tuple[dict[str, tuple[Any, ...]], dict[str, str]]:
    if not isinstance(g, Mapping):
        raise _fail("grid", f'expected a table of dotted keys and value lists ([grid] with "cost.lambda" = [1.0, 10.0]), found {_describe(g)}')
    flat: dict[str, Any] = {}
    _flatten(g, "", flat)
    if not flat:
        raise _fail("grid", 'expected at least one dotted key with a list of values (e.g. "cost.lambda" = [1.0, 10.0]), found an empty table')
    grid: dict[str, tuple[Any, ...]] = {}
    kinds: dict[str, str] = {}
    for key, values in flat.items():
        gk = _gkey(key)
        if key in _ROW_COLUMNS or key in ("estimator", "estimators", "name"):
            hint = (
                "set the estimators with the sweep file's estimators key" if key in ("estimator", "estimators") else "it is a column of the results"
            )
            raise _fail(gk, f"cannot be swept ({hint})")
        if not isinstance(values, list):
            raise _fail(
                gk,
                f"expected a non-empty list of values (one point each), found {_describe(values)}; write [{json.dumps(values) if isinstance(values, (int, float, str)) else '...'}] for a single value",
            )
        if not values:
            raise _fail(gk, "expected a non-empty list of values (one point each), found an empty list")
        found = [_kind(v) for v in values]
        for k, f in enumerate(found):
            if f not in ("bool", "int", "float", "string", "json"):
                raise _fail(gk, f"value {k} has an unsupported type {f}")
        kset = set(found)
        if kset <= {"int", "float"}:
            kind = "int" if kset == {"int"} else "float"
            if kind == "float":
                values = [float(v) for v in values]
        elif len(kset) == 1:
            kind = found[0]
        else:
            a = next(k for k, f in enumerate(found) if f != found[0])
            raise _fail(gk, f"expected values of one type, found {_describe(values[0])} (value 0) and {_describe(values[a])} (value {a})")
        if key == A_SCALE and kind not in ("int", "float"):
            raise _fail(gk, f"expected numbers (system.A is multiplied by each), found {_describe(values[0])}")
        canon = [_canonical(v) for v in values]
        for k, c in enumerate(canon):
            if c in canon[:k]:
                raise _fail(gk, f"value {values[k]!r} is listed twice (values {canon.index(c)} and {k}); list each value once")
        grid[key] = tuple(values)
        kinds[key] = kind
    return grid, kinds


def _check_points(spec: SweepSpec) -> tuple[str, ...]:
    """Apply every key alone, then every point, to the base scenario; return the cost columns used."""
    for key, values in spec.grid.items():
        for v in values:
            try:
                apply_point(spec.base, {key: v})
            except ScenarioError as exc:
                raise _wrap(key, v, exc) from None
    horizons = set()
    for p in spec.points:
        try:
            sc = spec.scenario_for(p)
        except ScenarioError as exc:
            raise ScenarioError(f"{exc} (at grid point {p.index}: {p.describe()})") from None
        horizons.add(sc.horizon is None or not sc.simulates)  # a population reports its average cost
        if spec.runs and sc.horizon is None:
            raise _fail(
                "runs",
                f"Monte Carlo runs need a finite horizon, but grid point {p.index} ({p.describe()}) has none "
                "(steady state); set runs = 0 or give the scenario a horizon",
            )
    seen: dict[str, int] = {}
    for p in spec.points:
        if p.point_id in seen:  # pragma: no cover - 48-bit hash collision
            raise SweepError(f"grid points {seen[p.point_id]} and {p.index} have the same id {p.point_id}; change a value slightly")
        seen[p.point_id] = p.index
    return tuple(k for k, steady in (("total_cost", False), ("average_cost", True)) if steady in horizons)


def _wrap(key: str, value: Any, exc: ScenarioError) -> ScenarioError:
    """The scenario's error for one grid value, with the grid key and value in front."""
    msg = str(exc)
    err = ScenarioError(f"{_gkey(key)} = {json.dumps(value)}: {msg}")
    err.key = key  # type: ignore[attr-defined]
    return err
