"""The bad-input campaign (issues 9, 10 and 25, rounds 1 to 3), as one table-driven test.

Every row is a bad input given as a new user would: through the ``teamkf``
command (in-process ``teamkf.cli.main([...])``, a few through a subprocess) or
the public Python API. Each must give

* Python: a :class:`~teamkf.exceptions.TeamkfError` subclass whose message
  names the offending key or argument;
* CLI: exit status 2 and exactly one stderr line
  ``teamkf: error: <key or argument>: ...`` (no traceback without ``--debug``),
  naming the key or argument and what was expected;
* no output file left behind, and nothing in the working folder written or
  overwritten (every command-line row compares a snapshot of the folder);
* a request too large for the machine: a :class:`~teamkf.exceptions.ResourceError`
  at once, before anything is allocated (rows named ``*-huge*``).

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
from teamkf.exceptions import ResourceError, TeamkfError

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
GOOD_TOML = """name = "good"
horizon = 4
estimators = ["mtmse"]
[system]
A = [[0.9, 0.1], [0.0, 0.8]]
Q = 1.0
Sigma_x = 1.0
[[agents]]
C = [[1.0, 0.0]]
R = 0.5
[[agents]]
C = [[0.0, 1.0]]
R = 0.5
[graph]
kind = "line"
[cost]
kind = "average"
lambda = 1.0
"""
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
    # issue 25: one schema (types, ranges, shapes of every key; numbers the code can represent)
    ("description-list", M(BASE, "description", ["a", "b"]), "description"),
    ("description-nul", M(BASE, "description", "a\x00b"), "description"),
    ("name-control-character", M(BASE, "name", "team\x07one"), "name"),
    ("x0_mean-strings", M(BASE, "system.x0_mean", ["a", "b"]), "system.x0_mean"),
    ("x0_mean-boolean", M(BASE, "system.x0_mean", False), "system.x0_mean"),
    ("x0_mean-wrong-length", M(BASE, "system.x0_mean", [0.0, 1.0, 2.0]), "system.x0_mean"),
    ("b-string", M(BASE, "system.b", "zero"), "system.b"),
    ("B-boolean", M(BASE, "system.B", True), "system.B"),
    ("B-wrong-rows", M(BASE, "system.B", [[1.0], [0.0], [2.0]]), "system.B"),
    ("u-without-B", M(BASE, "system.u", [0.5, 0.5]), "system.u"),
    ("D-table", M(BASE, "agents.0.D", {"rows": 1}), "agents[0].D"),
    ("d-wrong-length", M(BASE, "agents.1.d", [0.1, 0.2]), "agents[1].d"),
    ("C-one-step-sequence", M(BASE, "agents.1.C", [[[0.0, 1.0]]]), "agents[1].C"),
    ("R-one-step-sequence", M(BASE, "agents.0.R", [[[0.5]]]), "agents[0].R"),
    ("A-four-levels", M(BASE, "system.A", [[[[0.9, 0.1], [0.0, 0.8]]]] * 2), "system.A"),
    ("graph-delay-huge-integer", M(BASE, "graph.delay", 2**80), "graph.delay"),
    ("edges-agent-id-written-as-float", M(BASE, "graph", {"edges": [[0, 1.0, 1], [1, 0, 1]]}), "graph.edges"),
    ("edges-delay-huge-float", M(BASE, "graph", {"edges": [[0, 1, 1e200], [1, 0, 1]]}), "graph.edges"),
    ("cost-lambda-huge-integer", M(BASE, "cost.lambda", 10**400), "cost.lambda"),
    ("horizon-huge-integer", M(BASE, "horizon", 10**40), "horizon"),
    ("steady-common-lag-huge", M(M(BASE, "horizon", DROP), "information", {"common_lag": 300_000, "local": [[], []]}), "information.common_lag"),
    ("icf-iterations-huge", M(M(BASE, "estimators", ["icf"]), "icf", {"iterations": 10**8, "variant": "ideal"}), "icf.iterations"),
    ("hcmci-iterations-huge", M(M(BASE, "estimators", ["hcmci"]), "hcmci", {"iterations": 5 * 10**6}), "hcmci.iterations"),
    # round 3: sized from the raw tables before the n^2 graph, and every horizon sized before its loop
    ("agents-600-ring-window-huge", M(M(M(BASE, "agents", [{"C": [[1.0, 0.0]], "R": 0.5}] * 600), "graph.kind", "ring"), "horizon", DROP), "agents"),
    ("steady-graph-delay-huge", M(M(BASE, "horizon", DROP), "graph.delay", 10**9), "graph.delay"),
    ("kcf-horizon-huge", M(M(BASE, "estimators", ["kcf"]), "horizon", 10**9), "horizon"),
    ("centralized-horizon-huge", M(M(BASE, "estimators", ["centralized"]), "horizon", 2 * 10**8), "horizon"),
]

TEXT_ROWS: list[tuple[str, str, Any, str]] = [  # (name, file suffix, text or bytes, key)
    ("toml-malformed", ".toml", "name = \nhorizon = 5", "bad.toml"),
    ("toml-unclosed-table", ".toml", "[system\nA = 1", "bad.toml"),
    ("json-malformed", ".json", '{"name": "x", ', "bad.json"),
    ("json-top-level-list", ".json", "[1, 2, 3]", "bad.json"),
    ("json-trailing-comma", ".json", '{"name": "x",}', "bad.json"),
    ("file-empty-toml", ".toml", "", "system"),
    ("file-binary", ".toml", "\x00\x01\x02garbage", "bad.toml"),
    ("file-unknown-extension", ".yaml", "name: x", "bad.yaml"),
    ("toml-nan-literal", ".toml", "", "system.A"),  # filled below from BASE with A = [[nan, 0], [0, 0.9]]
    # issue 25: parsers' limits, duplicates and encodings give one line naming the file
    ("json-duplicate-key", ".json", '{"name": "a", "horizon": 4, "name": "b"}', "bad.json"),
    ("json-duplicate-nested-key", ".json", '{"name": "a", "graph": {"kind": "line", "delay": 1, "delay": 2}}', "bad.json"),
    ("json-deep-nesting", ".json", '{"name": "x", "system": ' + "[" * 200_000 + "]" * 200_000 + "}", "bad.json"),
    ("json-nesting-deeper-than-any-key", ".json", '{"name": "x", "description": ' + "[" * 500 + "]" * 500 + "}", "description"),
    ("toml-deep-nesting", ".toml", "horizon = " + "[" * 100_000 + "]" * 100_000 + "\n", "bad.toml"),
    ("json-integer-of-6000-digits", ".json", '{"name": "x", "horizon": ' + "7" * 6000 + "}", "bad.json"),
    ("toml-integer-of-5000-digits", ".toml", "horizon = " + "3" * 5000 + "\n", "bad.toml"),
    ("json-utf16", ".json", b"\xff\xfe" + '{"name": "x"}'.encode("utf-16-le"), "bad.json"),
    ("toml-utf16-no-bom", ".toml", 'name = "x"\n'.encode("utf-16-le"), "bad.toml"),
    ("toml-latin1", ".toml", 'name = "caf\xe9"\n'.encode("latin-1"), "bad.toml"),
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
    ("pop-memory-huge", M(POP, "population.memory", 3 * 10**9), "population.memory"),
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
    # issue 25: nothing lost (an output is never an input; no folder created; the extension matches the format)
    ("design-out-is-the-scenario", ["design", "{S}", "--out", "{S}"], "--out", None),
    ("design-out-link-to-the-scenario", ["design", "{S}", "--out", "{T}/link.npz"], "--out", None),
    ("design-out-relative-spelling-of-scenario", ["design", "{S}", "--out", "{T}/./adir.png/../good.json"], "--out", None),
    ("design-out-txt", ["design", "{S}", "--out", "{T}/gains.txt"], "--out", "{T}/gains.txt"),
    ("design-out-no-extension", ["design", "{S}", "--out", "{T}/gains"], "--out", "{T}/gains"),
    ("design-out-csv-onto-data", ["design", "{S}", "--out", "{T}/meas.csv"], "--out", None),
    ("design-out-missing-folder", ["design", "{S}", "--out", "{T}/typo/sub/g.npz"], "typo", "{T}/typo"),
    ("plot-missing-folder", ["evaluate", "{S}", "--plot", "{T}/typo2/p.png"], "typo2", "{T}/typo2"),
    ("plot-is-the-scenario", ["evaluate", "{T}/scen.png", "--plot", "{T}/scen.png"], "--plot", None),
    ("filter-out-is-measurements", ["filter", "{S}", "--measurements", "{T}/meas.csv", "--out", "{T}/meas.csv"], "--out", None),
    ("filter-out-is-truth", ["filter", "{S}", "--measurements", "{T}/meas.csv", "--truth", "{T}/truth.csv", "--out", "{T}/truth.csv"], "--out", None),
    (
        "filter-cost-file-is-truth",
        ["filter", "{S}", "--measurements", "{T}/meas.csv", "--truth", "{T}/est-cost.csv", "--out", "{T}/est.csv"],
        "--out",
        "{T}/est.csv",
    ),
    ("filter-out-missing-folder", ["filter", "{S}", "--measurements", "{T}/meas.csv", "--out", "{T}/typo3/e.csv"], "typo3", "{T}/typo3"),
    ("filter-out-npz", ["filter", "{S}", "--measurements", "{T}/meas.csv", "--out", "{T}/e.npz"], "--out", "{T}/e.npz"),
    ("sweep-out-missing-folder", ["sweep", "{W}", "--scheduler", "serial", "--out", "{T}/typo4/r.parquet"], "typo4", "{T}/typo4"),
    ("sweep-out-is-the-sweep-file", ["sweep", "{W}", "--scheduler", "serial", "--out", "{W}"], "sweep.json", None),
    ("reproduce-out-missing-parent", ["reproduce", "fig1", "--quick", "--out", "{T}/typo5/res"], "typo5", "{T}/typo5"),
    ("demo-out-missing-parent", ["demo", "--quick", "--out", "{T}/typo6/res"], "typo6", "{T}/typo6"),
    # issue 25: recorded data (encodings, booleans, ignored columns) and its resume folder
    ("filter-measurements-utf16", ["filter", "{S}", "--measurements", "{T}/meas16.csv", "--out", "{T}/e1.csv"], "meas16.csv", "{T}/e1.csv"),
    ("filter-measurements-booleans", ["filter", "{S}", "--measurements", "{T}/mbool.csv", "--out", "{T}/e2.csv"], "mbool.csv", "{T}/e2.csv"),
    ("filter-measurements-extra-column", ["filter", "{S}", "--measurements", "{T}/mextra.csv", "--out", "{T}/e3.csv"], "mextra.csv", "{T}/e3.csv"),
    (
        "filter-truth-binary",
        ["filter", "{S}", "--measurements", "{T}/meas.csv", "--truth", "{T}/tbin.csv", "--out", "{T}/e4.csv"],
        "tbin.csv",
        "{T}/e4.csv",
    ),
    ("sweep-resume-foreign-file", ["sweep", "{W}", "--scheduler", "serial", "--out", "{T}/res.parquet", "--resume"], "notes.txt", None),
    ("sweep-duplicate-json-key", ["sweep", "{T}/dupsweep.json", "--scheduler", "serial", "--out", "{T}/d.parquet"], "dupsweep.json", "{T}/d.parquet"),
    # issue 25: sized before started (one line, at once)
    ("mc-huge-runs", ["evaluate", "{S}", "--monte-carlo", str(10**15)], "--monte-carlo", None),
    ("scheduler-garbage-without-monte-carlo", ["evaluate", "{S}", "--scheduler", "nowhere:::"], "--scheduler", None),
    # round 3: empty output paths, duplicate names, the work-limit override, a plug-in that exits
    ("plot-empty-path", ["evaluate", "{S}", "--plot", ""], "--plot", None),
    ("design-out-empty-path", ["design", "{S}", "--out", ""], "--out", None),
    ("sweep-out-empty-path", ["sweep", "{W}", "--scheduler", "serial", "--out", ""], "--out", None),
    (
        "filter-estimators-duplicate",
        ["filter", "{S}", "--measurements", "{T}/meas.csv", "--out", "{T}/e5.csv", "--estimators", "mtmse", "mtmse"],
        "estimators",
        "{T}/e5.csv",
    ),
    ("max-hours-zero", ["--max-hours", "0", "evaluate", "{S}"], "--max-hours", None),
    ("max-hours-not-a-number", ["evaluate", "{S}", "--max-hours", "nan"], "--max-hours", None),
    ("mc-over-max-hours", ["evaluate", "{S}", "--monte-carlo", "1000000", "--max-hours", "1e-4"], "--monte-carlo", None),
    ("plugin-exits-on-import", ["--plugin", "{T}/exitplug.py", "families"], "plugin", None),
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
    ("sweep-grid-huge", M(SWEEP_BASE, "grid", {"cost.lambda": [1.0 + k for k in range(1000)], "graph.delay": list(range(1, 1001))}), "grid"),
    ("sweep-grid-horizon-huge", M(SWEEP_BASE, "grid", {"horizon": [10**9]}), "horizon"),
    ("sweep-runs-huge", M(SWEEP_BASE, "runs", 10**13), "runs"),
    ("sweep-runs-beyond-int64", M(SWEEP_BASE, "runs", 2**70), "runs"),
    ("sweep-name-control-character", M(SWEEP_BASE, "name", "a\nb"), "name"),
    ("sweep-grid-delay-huge", M(SWEEP_BASE, "grid", {"graph.delay": [10**12]}), "graph.delay"),
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
        # issue 25: every public function checks the kinds of its arguments (a TeamkfError naming it, never AttributeError/TypeError)
        ("design-system-none", lambda: teamkf.design_mtmse(None, cost, graph, 4), "system"),
        ("design-cost-string", lambda: teamkf.design_centralized(good, "mse", horizon=4), "cost"),
        ("design-graph-list", lambda: teamkf.design_kcf(good, cost, [[0, 1, 1]], 4), "graph"),
        ("mc-designs-string", lambda: teamkf.monte_carlo("mtmse", 4, 10, rng=1), "designs"),
        ("mc-design-not-a-design", lambda: teamkf.monte_carlo({"a": 3.0}, 4, 10, rng=1), "designs['a']"),
        ("sample-system-none", lambda: teamkf.sample(None, 4, 2, rng=1), "system"),
        ("run-online-agents-string", lambda: teamkf.run_online("agents", [np.zeros((1, 4, 1))] * 2), "agents"),
        ("information-from-graph-none", lambda: teamkf.InformationStructure.from_graph(None), "graph"),
        ("load-scenario-number", lambda: teamkf.load_scenario(42), "path"),
        ("evaluate-point-not-a-scenario", lambda: teamkf.evaluate_point({"name": "x"}), "scenario"),
        (
            "system-0x0",
            lambda: LinearGaussianSystem(A=np.zeros((0, 0)), Q=np.zeros((0, 0)), Sigma_x=np.zeros((0, 0)), C=[np.zeros((1, 0))], R=[1.0]),
            "A",
        ),
        ("system-C-no-rows", lambda: system(C=[np.zeros((0, 2)), [[0.0, 1.0]]]), "C[0]"),
        ("system-A-strings", lambda: system(A=[["0.9", "0"], ["0", "0.8"]]), "A"),
        ("system-Q-booleans", lambda: system(Q=np.eye(2, dtype=bool)), "Q"),
        ("cost-ring-two-agents", lambda: TeamCost.ring(2, 1.0), "n_agents"),
        ("api-cost-lambda-huge-integer", lambda: TeamCost.platoon(2, lam=10**400), "lambda"),
        ("register-family-section-name", lambda: teamkf.register_family(name="network", design=len, title="x"), "name"),
        ("option-check-not-callable", lambda: teamkf.Option(name="gain", default=1.0, check="float"), "check"),
        ("graph-complete-huge", lambda: CommGraph.complete(10**6), "n"),
        ("graph-ring-huge", lambda: CommGraph.ring(3 * 10**6), "n"),
        ("graph-delay-huge", lambda: CommGraph.ring(3, delay=10**20), "delay"),
        ("sample-huge", lambda: teamkf.sample(good, 10**6, 10**7, rng=1), "n_runs"),
        ("pop-fm-memory-huge", lambda: finite_memory_filter(PopulationModel(n_agents=10, a=2.5, f=2.0), 10, 10**9), "memory"),
        ("mc-huge-work", lambda: teamkf.monte_carlo({"c": teamkf.design_centralized(good, cost, horizon=4)}, 4, 10**15, rng=1), "n_runs"),
        ("kalman-covariances-huge", lambda: teamkf.kalman_covariances(good, 10**10), "horizon"),
        ("kcf-horizon-huge-api", lambda: teamkf.design_kcf(good, cost, graph, horizon=10**9), "horizon"),
        ("unregister-family-number", lambda: teamkf.unregister_family(3), "name"),
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
    (tmp_path / "scen.png").write_text(GOOD_TOML)  # a scenario (TOML) under a plot's name
    (tmp_path / "sweep.json").write_text(json.dumps(SWEEP_BASE))
    (tmp_path / "link.npz").symlink_to(tmp_path / "good.json")
    rows = "".join(f"{t},{i},{0.1 * (t + i):.1f}\n" for t in range(4) for i in range(2))
    (tmp_path / "meas.csv").write_text("step,agent,y0\n" + rows)
    (tmp_path / "meas16.csv").write_bytes(("step,agent,y0\n" + rows).encode("utf-16"))
    (tmp_path / "mbool.csv").write_text(
        "step,agent,y0\n" + "".join(f"{t},{i},{'true' if (t + i) % 2 else 'false'}\n" for t in range(4) for i in range(2))
    )
    (tmp_path / "mextra.csv").write_text("step,agent,y0,battery\n" + "".join(f"{t},{i},0.5,0.9\n" for t in range(4) for i in range(2)))
    (tmp_path / "truth.csv").write_text("step,x0,x1\n" + "".join(f"{t},0.0,0.0\n" for t in range(4)))
    (tmp_path / "est-cost.csv").write_text("step,x0,x1\n" + "".join(f"{t},0.0,0.0\n" for t in range(4)))
    (tmp_path / "tbin.csv").write_bytes(bytes(range(256)) * 8)
    res = tmp_path / "res.parquet"
    res.mkdir()
    (res / "_sweep.json").write_text(json.dumps({"fingerprint": {}}))
    (res / "notes.txt").write_text("my notes")
    (tmp_path / "exitplug.py").write_text("import sys\nsys.exit(3)\n")
    (tmp_path / "dupsweep.json").write_text('{"scenario": "platoon-4", "grid": {"cost.lambda": [1.0]}, "runs": 0, "runs": 5}')
    yield tmp_path
    ro.chmod(0o700)


def _snapshot(folder: Path | None) -> dict[str, Any]:
    """Every entry under ``folder``: its kind and content (links by target), to prove that nothing was written or overwritten."""
    if folder is None:
        return {}
    out: dict[str, Any] = {}
    for p in sorted(folder.rglob("*")):
        rel = str(p.relative_to(folder))
        if p.is_symlink():
            out[rel] = ("link", os.readlink(p))
        elif p.is_dir():
            out[rel] = ("dir",)
        else:
            try:
                out[rel] = ("file", p.read_bytes())
            except OSError:
                out[rel] = ("unreadable",)
    return out


def _check_cli(capsys: Any, argv: list[str], key: str, leftover: Path | None = None, folder: Path | None = None) -> None:
    before = _snapshot(folder)
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
    after = _snapshot(folder)
    assert after == before, f"the command wrote into {folder}: {sorted(set(after.items()) ^ set(before.items()), key=str)[:3]}"
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
        sc.designs() if sc.simulates else sc.evaluate()
    assert key in str(info.value), str(info.value)


@pytest.mark.parametrize("row", TEXT_ROWS, ids=_ids(TEXT_ROWS, "file", N_SCEN + N_POP + 1))
def test_bad_file(row: tuple[str, str, Any, str], workdir: Path, capsys: Any) -> None:
    name, suffix, text, key = row
    if name == "toml-nan-literal":
        text = 'name = "x"\nhorizon = 4\nestimators = ["mtmse"]\n[system]\nA = [[nan, 0.0], [0.0, 0.9]]\nQ = 1.0\nSigma_x = 1.0\n'
        text += '[[agents]]\nC = [[1.0, 0.0]]\nR = 0.5\n[[agents]]\nC = [[0.0, 1.0]]\nR = 0.5\n[graph]\nkind = "line"\n[cost]\nkind = "mse"\n'
    path = workdir / f"bad{suffix}"
    path.write_bytes(text) if isinstance(text, bytes) else path.write_text(text, encoding="utf-8")
    _check_cli(capsys, ["evaluate", str(path)], key)


@pytest.mark.parametrize("row", CLI_ROWS, ids=_ids(CLI_ROWS, "cli", N_SCEN + N_POP + N_TEXT + 1))
def test_bad_command_line(row: tuple[str, list[str], str, str | None], workdir: Path, capsys: Any) -> None:
    name, argv, key, leftover = row
    _check_cli(capsys, [_sub(a, workdir) for a in argv], _sub(key, workdir), Path(_sub(leftover, workdir)) if leftover else None, workdir)


@pytest.mark.parametrize("row", SWEEP_ROWS, ids=_ids(SWEEP_ROWS, "sweep", N_SCEN + N_POP + N_TEXT + N_CLI + 1))
def test_bad_sweep(row: tuple[str, Any, str], workdir: Path, capsys: Any) -> None:
    name, data, key = row
    path = workdir / f"{name}.json"
    path.write_text(json.dumps(data))
    out = workdir / f"{name}.parquet"
    _check_cli(capsys, ["sweep", str(path), "--scheduler", "serial", "--out", str(out), "--no-progress"], key, out, workdir)


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
    if name in RESOURCE_ROWS:  # too large for the machine: refused before anything is allocated
        assert isinstance(info.value, ResourceError), (name, type(info.value))


#: the API rows that must end in a ResourceError (sized before started)
RESOURCE_ROWS = {
    "graph-complete-huge",
    "graph-ring-huge",
    "sample-huge",
    "pop-fm-memory-huge",
    "mc-huge-work",
    "kalman-covariances-huge",
    "kcf-horizon-huge-api",
}


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
