"""The bad-input campaign (issues 9 and 10), as one table-driven test.

Every row is a bad input given as a new user would: through the ``teamkf``
command (in-process ``teamkf.cli.main([...])``, a few through a subprocess) or
the public Python API. Each must give

* Python: a :class:`~teamkf.exceptions.TeamkfError` subclass whose message
  names the offending key or argument;
* CLI: exit status 2 and exactly one stderr line
  ``teamkf: error: <key or argument>: ...`` (no traceback without ``--debug``),
  naming the key or argument and what was expected;
* no output file left behind.

The family rows are generated from ``teamkf.families()``: a family registered
later is covered without editing this file. The row count is in every test id
(``cli-017-...``, ``api-203-...``) and checked by ``test_campaign_size``.
"""

from __future__ import annotations

import copy
import json
import os
import socket
import subprocess
import sys
from pathlib import Path
from typing import Any, Callable

import numpy as np
import pytest

import teamkf
from teamkf.cli import main
from teamkf.exceptions import TeamkfError

ROOT = Path(__file__).resolve().parents[2]

# ---------------------------------------------------------------------------
# a small valid scenario (2 agents, d_x = 2, T = 4) that every family accepts
# ---------------------------------------------------------------------------
BASE: dict[str, Any] = {
    "name": "bad-input-base",
    "horizon": 4,
    "system": {"A": [[0.9, 0.1], [0.0, 0.8]], "Q": 1.0, "Sigma_x": 1.0},
    "agents": [{"C": [[1.0, 0.0]], "R": 0.5}, {"C": [[0.0, 1.0]], "R": 0.5}],
    "graph": {"kind": "line", "delay": 1},
    "cost": {"kind": "average", "lambda": 1.0},
    "estimators": ["mtmse"],
}
POP: dict[str, Any] = {"name": "pop", "horizon": 20, "population": {"n_agents": 10, "a": 2.5, "f": 2.0}}

DROP = object()


def _set(d: dict[str, Any], path: str, value: Any) -> dict[str, Any]:
    """A deep copy of ``d`` with the dotted path (list items as integers) set, or removed with DROP."""
    out = copy.deepcopy(d)
    parts: list[Any] = [int(p) if p.isdigit() else p for p in path.split(".")]
    node: Any = out
    for p in parts[:-1]:
        node = node[p]
    if value is DROP:
        del node[parts[-1]]
    else:
        node[parts[-1]] = value
    return out


def _closed_port() -> int:
    """A local TCP port with nothing listening (bound, then released)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


CLOSED = f"tcp://127.0.0.1:{_closed_port()}"

# ---------------------------------------------------------------------------
# scenario rows: (name, scenario data or raw text, key the message must name)
# ---------------------------------------------------------------------------
M = _set
SCENARIO_ROWS: list[tuple[str, Any, str]] = [
    # top level
    ("unknown-top-key", M(BASE, "horizn", 5), "horizn"),
    ("name-not-string", M(BASE, "name", 3), "name"),
    ("name-empty", M(BASE, "name", " "), "name"),
    ("horizon-zero", M(BASE, "horizon", 0), "horizon"),
    ("horizon-negative", M(BASE, "horizon", -3), "horizon"),
    ("horizon-fraction", M(BASE, "horizon", 2.5), "horizon"),
    ("horizon-string", M(BASE, "horizon", "10"), "horizon"),
    ("horizon-bool", M(BASE, "horizon", True), "horizon"),
    ("horizon-impossible", M(BASE, "horizon", 10**13), "horizon"),
    ("missing-system", M(BASE, "system", DROP), "system"),
    ("missing-agents", M(BASE, "agents", DROP), "agents"),
    ("missing-graph", M(BASE, "graph", DROP), "graph"),
    ("missing-cost", M(BASE, "cost", DROP), "cost"),
    ("missing-estimators", M(BASE, "estimators", DROP), "estimators"),
    ("estimators-empty", M(BASE, "estimators", []), "estimators"),
    ("estimators-string", M(BASE, "estimators", "mtmse"), "estimators"),
    ("estimators-number", M(BASE, "estimators", [3]), "estimators[0]"),
    ("estimators-unknown", M(BASE, "estimators", ["kalman"]), "estimators[0]"),
    ("estimators-misspelled", M(BASE, "estimators", ["mtsme"]), "estimators[0]"),
    ("estimators-duplicate", M(BASE, "estimators", ["mtmse", "mtmse"]), "estimators"),
    # system matrices
    ("A-string", M(BASE, "system.A", "abc"), "system.A"),
    ("A-ragged", M(BASE, "system.A", [[1.0, 0.0], [0.5]]), "system.A"),
    ("A-vector", M(BASE, "system.A", [0.9, 0.8]), "system.A"),
    ("A-not-square", M(BASE, "system.A", [[0.9, 0.0, 0.0], [0.0, 0.9, 0.0]]), "system.A"),
    ("A-nan", M(BASE, "system.A", [[float("nan"), 0.0], [0.0, 0.9]]), "system.A"),
    ("A-inf", M(BASE, "system.A", [[float("inf"), 0.0], [0.0, 0.9]]), "system.A"),
    ("A-bool", M(BASE, "system.A", [[True, False], [False, True]]), "system.A"),
    ("A-table", M(BASE, "system.A", {"x": 1}), "system.A"),
    ("A-missing", M(BASE, "system.A", DROP), "system.A"),
    ("A-3x3-vs-C", M(BASE, "system.A", np.eye(3).tolist()), "agents[0].C"),
    ("Q-not-symmetric", M(BASE, "system.Q", [[1.0, 0.5], [0.0, 1.0]]), "system.Q"),
    ("Q-not-psd", M(BASE, "system.Q", [[1.0, 0.0], [0.0, -1.0]]), "system.Q"),
    ("Q-negative-scalar", M(BASE, "system.Q", -1.0), "system.Q"),
    ("Q-wrong-size", M(BASE, "system.Q", np.eye(3).tolist()), "system.Q"),
    ("Q-nan", M(BASE, "system.Q", float("nan")), "system.Q"),
    ("Q-string", M(BASE, "system.Q", "one"), "system.Q"),
    ("Sigma_x-not-psd", M(BASE, "system.Sigma_x", [[1.0, 2.0], [2.0, 1.0]]), "system.Sigma_x"),
    ("Sigma_x-not-symmetric", M(BASE, "system.Sigma_x", [[1.0, 0.1], [0.3, 1.0]]), "system.Sigma_x"),
    ("Sigma_x-inf", M(BASE, "system.Sigma_x", float("inf")), "system.Sigma_x"),
    ("system-unknown-key", M(BASE, "system.Bogus", 1.0), "system.Bogus"),
    ("system-not-table", M(BASE, "system", [1, 2]), "system"),
    # agents
    ("agents-empty", M(BASE, "agents", []), "agents"),
    ("agents-not-list", M(BASE, "agents", {"C": 1}), "agents"),
    ("agent-not-table", M(BASE, "agents.0", 3), "agents[0]"),
    ("agent-unknown-key", M(BASE, "agents.0.Cc", [[1.0, 0.0]]), "agents[0].Cc"),
    ("C-missing", M(BASE, "agents.0.C", DROP), "agents[0].C"),
    ("C-wrong-columns", M(BASE, "agents.0.C", [[1.0, 0.0, 0.0]]), "agents[0].C"),
    ("C-ragged", M(BASE, "agents.1.C", [[1.0], [0.0, 1.0]]), "agents[1].C"),
    ("C-nan", M(BASE, "agents.1.C", [[float("nan"), 1.0]]), "agents[1].C"),
    ("C-string", M(BASE, "agents.1.C", [["a", "b"]]), "agents[1].C"),
    ("R-zero", M(BASE, "agents.0.R", 0.0), "agents[0].R"),
    ("R-negative", M(BASE, "agents.0.R", -0.5), "agents[0].R"),
    ("R-wrong-size", M(BASE, "agents.0.R", np.eye(2).tolist()), "agents[0].R"),
    ("R-not-symmetric", M(M(BASE, "agents.0.C", [[1.0, 0.0], [0.0, 1.0]]), "agents.0.R", [[1.0, 0.2], [0.0, 1.0]]), "agents[0].R"),
    ("R-inf", M(BASE, "agents.1.R", float("inf")), "agents[1].R"),
    ("R-missing", M(BASE, "agents.1.R", DROP), "agents[1].R"),
    # graph and delays
    ("graph-kind-misspelled", M(BASE, "graph.kind", "lin"), "graph.kind"),
    ("graph-kind-number", M(BASE, "graph.kind", 2), "graph.kind"),
    ("graph-delay-zero", M(BASE, "graph.delay", 0), "graph.delay"),
    ("graph-delay-negative", M(BASE, "graph.delay", -1), "graph.delay"),
    ("graph-delay-fraction", M(BASE, "graph.delay", 1.5), "graph.delay"),
    ("graph-delay-string", M(BASE, "graph.delay", "1"), "graph.delay"),
    ("graph-unknown-key", M(BASE, "graph.delays", 1), "graph.delays"),
    ("graph-not-table", M(BASE, "graph", "line"), "graph"),
    ("edges-out-of-range", M(BASE, "graph", {"edges": [[0, 5, 1], [1, 0, 1]]}), "graph.edges"),
    ("edges-self-loop", M(BASE, "graph", {"edges": [[0, 0, 1], [1, 0, 1]]}), "graph.edges"),
    ("edges-short", M(BASE, "graph", {"edges": [[0, 1], [1, 0, 1]]}), "graph.edges"),
    ("edges-string", M(BASE, "graph", {"edges": "0-1"}), "graph.edges"),
    ("edges-delay-zero", M(BASE, "graph", {"edges": [[0, 1, 0], [1, 0, 1]]}), "graph.edges"),
    ("edges-negative-agent", M(BASE, "graph", {"edges": [[-1, 1, 1], [1, 0, 1]]}), "graph.edges"),
    ("edges-duplicate", M(BASE, "graph", {"edges": [[0, 1, 1], [0, 1, 2], [1, 0, 1]]}), "graph.edges"),
    # cost
    ("cost-kind-misspelled", M(BASE, "cost.kind", "averge"), "cost.kind"),
    ("cost-lambda-negative", M(BASE, "cost.lambda", -1.0), "cost.lambda"),
    ("cost-lambda-string", M(BASE, "cost.lambda", "ten"), "cost.lambda"),
    ("cost-lambda-nan", M(BASE, "cost.lambda", float("nan")), "cost.lambda"),
    ("cost-unknown-key", M(BASE, "cost.lamda", 1.0), "cost.lamda"),
    ("cost-S-not-symmetric", M(BASE, "cost", {"S": [[1.0, 0.5], [0.0, 1.0]], "L": [[1.0, 0.0], [0.0, 1.0]]}), "cost.S"),
    ("cost-S-not-psd", M(BASE, "cost", {"S": [[1.0, 0.0], [0.0, -1.0]], "L": [[1.0, 0.0], [0.0, 1.0]]}), "cost.S"),
    ("cost-S-wrong-size", M(BASE, "cost", {"S": np.eye(3).tolist(), "L": [[1.0, 0.0], [0.0, 1.0]]}), "cost.S"),
    ("cost-L-wrong-shape", M(BASE, "cost", {"S": np.eye(2).tolist(), "L": [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]}), "cost.L"),
    ("cost-S-without-L", M(BASE, "cost", {"S": np.eye(2).tolist()}), "cost.L"),
    (
        "cost-average-dx-not-multiple",
        M(M(BASE, "system.A", np.eye(3).tolist()), "agents", [{"C": [[1, 0, 0]], "R": 1}, {"C": [[0, 1, 0]], "R": 1}]),
        "cost",
    ),
    # information structure
    ("information-lag-zero", M(BASE, "information", {"common_lag": 0, "local": [[], []]}), "information"),
    ("information-not-table", M(BASE, "information", 3), "information"),
    ("information-unknown-key", M(BASE, "information", {"common_lag": 2, "locals": [[], []]}), "information"),
    ("information-local-ragged", M(BASE, "information", {"common_lag": 2, "local": [[[0, 0]], []]}), "information.local"),
]

TEXT_ROWS: list[tuple[str, str, str, str]] = [  # (name, file suffix, text, key)
    ("toml-malformed", ".toml", "name = \nhorizon = 5", "bad.toml"),
    ("toml-unclosed-table", ".toml", "[system\nA = 1", "bad.toml"),
    ("json-malformed", ".json", '{"name": "x", ', "bad.json"),
    ("json-top-level-list", ".json", "[1, 2, 3]", "bad.json"),
    ("json-trailing-comma", ".json", '{"name": "x",}', "bad.json"),
    ("file-empty-toml", ".toml", "", "system"),
    ("file-binary", ".toml", "\x00\x01\x02garbage", "bad.toml"),
    ("file-unknown-extension", ".yaml", "name: x", "bad.yaml"),
    ("toml-nan-literal", ".toml", "", "system.A"),  # filled below from BASE with A = [[nan, 0], [0, 0.9]]
]

POP_ROWS: list[tuple[str, Any, str]] = [
    ("pop-n-zero", M(POP, "population.n_agents", 0), "population.n_agents"),
    ("pop-n-fraction", M(POP, "population.n_agents", 2.5), "population.n_agents"),
    ("pop-a-string", M(POP, "population.a", "x"), "population.a"),
    ("pop-a-nan", M(POP, "population.a", float("nan")), "population.a"),
    ("pop-a-missing", M(POP, "population.a", DROP), "population.a"),
    ("pop-f-and-a_f", M(POP, "population.a_f", 0.5), "population.a_f"),
    ("pop-unknown-key", M(POP, "population.sigmaw", 1.0), "population.sigmaw"),
    ("pop-memory-negative", M(POP, "population.memory", -1), "population.memory"),
    ("pop-sigma_v-zero", M(POP, "population.sigma_v", 0.0), "population.sigma_v"),
    ("pop-c-zero", M(POP, "population.c", 0.0), "population.c"),
    ("pop-horizon-missing", M(POP, "horizon", DROP), "horizon"),
    ("pop-horizon-zero", M(POP, "horizon", 0), "horizon"),
    ("pop-not-table", M(POP, "population", [1]), "population"),
    ("pop-cdma-missing-alpha", M(POP, "population.cdma", {"beta": 1.0, "h_prime": 1.0}), "population.cdma.alpha"),
    ("pop-cdma-with-c", M(M(POP, "population.c", 1.0), "population.cdma", {"alpha": 1.0, "beta": 1.0, "h_prime": 1.0}), "population.cdma"),
    ("pop-unstable-exact", M(M(M(POP, "population.a", 1.5), "population.f", 0.0), "horizon", 500), "horizon"),
    ("pop-huge-exact-horizon", M(POP, "horizon", 10**7), "horizon"),
]


def _family_rows() -> list[tuple[str, Any, str]]:
    """Rows for every registered family: unknown option, misspelled name, a bad value per option, an unsupported horizon."""
    rows: list[tuple[str, Any, str]] = []
    for name, fam in teamkf.families().items():
        sc = M(BASE, "estimators", [name])
        rows.append((f"{name}-unknown-option", M(sc, name, {"bogus_option": 1}), f"{name}.bogus_option"))
        rows.append((f"{name}-options-not-table", M(sc, name, 3), name))
        rows.append((f"{name}-misspelled", M(BASE, "estimators", [name[:-1] + name[-1].upper() + "x"]), "estimators[0]"))
        for opt in fam.options:
            rows.append((f"{name}-option-{opt.name}-table", M(sc, name, {opt.name: {"not": "a value"}}), f"{name}.{opt.name}"))
        if "infinite" not in fam.horizons:
            rows.append((f"{name}-no-steady-state", M(sc, "horizon", DROP), "horizon"))
        if fam.uses != "none":
            rows.append((f"{name}-graph-delay-string", M(sc, "graph.delay", "one"), "graph.delay"))
        if fam.unit_delays:
            rows.append((f"{name}-needs-unit-delays", M(sc, "graph.delay", 2), "graph"))
    return rows


#: the families the rows were generated for (registered when this module is collected: built-ins, entry points)
FAMILIES = tuple(teamkf.families())
SCENARIO_ROWS += _family_rows()


# ---------------------------------------------------------------------------
# command-line rows: (name, argv with {S} = a valid scenario file, {T} = tmp dir, key, output path that must not appear)
# ---------------------------------------------------------------------------
CLI_ROWS: list[tuple[str, list[str], str, str | None]] = [
    ("no-command", [], "COMMAND", None),
    ("unknown-command", ["evalute", "{S}"], "COMMAND", None),
    ("unknown-flag", ["evaluate", "{S}", "--fast"], "--fast", None),
    ("evaluate-no-scenario", ["evaluate"], "SCENARIO", None),
    ("scenario-missing-file", ["evaluate", "{T}/nope.toml"], "nope.toml", None),
    ("scenario-directory", ["evaluate", "{T}"], "{T}", None),
    ("scenario-packaged-misspelled", ["evaluate", "platon-4"], "platon-4", None),
    ("mc-zero", ["evaluate", "{S}", "--monte-carlo", "0"], "--monte-carlo", None),
    ("mc-negative", ["evaluate", "{S}", "--monte-carlo", "-5"], "--monte-carlo", None),
    ("mc-one", ["evaluate", "{S}", "--monte-carlo", "1"], "--monte-carlo", None),
    ("mc-text", ["evaluate", "{S}", "--monte-carlo", "many"], "--monte-carlo", None),
    ("mc-fraction", ["evaluate", "{S}", "--monte-carlo", "2.5"], "--monte-carlo", None),
    ("mc-too-many", ["evaluate", "{S}", "--monte-carlo", str(2**64)], "--monte-carlo", None),
    ("mc-steady-state", ["evaluate", "platoon-4-steady", "--monte-carlo", "10"], "horizon", None),
    ("mc-population", ["evaluate", "interference", "--monte-carlo", "10"], "--monte-carlo", None),
    ("seed-negative", ["evaluate", "{S}", "--monte-carlo", "5", "--seed", "-1"], "--seed", None),
    ("seed-text", ["evaluate", "{S}", "--seed", "abc"], "--seed", None),
    ("plot-bad-extension", ["evaluate", "{S}", "--plot", "{T}/out.txt"], "--plot", "{T}/out.txt"),
    ("plot-no-extension", ["evaluate", "{S}", "--plot", "{T}/out"], "--plot", "{T}/out"),
    ("plot-directory", ["evaluate", "{S}", "--plot", "{T}/adir.png"], "--plot", None),
    ("plot-unwritable", ["evaluate", "{S}", "--plot", "{T}/ro/out.png"], "--plot", "{T}/ro/out.png"),
    ("plot-under-a-file", ["evaluate", "{S}", "--plot", "{T}/afile/out.png"], "--plot", "{T}/afile/out.png"),
    ("plot-population", ["evaluate", "interference", "--plot", "{T}/pop.png"], "--plot", "{T}/pop.png"),
    ("design-out-unwritable", ["design", "{S}", "--out", "{T}/ro/g.npz"], "--out", "{T}/ro/g.npz"),
    ("design-out-directory", ["design", "{S}", "--out", "{T}/adir.png"], "--out", None),
    ("design-out-under-a-file", ["design", "{S}", "--out", "{T}/afile/g.npz"], "--out", "{T}/afile/g.npz"),
    ("design-out-population-unwritable", ["design", "interference", "--out", "{T}/ro/p.npz"], "--out", "{T}/ro/p.npz"),
    ("reproduce-unknown", ["reproduce", "fig9"], "fig9", None),
    ("reproduce-no-name", ["reproduce"], "reproduce", None),
    ("reproduce-scheduler-ignored", ["reproduce", "fig3", "--scheduler", "local"], "--scheduler", None),
    ("reproduce-scheduler-garbage", ["reproduce", "bulk-lq-cost", "--scheduler", "foo"], "--scheduler", None),
    ("reproduce-scheduler-closed-port", ["reproduce", "bulk-lq-cost", "--quick", "--scheduler", CLOSED], "--scheduler", None),
    ("reproduce-out-is-file", ["reproduce", "fig1", "--quick", "--out", "{T}/afile"], "--out", None),
    ("reproduce-out-unwritable", ["reproduce", "fig1", "--quick", "--out", "{T}/ro/res"], "--out", "{T}/ro/res"),
    ("sweep-missing-file", ["sweep", "{T}/nope.toml"], "nope.toml", None),
    ("sweep-workers-zero", ["sweep", "{W}", "--workers", "0"], "--workers", None),
    ("sweep-scheduler-closed-port", ["sweep", "{W}", "--scheduler", CLOSED, "--out", "{T}/sw1.parquet"], "--scheduler", "{T}/sw1.parquet"),
    ("sweep-scheduler-garbage", ["sweep", "{W}", "--scheduler", "tcp://", "--out", "{T}/sw2.parquet"], "--scheduler", "{T}/sw2.parquet"),
    ("sweep-out-is-file", ["sweep", "{W}", "--scheduler", "serial", "--out", "{T}/afile"], "afile", None),
]

SWEEP_BASE: dict[str, Any] = {"name": "sw", "scenario": "platoon-4", "grid": {"cost.lambda": [1.0, 10.0]}}
SWEEP_ROWS: list[tuple[str, Any, str]] = [
    ("sweep-unknown-key", M(SWEEP_BASE, "grids", {}), "grids"),
    ("sweep-no-grid", M(SWEEP_BASE, "grid", DROP), "grid"),
    ("sweep-no-scenario", M(SWEEP_BASE, "scenario", DROP), "scenario"),
    ("sweep-scenario-missing", M(SWEEP_BASE, "scenario", "nope.toml"), "scenario"),
    ("sweep-runs-one", M(SWEEP_BASE, "runs", 1), "runs"),
    ("sweep-runs-negative", M(SWEEP_BASE, "runs", -2), "runs"),
    ("sweep-seed-negative", M(SWEEP_BASE, "seed", -1), "seed"),
    ("sweep-seed-huge", M(SWEEP_BASE, "seed", 2**64), "seed"),
    ("sweep-grid-not-list", M(SWEEP_BASE, "grid", {"cost.lambda": 1.0}), "cost.lambda"),
    ("sweep-grid-empty-list", M(SWEEP_BASE, "grid", {"cost.lambda": []}), "cost.lambda"),
    ("sweep-grid-bad-value", M(SWEEP_BASE, "grid", {"cost.lambda": [-1.0]}), "cost.lambda"),
    ("sweep-grid-unknown-key", M(SWEEP_BASE, "grid", {"cost.lamda": [1.0]}), "cost.lamda"),
    ("sweep-grid-mixed-types", M(SWEEP_BASE, "grid", {"cost.lambda": [1.0, "x"]}), "cost.lambda"),
    ("sweep-grid-duplicate", M(SWEEP_BASE, "grid", {"cost.lambda": [1.0, 1.0]}), "cost.lambda"),
    ("sweep-A_scale-string", M(SWEEP_BASE, "grid", {"system.A_scale": ["x"]}), "system.A_scale"),
    ("sweep-estimator-unknown", M(SWEEP_BASE, "estimators", ["mtmes"]), "estimators[0]"),
    ("sweep-estimators-not-a-list", M(SWEEP_BASE, "estimators", "kcf"), "estimators"),
    ("sweep-population-runs", {"scenario": "interference", "runs": 10, "grid": {"population.a": [2.0]}}, "runs"),
    ("sweep-population-estimators", {"scenario": "interference", "estimators": ["mtmse"], "grid": {"population.a": [2.0]}}, "estimators"),
    ("sweep-population-bad-grid", {"scenario": "interference", "grid": {"population.n_agents": [0]}}, "population.n_agents"),
]


# ---------------------------------------------------------------------------
# the Python API: (name, thunk, argument the message must name)
# ---------------------------------------------------------------------------
def _api_rows() -> list[tuple[str, Callable[[], Any], str]]:
    from teamkf import CommGraph, LinearGaussianSystem, TeamCost
    from teamkf.estimators.bulk import exact_bulk_filter, finite_memory_filter
    from teamkf.models.population import PopulationModel
    from teamkf.study.population import evaluate_population

    I2 = np.eye(2)
    sysk = dict(A=[[0.9, 0.1], [0.0, 0.8]], Q=1.0, Sigma_x=1.0, C=[[[1.0, 0.0]], [[0.0, 1.0]]], R=[0.5, 0.5])

    def system(**kw: Any) -> Any:
        return LinearGaussianSystem(**{**sysk, **kw})

    good = system()
    cost = TeamCost.average_tracking(2, 1.0)
    graph = CommGraph.line(2, delay=1)
    rows: list[tuple[str, Callable[[], Any], str]] = [
        ("system-A-complex", lambda: system(A=I2 * (1 + 1j)), "A"),
        ("system-A-complex-list", lambda: system(A=[[1 + 0j, 0], [0, 1]]), "A"),
        ("system-C-complex", lambda: system(C=[[[1j, 0.0]], [[0.0, 1.0]]]), "C[0]"),
        ("system-R-complex", lambda: system(R=[0.5 + 0j, 0.5]), "R[0]"),
        ("system-Q-complex", lambda: system(Q=np.array([[1, 0], [0, 1j]])), "Q"),
        ("system-Sigma-complex", lambda: system(Sigma_x=complex(1, 0)), "Sigma_x"),
        ("system-A-nan", lambda: system(A=[[np.nan, 0], [0, 1]]), "A"),
        ("system-A-ragged", lambda: system(A=[[1.0, 0.0], [1.0]]), "A"),
        ("system-A-object", lambda: system(A=object()), "A"),
        ("system-Q-not-psd", lambda: system(Q=-1.0), "Q"),
        ("system-R-singular", lambda: system(R=[0.0, 0.5]), "R[0]"),
        ("system-C-wrong-dim", lambda: system(C=[[[1.0, 0.0, 0.0]], [[0.0, 1.0]]]), "C[0]"),
        ("system-C-R-count", lambda: system(R=[0.5]), "R"),
        ("cost-lambda-complex", lambda: TeamCost.platoon(2, lam=1 + 1j), "lambda"),
        ("cost-lambda-numpy-complex", lambda: TeamCost.platoon(2, lam=np.complex128(1)), "lambda"),
        ("api-cost-lambda-negative", lambda: TeamCost.average_tracking(2, -1.0), "lambda"),
        ("cost-S-complex", lambda: TeamCost(S=I2 * 1j, L=I2, n_agents=2), "S"),
        ("cost-n-agents-zero", lambda: TeamCost.mse(0, 2), "n_agents"),
        ("graph-n-complex", lambda: CommGraph(2 + 0j, ((0, 1, 1), (1, 0, 1))), "n_agents"),
        ("graph-delay-complex", lambda: CommGraph(2, ((0, 1, 1 + 0j), (1, 0, 1))), "delay"),
        ("graph-line-delay-complex", lambda: CommGraph.line(3, delay=1 + 0j), "delay"),
        ("graph-line-delay-zero", lambda: CommGraph.line(3, delay=0), "delay"),
        ("graph-line-n-zero", lambda: CommGraph.line(0), "n"),
        ("graph-edge-out-of-range", lambda: CommGraph(2, ((0, 3, 1),)), "edges"),
        ("graph-random-p-complex", lambda: CommGraph.random(4, p=0.5j, rng=1), "p"),
        ("pop-a-complex", lambda: PopulationModel(n_agents=10, a=1 + 1j, f=0.5), "a"),
        ("pop-f-numpy-complex", lambda: PopulationModel(n_agents=10, a=1.0, f=np.complex128(0.5)), "f"),
        ("pop-from-af-complex", lambda: PopulationModel.from_af(10, 2.0, 0.5j), "a_f"),
        ("pop-n-complex", lambda: PopulationModel(n_agents=10 + 0j, a=1.0, f=0.5), "n_agents"),
        ("api-pop-unstable-exact", lambda: exact_bulk_filter(PopulationModel(n_agents=1000, a=1.5, f=0.0), 500), "horizon"),
        ("api-pop-unstable-a_f", lambda: exact_bulk_filter(PopulationModel.from_af(1000, 1.5, 1.3), 1000), "horizon"),
        ("pop-unstable-evaluate", lambda: evaluate_population(PopulationModel(n_agents=1000, a=1.05, f=0.0), 500), "horizon"),
        ("pop-exact-horizon-zero", lambda: exact_bulk_filter(PopulationModel(n_agents=10, a=2.5, f=2.0), 0), "horizon"),
        ("pop-exact-too-long", lambda: exact_bulk_filter(PopulationModel(n_agents=10, a=2.5, f=2.0), 10**7), "horizon"),
        ("pop-fm-memory-zero", lambda: finite_memory_filter(PopulationModel(n_agents=10, a=2.5, f=2.0), 10, 0), "memory"),
        ("pop-exact-flush", lambda: exact_bulk_filter(PopulationModel(n_agents=10, a=2.5, f=2.0), 10, flush=0.5), "flush"),
        ("sample-rng-negative", lambda: teamkf.sample(good, 5, 2, rng=-1), "rng"),
        ("sample-rng-string", lambda: teamkf.sample(good, 5, 2, rng="seed"), "rng"),
        ("sample-rng-fraction", lambda: teamkf.sample(good, 5, 2, rng=1.5), "rng"),
        ("sample-steps-zero", lambda: teamkf.sample(good, 0, 2, rng=1), "n_steps"),
        ("sample-runs-zero", lambda: teamkf.sample(good, 5, 0, rng=1), "n_runs"),
        ("sample-runs-string", lambda: teamkf.sample(good, 5, "2", rng=1), "n_runs"),
        ("scenario-from-list", lambda: teamkf.scenario_from_dict([1, 2]), "scenario"),
        ("get-family-misspelled", lambda: teamkf.get_family("mtmes"), "mtmes"),
        ("register-family-bad-name", lambda: teamkf.register_family(name="Bad Name", design=len, title="x"), "name"),
        ("register-family-not-callable", lambda: teamkf.register_family(name="nodesign", design=3, title="x"), "design"),
        ("register-family-duplicate", lambda: teamkf.register_family(name="mtmse", design=len, title="x"), "name"),
        ("register-family-bad-uses", lambda: teamkf.register_family(name="baduses", design=len, title="x", uses="graf"), "uses"),
        ("register-family-bad-horizons", lambda: teamkf.register_family(name="badhz", design=len, title="x", horizons={"forever"}), "horizons"),
    ]
    # per family: the design function, its designs' filter and Monte Carlo
    structure = teamkf.InformationStructure.from_graph(graph) if hasattr(teamkf.InformationStructure, "from_graph") else graph
    for name, fam in teamkf.families().items():
        third = {"structure": structure, "graph": graph, "none": None}[fam.uses]
        H = 4

        def design(h: Any = H, fam: Any = fam, third: Any = third, **kw: Any) -> Any:
            return fam.design(good, cost, third, h, **kw)

        rows += [
            (f"{name}-horizon-zero", lambda design=design: design(0), "horizon"),
            (f"{name}-horizon-negative", lambda design=design: design(-2), "horizon"),
            (f"{name}-horizon-fraction", lambda design=design: design(2.5), "horizon"),
            (f"{name}-horizon-string", lambda design=design: design("4"), "horizon"),
            (f"{name}-horizon-bool", lambda design=design: design(True), "horizon"),
            (f"{name}-unknown-keyword", lambda fam=fam: fam.check_options({"bogus": 1}), f"{name}.bogus"),
            (f"{name}-cost-other-team", lambda fam=fam, third=third: fam.design(good, TeamCost.average_tracking(3, 1.0), third, H), "cost"),
        ]
        if fam.uses != "none":
            rows.append((f"{name}-graph-wrong-agents", lambda fam=fam: fam.design(good, cost, CommGraph.line(3), H), fam.uses))
            rows.append((f"{name}-graph-string", lambda fam=fam: fam.design(good, cost, "line", H), fam.uses))
        d = design()
        x, y = teamkf.sample(good, H, 3, rng=1)
        y_nan = [yi.copy() for yi in y]
        y_nan[1][0, 2, 0] = np.nan
        y_long = teamkf.sample(good, H + 3, 1, rng=1)[1]
        rows += [
            (f"{name}-filter-one-agent", lambda d=d, y=y: d.filter(y[:1]), "measurements"),
            (f"{name}-filter-nan", lambda d=d, y=y_nan: d.filter(y), "measurements[1]"),
            (f"{name}-filter-inf", lambda d=d, y=y: d.filter([y[0], np.full_like(y[1], np.inf)]), "measurements[1]"),
            (f"{name}-filter-complex", lambda d=d, y=y: d.filter([y[0] + 1j, y[1]]), "measurements[0]"),
            (f"{name}-filter-wrong-dy", lambda d=d, y=y: d.filter([np.concatenate([y[0], y[0]], axis=2), y[1]]), "measurements[0]"),
            (f"{name}-filter-too-long", lambda d=d, y=y_long: d.filter(y), "measurements"),
            (f"{name}-filter-not-list", lambda d=d: d.filter("y"), "measurements"),
            (f"{name}-mc-runs-one", lambda d=d: teamkf.monte_carlo({name: d}, H, 1, rng=1), "n_runs"),
            (f"{name}-mc-batch-zero", lambda d=d: teamkf.monte_carlo({name: d}, H, 4, rng=1, batch=0), "batch"),
            (f"{name}-mc-rng-negative", lambda d=d: teamkf.monte_carlo({name: d}, H, 4, rng=-1), "rng"),
            (f"{name}-mc-steps-beyond-horizon", lambda d=d: teamkf.monte_carlo({name: d}, H + 5, 4, rng=1), "n_steps"),
            (f"{name}-mc-path-unknown", lambda d=d: teamkf.monte_carlo({name: d}, H, 4, rng=1, path="fast"), "path"),
            (f"{name}-mc-too-many-runs", lambda d=d: teamkf.monte_carlo({name: d}, H, 2**64, rng=1), "n_runs"),
        ]
        if fam.uses == "structure":
            rows.append((f"{name}-run-online-nan", lambda d=d, y=y_nan: teamkf.run_online(d.agents(), y), "measurements[1]"))
            rows.append((f"{name}-run-online-too-long", lambda d=d, y=y_long: teamkf.run_online(d.agents(), y), "measurements"))
    return rows


API_ROWS = _api_rows()


# ---------------------------------------------------------------------------
# fixtures and checks
# ---------------------------------------------------------------------------
@pytest.fixture()
def workdir(tmp_path: Path) -> Path:
    (tmp_path / "adir.png").mkdir()
    (tmp_path / "afile").write_text("not a folder")
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    good = M(BASE, "name", "good")
    (tmp_path / "good.json").write_text(json.dumps(good))
    (tmp_path / "sweep.json").write_text(json.dumps(SWEEP_BASE))
    yield tmp_path
    ro.chmod(0o700)


def _check_cli(capsys: Any, argv: list[str], key: str, leftover: Path | None = None) -> None:
    rc = main(argv)
    out, err = capsys.readouterr()
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert rc == 2, (argv, rc, out, err)
    assert "Traceback" not in err, err
    errors = [ln for ln in lines if ln.startswith("teamkf: error: ")]
    assert len(errors) == 1 and lines[-1] == errors[0], f"expected exactly one error line, got {lines!r}"
    assert key in errors[0], f"the message does not name {key!r}: {errors[0]}"
    detail = errors[0].removeprefix("teamkf: error: ")
    words = ("expected", "did you mean", "missing", "unknown", "cannot", "needs", "no such", "not ", "invalid", "give ", "use ", "choose", "drop ")
    words += ("once", "set ", "remove")
    assert any(w in detail for w in words), f"the message does not say what was expected: {detail}"
    if leftover is not None:
        assert not leftover.exists(), f"{leftover} left behind"
        assert not any(p.name.startswith(f".{leftover.name}.") for p in leftover.parent.glob(".*")) if leftover.parent.exists() else True


#: a folder nobody may write into: a read-only one, or /proc/1 when the tests run as root (root writes anywhere else)
def _ro(tmp: Path) -> str:
    return "/proc/1/teamkf-ro" if os.geteuid() == 0 else str(tmp / "ro")


def _sub(s: str, tmp: Path) -> str:
    s = s.replace("{T}/ro", _ro(tmp))
    return s.replace("{T}", str(tmp)).replace("{S}", str(tmp / "good.json")).replace("{W}", str(tmp / "sweep.json"))


def _ids(rows: list[Any], prefix: str, start: int) -> list[str]:
    # the same ids in every process (pytest-xdist workers collect separately): no port number of this run in them
    return [f"{prefix}-{start + k:03d}-{r[0]}".replace(CLOSED, "tcp://127.0.0.1:CLOSED") for k, r in enumerate(rows)]


N_SCEN = len(SCENARIO_ROWS)
N_TEXT = len(TEXT_ROWS)
N_POP = len(POP_ROWS)
N_CLI = len(CLI_ROWS)
N_SWEEP = len(SWEEP_ROWS)
N_API = len(API_ROWS)


@pytest.mark.parametrize("row", SCENARIO_ROWS + POP_ROWS, ids=_ids(SCENARIO_ROWS + POP_ROWS, "scenario", 1))
def test_bad_scenario(row: tuple[str, Any, str], workdir: Path, capsys: Any) -> None:
    name, data, key = row
    path = workdir / f"{name}.json"
    path.write_text(json.dumps(data))  # NaN and Infinity tokens are accepted by teamkf's JSON reader
    _check_cli(capsys, ["evaluate", str(path)], key)
    with pytest.raises(TeamkfError) as info:
        sc = teamkf.load_scenario(path)
        sc.designs() if hasattr(sc, "designs") else sc.evaluate()
    assert key in str(info.value), str(info.value)


@pytest.mark.parametrize("row", TEXT_ROWS, ids=_ids(TEXT_ROWS, "file", N_SCEN + N_POP + 1))
def test_bad_file(row: tuple[str, str, str, str], workdir: Path, capsys: Any) -> None:
    name, suffix, text, key = row
    if name == "toml-nan-literal":
        text = 'name = "x"\nhorizon = 4\nestimators = ["mtmse"]\n[system]\nA = [[nan, 0.0], [0.0, 0.9]]\nQ = 1.0\nSigma_x = 1.0\n'
        text += '[[agents]]\nC = [[1.0, 0.0]]\nR = 0.5\n[[agents]]\nC = [[0.0, 1.0]]\nR = 0.5\n[graph]\nkind = "line"\n[cost]\nkind = "mse"\n'
    path = workdir / f"bad{suffix}"
    path.write_text(text)
    _check_cli(capsys, ["evaluate", str(path)], key)


@pytest.mark.parametrize("row", CLI_ROWS, ids=_ids(CLI_ROWS, "cli", N_SCEN + N_POP + N_TEXT + 1))
def test_bad_command_line(row: tuple[str, list[str], str, str | None], workdir: Path, capsys: Any) -> None:
    name, argv, key, leftover = row
    _check_cli(capsys, [_sub(a, workdir) for a in argv], _sub(key, workdir), Path(_sub(leftover, workdir)) if leftover else None)


@pytest.mark.parametrize("row", SWEEP_ROWS, ids=_ids(SWEEP_ROWS, "sweep", N_SCEN + N_POP + N_TEXT + N_CLI + 1))
def test_bad_sweep(row: tuple[str, Any, str], workdir: Path, capsys: Any) -> None:
    name, data, key = row
    path = workdir / f"{name}.json"
    path.write_text(json.dumps(data))
    out = workdir / f"{name}.parquet"
    _check_cli(capsys, ["sweep", str(path), "--scheduler", "serial", "--out", str(out), "--no-progress"], key, out)


@pytest.mark.parametrize("row", API_ROWS, ids=_ids(API_ROWS, "api", N_SCEN + N_POP + N_TEXT + N_CLI + N_SWEEP + 1))
def test_bad_python_input(row: tuple[str, Callable[[], Any], str]) -> None:
    name, thunk, key = row
    try:
        with pytest.raises(TeamkfError) as info:
            thunk()
    finally:
        for fam in ("nodesign", "baduses", "badhz"):
            teamkf.unregister_family(fam)
    assert key in str(info.value), f"{name}: the message does not name {key!r}: {info.value}"


SUBPROCESS_ROWS = [
    (["evaluate", "platon-4"], "platon-4"),
    (["evaluate", "platoon-4", "--monte-carlo", "1"], "--monte-carlo"),
    (["reproduce", "table1", "--scheduler", CLOSED], "--scheduler"),
    (["evalute"], "COMMAND"),
]


@pytest.mark.parametrize("row", SUBPROCESS_ROWS, ids=_ids(SUBPROCESS_ROWS, "process", N_SCEN + N_POP + N_TEXT + N_CLI + N_SWEEP + N_API + 1))
def test_bad_input_subprocess(row: tuple[list[str], str]) -> None:
    argv, key = row
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT / "src") + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    p = subprocess.run([sys.executable, "-m", "teamkf", *argv], capture_output=True, text=True, env=env, timeout=120)
    lines = [ln for ln in p.stderr.splitlines() if ln.strip()]
    assert p.returncode == 2 and p.stdout == ""
    assert len(lines) == 1 and lines[0].startswith("teamkf: error: ") and key in lines[0], p.stderr
    # with --debug the traceback is shown
    if argv[0] != "evalute":
        q = subprocess.run([sys.executable, "-m", "teamkf", "--debug", *argv], capture_output=True, text=True, env=env, timeout=120)
        assert q.returncode == 2 and "Traceback" in q.stderr


def test_campaign_size() -> None:
    total = N_SCEN + N_POP + N_TEXT + N_CLI + N_SWEEP + N_API + len(SUBPROCESS_ROWS)
    names = [r[0] for rows in (SCENARIO_ROWS, POP_ROWS, TEXT_ROWS, CLI_ROWS, SWEEP_ROWS, API_ROWS) for r in rows]
    assert len(set(names)) == len(names), "row names must be distinct"
    assert total >= 200, total
    # every registered family contributes rows
    assert {"centralized", "mtmse", "mmse", "kcf", "cikf"} <= set(FAMILIES)
    for fam in FAMILIES:
        assert sum(n.startswith(f"{fam}-") for n in names) >= 10, fam
