"""The baselines leaderboard: every family at its best and as published, ranked by exact team cost relative to MTMSE.

Networks: the UAV formation n = 4 and 10 (complete graph, delay 2,
cost (5) with lambda = n^2), the 4-vehicle platoon (line, delay 1, cost (6),
lambda = 10), a CIKF-style random field (20 sites, 20 agents, unit delays,
team MSE cost), a ring of 12 scalar sensors observing a 6-dimensional process
(unit delays, team MSE cost) and a random geometric graph of 30 sensors
(positions uniform in the unit square, edges between sensors closer than
0.35, delay = ceil(distance / 0.1)) tracking a 4-dimensional constant-velocity
target with scalar bearing-like measurements (team MSE cost). Our choices
where the references leave the model open are stated here and in
``docs/baselines.md``.

Rows per network, ranked by J / J* (ascending): MTMSE (the optimum, 1), the
centralized bound, the per-agent MMSE, the CIKF (unit-delay graphs only) and,
for every baseline family, its published defaults (honest: one
delay-compensated exchange per step), its tuned form (the family's free
parameters and fair honest forms picked on this network by the exact cost,
:mod:`teamkf.experiments.tuning`; the values in "options"), the heard-count
ICF and HCMCI (published count kept beside it) and the published ideal
variant. Every number is an exact analytic cost (no Monte Carlo): J_T = sum
of the stage costs over T = 40 steps (:data:`HORIZON`); "J / J*" is relative to the MTMSE
optimum on the same graph (>= 1 for every realizable row, a theorem; the
ideal variants exchange data inside the step, which no delay graph delivers:
"realizable" is False and they may go below 1); "last / last*" compares the
stage costs at t = T. A row whose stage cost keeps growing is marked
diverging (:func:`teamkf.experiments.tuning.diverging`: a 1.5-fold rise over
the last quarter, or sustained growth by a slope test over the second half),
and "why diverging" says why (:mod:`teamkf.experiments.divergence`):
structural (for some agents a mode of modulus >= 1 that their data cannot
detect is excited by the noise or Sigma_x and weighed by their cost: the
agents and the modes named), undetectable (their data miss a mode, but the
theorem does not force the growth) or parametric (its published parameters
on this delay graph). A structural row is marked diverging even when its
growth is still slow at t = T (its cost is unbounded: a theorem, not a
measurement).

Lossy links (``teamkf reproduce leaderboard-drops``, rows with p_drop > 0):
on the UAV formation n = 4 and the platoon, every family runs in the
message-passing runtime over links that drop each packet with probability
p in {0.1, 0.5}, with the behaviour for lost messages that its literature
gives (``docs/recorded-data-and-links.md``); team cost J_T by Monte Carlo
(T = 40, 200 runs, common random numbers, 95 % intervals), ranked relative
to MTMSE's Monte Carlo cost under the same drops. The drop-aware design
``mtmse_lossy`` (``mtmse-lossy``) is ranked there too, designed for each p,
with its exact expected cost in "J_T exact" (the Monte Carlo cost must cover
it). It is a separate command because its Monte Carlo runs (the baselines'
agents one run at a time) cost more than the exact leaderboard.

Plug-in families (``--plugin``, ``TEAMKF_PLUGINS``, entry points, ``register_family``) are ranked too,
with their published defaults (form "plug-in"), where their registry records permit: the exact
ranking takes those with an analytic cost and a finite-horizon design, the p_drop ranking those that
declare ``lossy_links``. Every other plug-in is listed, with the reason, before the run starts (on
stderr) and in these notes; so is a plug-in whose design fails on a network. Plug-in rows are not
cached (their source may change between runs).

Each network's rows are cached on disk (``$TEAMKF_CACHE_DIR``, default
``~/.cache/teamkf``; ``TEAMKF_CACHE_DIR=off`` disables it), keyed by the
network's arrays, T and the source of the estimators and of this module; a
part that does not read back as what it was written (truncated JSON, wrong keys
or types, another version) is recomputed with one ``teamkf: warning:`` line; and
networks run in parallel processes (``TEAMKF_WORKERS``, default: the number
of cores).
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import time
from pathlib import Path
from typing import Any

import numpy as np

from ..estimators import design_centralized, design_mtmse
from ..estimators.registry import families, get_family
from ..models import LinearGaussianSystem, TeamCost
from ..network import CommGraph
from . import ExperimentResult, plotting_available, register, save_figure
from ._common import platoon, uav
from ._leaderboard_cache import (  # noqa: F401  (the cache layer; _cached and ROWS_VERSION are used by the tests as leaderboard.*)
    CACHE_FORMAT,
    ROWS_VERSION,
    _cache_dir,
    _cached,
    _check_cache_dir,
    _fingerprint,
    _lossy_problem,
    _part_problem,
)
from .tuning import diverging as _diverging
from .tuning import evaluate, tune

__all__ = [
    "FAMILIES",
    "plugin_entrants",
    "HORIZON",
    "LOSSY_FAMILIES",
    "LOSSY_NETWORKS",
    "P_DROPS",
    "PARTS",
    "ROWS_VERSION",
    "assemble",
    "network_part",
    "network_rows",
    "lossy_network_rows",
    "networks",
    "run",
    "run_drops",
]

#: T of the exact rankings (quick and full alike, as the p_drop ranking): every row's stage cost has settled
#: by then on the default networks (MTMSE's within 0.02 % of its value at t = 100 by t = 20; the baselines'
#: within 1.5 % by t = 50), so J_T / J*_T ranks the steady behaviour with its transient, and a cold run of
#: the six networks fits in two minutes on two cores
HORIZON = 40

#: drop probabilities of the lossy ranking
P_DROPS = (0.1, 0.5)
#: the drop-aware design (mtmse_lossy), ranked under p_drop when it is registered (either spelling)
LOSSY_FAMILIES = ("mtmse_lossy", "mtmse-lossy")

#: (family, variants) ranked on every network
FAMILIES: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("local", ("honest",)),
    ("diffusion", ("honest", "ideal")),
    ("ci", ("honest", "ideal")),
    ("kcf", ("honest", "ideal")),
    ("icf", ("honest", "ideal")),
    ("hcmci", ("honest", "ideal")),
)


def ring_sensors(n: int = 12, dx: int = 6, *, rng: int = 12) -> tuple[LinearGaussianSystem, TeamCost, CommGraph]:
    """n scalar sensors on a ring (unit delays) observing a dx-dimensional rotating process (radius 0.98)."""
    gen = np.random.default_rng(rng)
    A = np.zeros((dx, dx))
    for b in range(dx // 2):
        th = 0.3 * (b + 1)
        A[2 * b : 2 * b + 2, 2 * b : 2 * b + 2] = 0.98 * np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
    if dx % 2:
        A[-1, -1] = 0.98
    C = []
    for _ in range(n):
        c = gen.standard_normal(dx)
        C.append((c / np.linalg.norm(c))[None])
    return LinearGaussianSystem(A=A, Q=0.1, Sigma_x=1.0, C=C, R=0.5), TeamCost.mse(n, dx), CommGraph.ring(n, 1)


def geometric_sensors(n: int = 30, *, radius: float = 0.35, hop: float = 0.1, rng: int = 30) -> tuple[LinearGaussianSystem, TeamCost, CommGraph]:
    """n sensors in the unit square, edges closer than ``radius``, delay ceil(distance / hop); constant-velocity target."""
    gen = np.random.default_rng(rng)
    for _ in range(1000):
        pos = gen.random((n, 2))
        edges = []
        for i in range(n):
            for j in range(n):
                d = float(np.linalg.norm(pos[i] - pos[j]))
                if i != j and d < radius:
                    edges.append((i, j, max(1, math.ceil(d / hop))))
        g = CommGraph(n, tuple(edges))
        if g.is_strongly_connected():
            break
    else:
        g.require_strongly_connected("graph")
    dt = 0.1
    A = np.block([[np.eye(2), dt * np.eye(2)], [np.zeros((2, 2)), np.eye(2)]])
    Q = np.block([[dt**3 / 3 * np.eye(2), dt**2 / 2 * np.eye(2)], [dt**2 / 2 * np.eye(2), dt * np.eye(2)]])
    target = np.array([0.5, 0.5])
    C = []
    for i in range(n):
        u = pos[i] - target
        u = u / max(np.linalg.norm(u), 1e-9)
        C.append(np.array([[u[0], u[1], 0.0, 0.0]]))
    return LinearGaussianSystem(A=A, Q=Q, Sigma_x=1.0, C=C, R=0.05), TeamCost.mse(n, 4), g


def networks(quick: bool) -> list[tuple[str, Any]]:
    """(name, builder) of the leaderboard's networks; ``quick`` keeps the small ones."""
    from ..study.random_field import random_field

    def field() -> tuple:
        system, graph = random_field(20, 20, rng=2024)
        return system, TeamCost.mse(20, system.dx), graph

    small = [
        ("UAV n=4 (complete, delay 2)", lambda: uav(4, 16.0)),
        ("platoon n=4 (line, delay 1)", lambda: platoon(10.0)),
    ]
    if quick:
        return small + [("ring of 6 scalar sensors, 4-dim process", lambda: ring_sensors(6, 4))]
    return small + [
        ("UAV n=10 (complete, delay 2)", lambda: uav(10, 100.0)),
        ("random field 20 sites, 20 agents (unit delays)", field),
        ("ring of 12 scalar sensors, 6-dim process", lambda: ring_sensors(12, 6)),
        ("random geometric graph, 30 sensors", lambda: geometric_sensors(30)),
    ]


def _fmt_options(opts: dict[str, Any]) -> str:
    """``k=v`` pairs of the options that are not the variant (empty: the published defaults)."""
    return ", ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}" for k, v in opts.items() if k != "variant")


def _row(
    base: dict[str, Any], estimator: str, variant: str, form: str, options: str, sc: np.ndarray, opt_sc: np.ndarray, realizable: bool, secs: Any
) -> dict[str, Any]:
    Jstar, last_star = float(np.sum(opt_sc)), float(opt_sc[-1])
    with np.errstate(over="ignore", invalid="ignore"):
        J = float(np.sum(sc))
        beats = bool(np.any(sc < opt_sc - 1e-9 * np.abs(opt_sc)))
    fin = math.isfinite(J)
    return {
        **base,
        "p_drop": 0.0,
        "estimator": estimator,
        "variant": variant,
        "form": form,
        "options": options,
        "J_T": J if fin else None,
        "J / J*": J / Jstar if fin else None,
        "J_T exact": J if fin else None,
        "last / last*": float(sc[-1]) / last_star if math.isfinite(float(sc[-1])) else None,
        "ci95 (MC)": None,
        "diverging": _diverging(sc),
        "realizable": realizable,
        "beats MTMSE at some step": beats,
        "seconds": secs,
    }


#: the parts of a network's exact rows, each computed alone (one parallel job, one cache file): "base" (MTMSE,
#: its steady state, the centralized bound, MMSE, CIKF), then each family of :data:`FAMILIES` (tuning and variants)
PARTS: tuple[str, ...] = ("base", *(f for f, _ in FAMILIES))


def _raw(estimator: str, variant: str, form: str, options: str, sc: Any, realizable: bool, secs: Any) -> dict[str, Any]:
    """One row before it is compared with MTMSE: its stage costs (JSON-ready; inf and nan kept for the cache)."""
    return {
        "estimator": estimator,
        "variant": variant,
        "form": form,
        "options": options,
        "stage_costs": [float(x) for x in np.asarray(sc, dtype=float)],
        "realizable": bool(realizable),
        "seconds": secs,
    }


def network_part(part: str, system: LinearGaussianSystem, cost: TeamCost, graph: CommGraph, T: int, quick: bool) -> dict[str, Any]:
    """The raw rows of one part of a network (:data:`PARTS`): ``{"raw": [...]}`` plus the steady state (base) or the candidates tried (a family)."""
    fams = families()
    if part == "base":
        t0 = time.perf_counter()
        opt = design_mtmse(system, cost, graph, T)
        raw = [_raw("mtmse", "", "optimum", "", opt.stage_costs, True, time.perf_counter() - t0)]
        steady = None
        if not quick and system.dx <= 10 and system.n_agents <= 12:  # the steady-state MTMSE of the larger networks is too slow here
            try:
                steady = design_mtmse(system, cost, graph, None).average_cost
            except Exception:  # noqa: BLE001  (no steady state: (A4)-(A5) fail; reported as empty)
                steady = None
        cen = design_centralized(system, cost, horizon=T)
        raw.append(_raw("centralized", "bound", "bound (holds every measurement)", "", cen.stage_costs, False, None))
        for extra in ("mmse", "cikf"):
            if extra not in fams:
                continue
            c = evaluate(extra, system, cost, graph, T, {})
            if c.error is None:
                raw.append(_raw(extra, "", "published", "", c.stage_costs, c.realizable, c.seconds))
        for r in raw:
            _explain(r, r["estimator"], {}, system, graph, None, cost)
        return {"raw": raw, "steady": steady, "n_agents": system.n_agents, "d_x": system.dx}
    variants = dict(FAMILIES)[part]
    if part not in fams:
        return {"raw": [], "tried": None}
    res = tune(part, system, cost, graph, T, variant="honest")
    tried = [{"options": _fmt_options(c.options), "J_T": c.J_T, "diverging": c.diverging, "error": c.error} for c in res.tried]
    pub, best = res.published, res.best
    tuned = (_fmt_options(best.options), bool(best.diverging)) if len(res.tried) > 1 else None
    raw = [
        _explain(
            _raw(part, "honest", "published defaults", "", pub.stage_costs, pub.realizable, pub.seconds),
            part,
            pub.options,
            system,
            graph,
            tuned,
            cost,
        )
    ]
    if len(res.tried) > 1:
        row = _raw(part, "honest", "tuned", _fmt_options(best.options) or "(published defaults)", best.stage_costs, best.realizable, best.seconds)
        raw.append(_explain(row, part, best.options, system, graph, tuned, cost))
    for c in res.tried:  # the heard-count ICF / HCMCI beside the published count
        if c.options.get("count") == "heard" and set(c.options) == {"count", "variant"} and c.error is None:
            row = _raw(part, "honest", "heard-count", "count=heard", c.stage_costs, c.realizable, c.seconds)
            raw.append(_explain(row, part, c.options, system, graph, tuned, cost))
    for v in variants:
        if v == "honest":
            continue
        c = evaluate(part, system, cost, graph, T, {"variant": v})
        if c.error is None:
            raw.append(_explain(_raw(part, v, "published", "", c.stage_costs, c.realizable, c.seconds), part, c.options, system, graph, tuned, cost))
    return {"raw": raw, "tried": tried}


#: the families the leaderboard ranks by name besides :data:`FAMILIES`: its base rows and the drop-aware design
_BY_NAME = ("mtmse", "centralized", "mmse", "cikf", *LOSSY_FAMILIES)


def plugin_entrants(lossy: bool = False) -> tuple[list[str], dict[str, str]]:
    """The registered families that are not teamkf's own: ``(ranked, left_out)``, left_out mapping name -> why.

    The exact ranking (``lossy=False``) takes a plug-in with an analytic cost and a finite-horizon design;
    the p_drop ranking (``lossy=True``) one with a finite-horizon design that declares ``lossy_links``.

    Examples
    --------
    >>> from teamkf.experiments.leaderboard import plugin_entrants
    >>> ranked, left = plugin_entrants()
    >>> isinstance(ranked, list) and isinstance(left, dict)
    True
    """
    from ..estimators._builtin import DECLARED

    own = {d.name for d in DECLARED} | set(_BY_NAME) | {f for f, _ in FAMILIES}
    ranked: list[str] = []
    left: dict[str, str] = {}
    for name, fam in families().items():
        if name in own:
            continue
        if "finite" not in fam.horizons:
            left[name] = f"it has no finite-horizon design (the leaderboard ranks J_T over T = {HORIZON} steps)"
        elif lossy and not fam.lossy_links:
            left[name] = "its record does not declare lossy_links=True (no rule for lost messages)"
        elif not lossy and not fam.analytic_cost:
            left[name] = (
                "its record declares analytic_cost=False and this ranking is by exact cost; compare it by Monte Carlo "
                "(teamkf evaluate --monte-carlo R; teamkf reproduce leaderboard-drops ranks it when it declares lossy_links)"
            )
        else:
            ranked.append(name)
    return ranked, left


def plugin_part(system: LinearGaussianSystem, cost: TeamCost, graph: CommGraph, T: int, names: list[str]) -> dict[str, Any]:
    """The exact rows of the plug-in families ``names`` on one network (published defaults); ``"failed"``: name -> error."""
    raw: list[dict[str, Any]] = []
    failed: dict[str, str] = {}
    for name in names:
        t0 = time.perf_counter()
        try:
            with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
                d = get_family(name).build(system, cost, graph=graph, structure=graph, horizon=T)
            sc = np.asarray(d.stage_costs, dtype=float) if d.stage_costs is not None else None
            if sc is None or sc.shape != (T,):
                raise ValueError(f"its design's stage_costs are {'None' if sc is None else f'of shape {sc.shape}'}, expected ({T},)")
        except Exception as exc:  # noqa: BLE001  (a user's family: any failure is reported, the ranking goes on)
            failed[name] = f"{type(exc).__name__}: {' '.join(str(exc).split())[:300]}"
            continue
        raw.append(_explain(_raw(name, "", "plug-in", "", sc, bool(d.realizable), time.perf_counter() - t0), name, {}, system, graph, None))
    return {"raw": raw, "failed": failed}


def _plugin_job(index: int, quick: bool, T: int, names: list[str]) -> dict[str, Any]:
    """The plug-in rows of network ``index`` (never cached: a plug-in's source may change between runs)."""
    name, build = networks(quick)[index]
    system, cost, graph = build()
    out = plugin_part(system, cost, graph, T, names)
    out["failed"] = {k: f"{name}: {v}" for k, v in out["failed"].items()}
    return out


def _announce(ranked: list[str], left: dict[str, str], what: str) -> str:
    """The plug-in notice: printed on stderr before the run and kept for the notes ("" without plug-ins)."""
    import sys

    lines = []
    if ranked:
        lines.append(f"plug-ins ranked ({what}): {', '.join(ranked)}")
    for name, why in left.items():
        lines.append(f"plug-in {name!r} left out: {why}")
    text = "; ".join(lines)
    if text:
        print(f"teamkf: leaderboard: {text}", file=sys.stderr, flush=True)
    return text


def _explain(
    row: dict[str, Any],
    family: str,
    options: dict[str, Any],
    system: LinearGaussianSystem,
    graph: CommGraph,
    tuned: tuple[str, bool] | None,
    cost: TeamCost | None = None,
) -> dict[str, Any]:
    """``row`` with its "why diverging" (None unless its stage costs diverge or the divergence theorem forces them to;
    :func:`~teamkf.experiments.divergence.why_diverging`)."""
    from .divergence import forced, why_diverging

    sc = np.asarray(row["stage_costs"], dtype=float)
    if _diverging(sc):
        row["why diverging"] = why_diverging(family, options, system, graph, tuned=tuned, cost=cost)
    elif forced(family, options, system, graph, cost):  # a theorem, whatever the horizon shows
        why = why_diverging(family, options, system, graph, tuned=tuned, cost=cost)
        row["why diverging"] = why + " (by the divergence theorem: the cost grows without bound, slowly on this horizon)"
    else:
        row["why diverging"] = None
    return row


def assemble(name: str, parts: dict[str, dict[str, Any]]) -> dict[str, Any]:
    """A network's exact rows (unranked, relative to its MTMSE row) and tuning record from its :data:`PARTS`."""
    b = parts["base"]
    opt_sc = np.asarray(b["raw"][0]["stage_costs"], dtype=float)
    Jstar = float(np.sum(opt_sc))
    base = {"network": name, "n_agents": b["n_agents"], "d_x": b["d_x"], "J*_avg (steady)": b["steady"]}
    rows = []
    tuning: dict[str, Any] = {}
    for part in (*PARTS, "plugins"):
        if part not in parts:
            continue
        for r in parts[part]["raw"]:
            sc = np.asarray(r["stage_costs"], dtype=float)
            rows.append(_row(base, r["estimator"], r["variant"], r["form"], r["options"], sc, opt_sc, r["realizable"], r["seconds"]))
            rows[-1]["why diverging"] = r.get("why diverging")
            rows[-1]["diverging"] = rows[-1]["diverging"] or r.get("why diverging") is not None  # structural: a theorem
        if parts[part].get("tried") is not None:  # (the plugins part has none)
            tuning[part] = [
                {
                    "options": c["options"],
                    "J / J*": c["J_T"] / Jstar if math.isfinite(c["J_T"]) else None,
                    "diverging": c["diverging"],
                    "error": c["error"],
                }
                for c in parts[part]["tried"]
            ]
    return {"rows": rows, "tuning": tuning}


def network_rows(name: str, system: LinearGaussianSystem, cost: TeamCost, graph: CommGraph, T: int, quick: bool) -> dict[str, Any]:
    """Every exact row of one network (unranked) and the tuning record, its parts one after the other; see the module docstring."""
    return assemble(name, {part: network_part(part, system, cost, graph, T, quick) for part in PARTS})


def _part_job(index: int, part: str, quick: bool, T: int) -> dict[str, Any]:
    """One part of one network's exact rows, from the disk cache when its fingerprint is there (runs in a worker process)."""
    _, build = networks(quick)[index]
    system, cost, graph = build()
    key = f"leaderboard-{'quick' if quick else 'full'}-T{T}-{_fingerprint(system, cost, graph)}-{part}"
    return _cached(key, lambda: network_part(part, system, cost, graph, T, quick), lambda out: _part_problem(out, part, T, system.n_agents))


def _lossy_job(index: int, quick: bool, tuned: dict[str, list[dict[str, Any]]], plugins: list[str] | None = None) -> dict[str, Any]:
    """One network's p_drop rows (Monte Carlo), cached like :func:`_part_job` (the key includes the tuned options); not cached with plug-ins."""
    name, build = networks(quick)[index]
    system, cost, graph = build()
    if plugins:
        failed: dict[str, str] = {}
        rows = lossy_network_rows(name, system, cost, graph, quick, tuned, plugins=plugins, failed=failed)
        return {"rows": rows, "failed": failed, "cached": False}
    tag = hashlib.sha256(json.dumps(tuned, sort_keys=True).encode()).hexdigest()[:12]
    key = f"leaderboard-lossy-{'quick' if quick else 'full'}-{_fingerprint(system, cost, graph)}-{tag}"
    return _cached(key, lambda: {"rows": lossy_network_rows(name, system, cost, graph, quick, tuned)}, _lossy_problem)


def _workers(n_jobs: int) -> int:
    from .._validation import env_count

    env = env_count("TEAMKF_WORKERS")  # not a whole number >= 1: one ArgumentError naming the variable
    return max(1, min(n_jobs, env if env is not None else os.cpu_count() or 1))


def _parallel(jobs: list[tuple[Any, tuple[Any, ...]]]) -> list[dict[str, Any]]:
    """``[f(*args) for f, args in jobs]``, in parallel processes when there are several cores (the last jobs start first)."""
    from .._progress import bar

    workers = _workers(len(jobs))
    if workers == 1:
        out = []
        with bar(len(jobs), desc="leaderboard", unit="job") as done:
            for f, args in jobs:
                out.append(f(*args))
                done.update()
        return out
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor, as_completed

    ctx = mp.get_context("fork") if "fork" in mp.get_all_start_methods() else None
    with ProcessPoolExecutor(max_workers=workers, mp_context=ctx) as ex:
        futs = {a: ex.submit(f, *args) for a, (f, args) in reversed(list(enumerate(jobs)))}  # the larger networks are listed last
        with bar(len(jobs), desc="leaderboard", unit="job") as done:  # after the workers forked: the bar's thread stays here
            for _ in as_completed(futs.values()):
                done.update()
        return [futs[a].result() for a in range(len(jobs))]


def _rank(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Rows of each (network, p_drop) sorted by J / J* ascending (diverging and missing last), with a rank column."""
    groups: dict[tuple[str, float], list[dict[str, Any]]] = {}
    for r in rows:
        groups.setdefault((r["network"], r["p_drop"]), []).append(r)
    out = []
    for grp in groups.values():
        grp.sort(key=lambda r: (r["J / J*"] is None, r["J / J*"] if r["J / J*"] is not None else 0.0))
        for a, r in enumerate(grp, 1):
            out.append({"rank": a, **r})
    return out


#: short plot labels of the rows' forms (published rows: none)
#: families whose agents send nothing: no exchange to be honest or ideal about, so no variant in their label
SENDS_NOTHING = frozenset({"local"})

_SHORT = {"tuned": "tuned", "heard-count": "heard-count", "drop-aware design": "drop-aware"}


def _label(r: dict[str, Any]) -> str:
    """``estimator variant form`` for the plot, the form shortened."""
    parts = [r["estimator"], "" if r["variant"] == "bound" or r["estimator"] in SENDS_NOTHING else r["variant"], _SHORT.get(r["form"], "")]
    return " ".join(x for x in parts if x) + (" (diverging)" if r["diverging"] else "")


def _add_lossy(
    designs: dict[str, Any], labels: dict[str, Any], key: str, fam: str, form: str, opts: dict[str, Any], system: Any, cost: Any, graph: Any, T: int
) -> None:
    """Design ``fam`` for the lossy ranking when it can be designed and has a rule for lost messages."""
    from ..exceptions import TeamkfError

    try:
        d = get_family(fam).build(system, cost, graph=graph, structure=graph, horizon=T, options=opts)
    except TeamkfError:  # a family that cannot be designed here is left out
        return
    if getattr(d, "tolerates_losses", True):
        designs[key] = d
        labels[key] = (fam, form, _fmt_options(opts))


#: the networks ranked under p_drop (indices into :func:`networks`: the UAV formation n = 4 and the platoon)
LOSSY_NETWORKS = (0, 1)


def lossy_network_rows(
    name: str,
    system: Any,
    cost: Any,
    graph: Any,
    quick: bool,
    tuned: dict[str, list[dict[str, Any]]],
    *,
    plugins: Any = (),
    failed: dict[str, str] | None = None,
) -> list[dict[str, Any]]:
    """The p_drop rankings of one network (Monte Carlo through the lossy runtime, common random numbers).

    ``tuned[family]`` are the family's candidates of the exact ranking, best first; a tuned form without a rule
    for lost messages (exact-gain diffusion) is replaced by the best candidate that has one. ``plugins``: plug-in
    families ranked too (published defaults); one whose design fails goes into ``failed`` (name -> why).
    """
    from ..simulation.links import LinkModel
    from ..simulation.monte_carlo import monte_carlo

    T, runs, seed = (12, 16, 7) if quick else (40, 200, 7)
    out: list[dict[str, Any]] = []
    fams = families()
    designs: dict[str, Any] = {}
    labels: dict[str, tuple[str, str, str]] = {}
    for fam in ("mtmse", "centralized", "mmse", "cikf"):
        if fam in fams:
            _add_lossy(designs, labels, fam, fam, "published", {}, system, cost, graph, T)
    for fam, _ in FAMILIES:
        if fam not in fams:
            continue
        _add_lossy(designs, labels, f"{fam} published", fam, "published defaults", {"variant": "honest"}, system, cost, graph, T)
        for opts in tuned.get(fam, []):  # the best candidate with a rule for lost messages; none when it is the published row
            if not opts or f"{fam} tuned" in designs:
                break
            _add_lossy(designs, labels, f"{fam} tuned", fam, "tuned", {**opts, "variant": "honest"}, system, cost, graph, T)
        if fam in ("icf", "hcmci"):
            _add_lossy(designs, labels, f"{fam} heard", fam, "heard-count", {"variant": "honest", "count": "heard"}, system, cost, graph, T)
    for fam in plugins:
        try:
            with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
                designs[fam] = get_family(fam).build(system, cost, graph=graph, structure=graph, horizon=T)
            labels[fam] = (fam, "plug-in", "")
        except Exception as exc:  # noqa: BLE001  (a user's family: reported, the ranking goes on)
            if failed is not None:
                failed[fam] = f"{name}: {type(exc).__name__}: {' '.join(str(exc).split())[:300]}"
    for p in P_DROPS:
        here, exact = dict(designs), {}
        for fam in dict.fromkeys(get_family(f).name for f in LOSSY_FAMILIES if f in fams):  # designed for this p (its option), once
            takes_p = any(o.name == "p_drop" for o in get_family(fam).options)
            _add_lossy(here, labels, fam, fam, "drop-aware design", {"p_drop": p} if takes_p else {}, system, cost, graph, T)
            if fam in here and takes_p and here[fam].total_cost is not None:
                exact[fam] = float(here[fam].total_cost)  # its exact expected cost under these drops
        mc = monte_carlo(here, T, runs, rng=seed, path="runtime", graph=graph, links=LinkModel(p_drop=p), progress=False)
        ref = mc["mtmse"].total_mean if "mtmse" in mc else float("nan")
        for key, r in mc.items():
            fam, form, opt_text = labels[key]
            lo, hi = r.ci95
            out.append(
                {
                    "network": f"{name}, T = {T}",
                    "n_agents": system.n_agents,
                    "d_x": system.dx,
                    "J*_avg (steady)": None,
                    "p_drop": p,
                    "estimator": fam,
                    "variant": "honest" if fam in dict(FAMILIES) else "",
                    "form": form,
                    "options": opt_text,
                    "J_T": float(r.total_mean),
                    "J / J*": float(r.total_mean) / ref,
                    "J_T exact": exact.get(key),
                    "last / last*": None,
                    "ci95 (MC)": f"[{lo:.6g}, {hi:.6g}] ({runs} runs)",
                    "diverging": False,
                    "why diverging": None,
                    "realizable": fam != "centralized",
                    "beats MTMSE at some step": None,
                    "seconds": None,
                }
            )
    return out


COLUMNS = [
    "rank",
    "network",
    "p_drop",
    "estimator",
    "variant",
    "form",
    "options",
    "J_T",
    "J / J*",
    "J_T exact",
    "last / last*",
    "ci95 (MC)",
    "diverging",
    "why diverging",
    "realizable",
    "beats MTMSE at some step",
    "J*_avg (steady)",
    "seconds",
]


def _exact_results(quick: bool, T: int, which: list[int], plugins: list[str] | None = None) -> list[dict[str, Any]]:
    """The exact rows and tuning records of networks ``which`` (their parts in parallel, each cached); ``"cached"``: every part was.

    ``plugins``: plug-in families ranked too (one more part per network, not cached); their failures in ``"failed"``.
    """
    _check_cache_dir()
    nets = networks(quick)
    jobs = [(i, part) for i in which for part in PARTS]
    calls: list[tuple[Any, tuple[Any, ...]]] = [(_part_job, (i, part, quick, T)) for i, part in jobs]
    if plugins:
        jobs += [(i, "plugins") for i in which]
        calls += [(_plugin_job, (i, quick, T, plugins)) for i in which]
    done = _parallel(calls)
    out = []
    for i in which:
        got = {part: res for (a, part), res in zip(jobs, done) if a == i}
        failed = got.get("plugins", {}).get("failed", {})
        cached = all(res.get("cached") for part, res in got.items() if part != "plugins")
        out.append({**assemble(nets[i][0], got), "cached": cached, "failed": failed})
    return out


def _tuned_options(results: list[dict[str, Any]]) -> dict[str, list[dict[str, Any]]]:
    """family -> its candidates of the exact ranking without divergence, cheapest first (the lossy ranking takes the first that tolerates losses)."""
    tuned: dict[str, list[dict[str, Any]]] = {}
    for res in results:
        for fam, tried in res["tuning"].items():
            ok = [c for c in tried if c["error"] is None and not c["diverging"] and c["J / J*"] is not None]
            ok.sort(key=lambda c: c["J / J*"])
            tuned[fam] = [_parse_options(c["options"]) for c in ok]
    return tuned


@register("leaderboard", "Baselines leaderboard: every family published and tuned, ranked by exact cost relative to MTMSE")
def run(out_dir: Path | None, quick: bool) -> ExperimentResult:
    """The ranked leaderboard table and plot, exact costs (``quick``: fewer and smaller networks); the p_drop ranking is :func:`run_drops`."""
    T = HORIZON
    t0 = time.perf_counter()
    nets = networks(quick)
    _check_cache_dir()  # a bad TEAMKF_CACHE_DIR is the one line, before any notice
    entrants, left = plugin_entrants()
    notice = _announce(entrants, left, "exact cost, published defaults")  # before the long run, not after it
    results = _exact_results(quick, T, list(range(len(nets))), entrants)
    ranked = _rank([r for res in results for r in res["rows"]])
    failed = [f"plug-in {k!r} left out on {v}" for res in results for k, v in res["failed"].items()]
    figures: list[str] = []
    if out_dir is not None and plotting_available():
        _plot(ranked, out_dir, figures, "leaderboard")
    cached = sum(1 for res in results if res.get("cached"))
    return ExperimentResult(
        "leaderboard",
        f"Baselines ranked by exact team cost relative to MTMSE (T = {T}), published and tuned (under p_drop: teamkf reproduce leaderboard-drops)",
        ranked,
        COLUMNS,
        notes=(__doc__.split("\n\n", 1)[1].strip() if __doc__ else "")
        + (f"\n\nPlug-ins: {'; '.join([notice, *failed] if notice else failed)}." if notice or failed else "")
        + f"\n\nNetworks from the cache: {cached} of {len(results)}; {time.perf_counter() - t0:.1f} s.",
        figures=figures,
        data={
            "T": T,
            "tuning": {name: res["tuning"] for (name, _), res in zip(nets, results)},
            "plugins": {"ranked": entrants, "left_out": {**left, **{k: v for res in results for k, v in res["failed"].items()}}},
        },
    )


@register("leaderboard-drops", "Baselines leaderboard under packet drops p_drop 0.1, 0.5: every family with its rule for lost messages, Monte Carlo")
def run_drops(out_dir: Path | None, quick: bool) -> ExperimentResult:
    """The p_drop rankings (Monte Carlo) of :data:`LOSSY_NETWORKS`, with the tuned options of the exact leaderboard (shared cache)."""
    T = HORIZON
    t0 = time.perf_counter()
    nets = networks(quick)
    _check_cache_dir()  # a bad TEAMKF_CACHE_DIR is the one line, before any notice
    entrants, left = plugin_entrants(lossy=True)
    notice = _announce(entrants, left, "Monte Carlo under p_drop, published defaults")  # before the long run, not after it
    exact = _exact_results(quick, T, list(LOSSY_NETWORKS))
    lossy = _parallel([(_lossy_job, (i, quick, _tuned_options([res]), entrants)) for i, res in zip(LOSSY_NETWORKS, exact)])
    ranked = _rank([r for res in lossy for r in res["rows"]])
    failed = [f"plug-in {k!r} left out on {v}" for res in lossy for k, v in res.get("failed", {}).items()]
    figures: list[str] = []
    if out_dir is not None and plotting_available():
        _plot(ranked, out_dir, figures, "leaderboard-drops")
    cached = sum(1 for res in [*exact, *lossy] if res.get("cached"))
    return ExperimentResult(
        "leaderboard-drops",
        f"Baselines ranked by Monte Carlo team cost relative to MTMSE under p_drop {', '.join(map(str, P_DROPS))} ({', '.join(nets[i][0] for i in LOSSY_NETWORKS)})",
        ranked,
        COLUMNS,
        notes=(__doc__.split("\n\n", 1)[1].strip() if __doc__ else "")
        + (f"\n\nPlug-ins: {'; '.join([notice, *failed] if notice else failed)}." if notice or failed else "")
        + f"\n\nParts from the cache: {cached} of {len(exact) + len(lossy)} (the exact rankings that give the tuned options, then the lossy rankings); "
        + f"{time.perf_counter() - t0:.1f} s.",
        figures=figures,
    )


def _parse_options(text: str) -> dict[str, Any]:
    """The inverse of :func:`_fmt_options` (numbers back to floats)."""
    out: dict[str, Any] = {}
    for part in filter(None, (p.strip() for p in text.split(","))):
        k, v = part.split("=", 1)
        if v in ("True", "False"):  # a bool option (ci feedback)
            out[k] = v == "True"
            continue
        try:
            out[k] = float(v)
        except ValueError:
            out[k] = v
    return out


def _plot(rows: list[dict[str, Any]], out_dir: Path, figures: list[str], name: str) -> None:
    """One panel per network (exact ranking, then the lossy ones): bars of J / J* (log), one colour per family."""
    from ..plotting import _pyplot, family_color

    plt = _pyplot()
    from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter

    panels = list(dict.fromkeys((r["network"], r["p_drop"]) for r in rows))
    ncol = 3
    nrow = math.ceil(len(panels) / ncol)
    fig, axes = plt.subplots(nrow, ncol, figsize=(6.2 * ncol, 4.6 * nrow), squeeze=False)
    seen: dict[str, Any] = {}
    for a, (net, p) in enumerate(panels):
        ax = axes[a // ncol][a % ncol]
        grp = [r for r in rows if r["network"] == net and r["p_drop"] == p]
        labels, vals, colors, hatches = [], [], [], []
        for r in grp:
            labels.append(_label(r))
            v = r["J / J*"]
            vals.append(v if v is not None and v > 0 and math.isfinite(v) else np.nan)
            colors.append(family_color(r["estimator"]))
            hatches.append("//" if not r["realizable"] else "")
        y = np.arange(len(grp))
        finite = [v for v in vals if np.isfinite(v)]
        cap = max(finite) if finite else 1.0
        shown = [min(v, 1e3) if np.isfinite(v) else cap for v in vals]
        bars = ax.barh(y, [v - 1.0 for v in shown], left=1.0, color=colors, edgecolor="k", linewidth=0.4)  # from MTMSE (1) to J/J*
        for b, h, r in zip(bars, hatches, grp):
            b.set_hatch(h)
            if h and family_color(r["estimator"]) in ("#000000", "black"):  # the hatch is drawn in the edge colour: grey on the black bound
                b.set_edgecolor("0.6")
            seen.setdefault(r["estimator"], b)
        ax.axvline(1.0, color="k", lw=0.8)
        ax.plot([1.0] * sum(r["estimator"] == "mtmse" for r in grp), [a for a, r in enumerate(grp) if r["estimator"] == "mtmse"], "ko", ms=4)
        ax.set_xscale("log")
        ax.xaxis.set_major_locator(LogLocator(base=10.0, subs=(1.0, 2.0, 5.0)))
        ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
        ax.xaxis.set_minor_formatter(NullFormatter())
        ax.set_yticks(y)
        ax.set_yticklabels(labels, fontsize=8)
        ax.invert_yaxis()
        ax.tick_params(axis="x", labelsize=8)
        ax.set_xlabel("J_T / J*_T (MTMSE = 1; log)" + ("" if p == 0 else ", Monte Carlo"), fontsize=9)
        ax.set_title(net + ("" if p == 0 else f", p_drop = {p}"), fontsize=9)
    for b in range(len(panels), nrow * ncol):
        axes[b // ncol][b % ncol].set_axis_off()
    names = list(seen)
    from matplotlib.patches import Patch

    handles = [Patch(facecolor=family_color(k), edgecolor="k", label=k) for k in names]
    handles.append(Patch(facecolor="white", edgecolor="k", hatch="//", label="not realizable (ideal / bound)"))
    fig.legend(handles=handles, loc="lower center", ncol=min(len(handles), 7), fontsize=9, frameon=False)
    what = "Monte Carlo team cost under packet drops" if name.endswith("drops") else "team cost"
    fig.suptitle(f"Baselines leaderboard: {what} relative to MTMSE on the same graph (ranked, published and tuned forms)", fontsize=11)
    fig.tight_layout(rect=(0, 0.05, 1, 0.97))
    save_figure(fig, out_dir, name, figures)
