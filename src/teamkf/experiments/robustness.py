"""Robustness to unreliable links: team cost against the drop probability and the jitter bound.

For the 4-vehicle platoon (line graph, unit delays) and the UAV formation with
n = 4 (complete graph, delay 2), every registered family that can be designed
for the scenario (MTMSE, per-agent MMSE, centralized, KCF, CIKF and any other
registered baseline) runs in the message-passing runtime over links that drop
each packet with probability p and delay it by 0..J extra steps
(:mod:`teamkf.simulation.links`): MTMSE, MMSE, the centralized filter, KCF,
CIKF (platoon only: it needs unit delays) and the baselines local, diffusion,
CI, ICF and HCMCI. ``mtmse-robust`` is MTMSE designed for the
delays τ + J (:func:`~teamkf.simulation.links.robust_graph`): with p = 0 it
meets every deadline and costs exactly its analytic cost. ``mtmse_lossy`` is
the drop-aware design (:mod:`teamkf.estimators.team_lossy`), designed for each
(p, J); its exact expected cost and the certified lower bound (the MTMSE cost
of the full information) are drawn dashed and dotted in its colour. Team cost J_T by
Monte Carlo with 95 % intervals; all estimators see the same sampled paths
and the same link events (common random numbers, one link stream per run).

What a missed packet does is each family's documented behaviour (the table
in ``docs/recorded-data-and-links.md``): MTMSE/MMSE replace it by its
conditional expectation given what the agent holds (common estimate and
received window); the consensus-type
filters use the neighbours that delivered (CIKF: on-time packets only;
KCF, diffusion, HCMCI: every delivered measurement, late ones delay-compensated,
and the latest estimate of each sender, the weight of a silent neighbour
going to the agent itself; CI: the latest local estimate of each sender, the
CI weights re-optimized over them; ICF: one consensus iteration over the
senders' latest pairs). At p = 1 KCF, CI, diffusion and local are each agent's
own Kalman filter; ICF and HCMCI are too, but with their own measurement
counted N times (their definitions assume consensus averages N agents'
information). The centralized filter is a bound that does not use the
network, so links do not affect it. A family whose agents cannot run with
missing packets would be listed as skipped in the notes (none today).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from . import ExperimentResult, plotting_available, register, save_figure

P_FULL = (0.0, 0.01, 0.05, 0.1, 0.2, 0.5, 1.0)
J_FULL = (0, 1, 2)
P_QUICK = (0.0, 0.2, 1.0)
J_QUICK = (0, 1)
SCENARIOS = ("platoon-4", "uav-4")
#: the drop-aware design, designed for each (p, J) of the grid; its exact expected cost and the certified
#: lower bound are drawn beside the Monte Carlo curves
LOSSY = "mtmse_lossy"


def _designs(sc: Any, jitter: int = 0) -> tuple[dict[str, Any], dict[str, str]]:
    """Every family designed for the scenario, and MTMSE for the delays τ + J when J = ``jitter`` > 0 (:func:`_with_robust`).

    Only ``mtmse-robust`` depends on the jitter bound, so :func:`run` calls this once per scenario."""
    from ..estimators.registry import families
    from ..exceptions import TeamkfError

    out, skipped = {}, {}
    for name, fam in families().items():
        if name == LOSSY:
            continue  # designed for each drop probability (run)
        if "finite" not in fam.horizons:
            skipped[name] = "no finite-horizon design"
            continue
        try:
            d = sc.design(name)
        except TeamkfError as exc:
            skipped[name] = exc.detail
            continue
        if not getattr(d, "tolerates_losses", True):
            skipped[name] = "its agents need every message (no defined behaviour for lost packets yet)"
            continue
        out[name] = d
    return _with_robust(sc, out, jitter), skipped


def _with_robust(sc: Any, designs: dict[str, Any], jitter: int) -> dict[str, Any]:
    """The designs of jitter bound J: those of :func:`_designs`, and MTMSE designed for the delays τ + J when J > 0."""
    out = dict(designs)
    if jitter > 0 and "mtmse" in out:
        from ..estimators.team import design_mtmse
        from ..simulation.links import robust_graph

        out["mtmse-robust"] = design_mtmse(sc.system, sc.cost, robust_graph(sc.graph, jitter), sc.horizon)
    return out


#: (scenario, J) -> (scenario, designs): set by :func:`run` before the grid points are mapped (forked workers inherit it)
_GRID: dict[tuple[str, int], tuple[Any, dict[str, Any]]] = {}


def _point(key: tuple[str, int, float, int, int, int]) -> tuple[tuple[float, float] | None, Any, dict[str, Any]]:
    """One grid point (scenario, J, p, T, runs, seed): the drop-aware design's (exact cost, lower bound) and the Monte Carlo.

    Independent of the other points (its own designs and the fixed seed), so the points can run in any order, in
    any process. Returns also each design's analytic cost on reliable links.
    """
    from ..estimators.registry import families
    from ..estimators.team_lossy import design_mtmse_lossy
    from ..simulation.links import LinkModel
    from ..simulation.monte_carlo import monte_carlo

    sname, J, p, T, runs, seed = key
    sc, designs = _GRID[(sname, J)]
    here = dict(designs)
    exact = None
    if LOSSY in families():
        lossy = design_mtmse_lossy(sc.system, sc.cost, sc.graph, T, p_drop=p, jitter=J)
        here[LOSSY] = lossy
        exact = (float(lossy.require_cost()), float(lossy.lower_bound))
    mc = monte_carlo(here, T, runs, rng=seed, path="runtime", graph=sc.graph, links=LinkModel(p_drop=p, jitter=J))
    return exact, mc, {name: d.total_cost for name, d in here.items()}


#: the drop probabilities of one (scenario, J) row, split into chains run one after the other in one process: the
#: most varied arrival patterns first, so the later points of a chain find most of their patterns' step maps and
#: fill gains already cached (the caches of the shared designs live in the process; the numbers do not depend on them)
CHAINS = ((0.5, 0.2, 0.1), (0.05, 0.01, 0.0, 1.0))


Key = tuple[str, int, float, int, int, int]  # (scenario, J, p, T, runs, seed): one grid point


def _chains(keys: list[Key]) -> list[list[Key]]:
    """The grid points grouped into chains (:data:`CHAINS` within each (scenario, J) row), the richest chains first.

    Every point is in exactly one chain; drop probabilities outside :data:`CHAINS` form a chain of their own.
    """
    rows: dict[tuple[str, int], list[Key]] = {}
    for key in keys:
        rows.setdefault((key[0], key[1]), []).append(key)
    groups: tuple[tuple[float, ...] | None, ...] = (*CHAINS, None)
    by_rank: list[list[list[Key]]] = [[] for _ in groups]
    for row in rows.values():
        for q, ps in enumerate(groups):
            if ps is None:
                chain = [k for k in row if all(k[2] not in c for c in CHAINS)]
            else:
                chain = [k for p in ps for k in row if k[2] == p]  # in the order of CHAINS
            if chain:
                by_rank[q].append(chain)
    # the first chain of every row, heaviest rows first (the platoon, large J: the longest windows), then the rest
    return [c for chains in by_rank for c in sorted(chains, key=lambda c: (c[0][0] != "platoon-4", -c[0][1]))]


def _chain(keys: list[Key]) -> list[Any]:
    """:func:`_point` of each key, in order, in this process."""
    return [_point(k) for k in keys]


@register("robustness", "Robustness: team cost vs packet-drop probability and jitter (platoon-4, UAV n = 4)")
def run(out_dir: Path | None, quick: bool) -> ExperimentResult:
    from ..simulation.parallel import process_map
    from ..study.scenario import load_packaged

    P, Js = (P_QUICK, J_QUICK) if quick else (P_FULL, J_FULL)
    T, runs, seed = (12, 16, 5) if quick else (50, 200, 5)
    rows: list[dict[str, Any]] = []
    notes_skipped: dict[str, str] = {}
    curves: dict[tuple[str, int, str], list[tuple[float, float, float, float]]] = {}
    # every family is designed once per scenario (MTMSE for tau + J once per J); the (scenario, J, p) points are
    # independent (each its own drop-aware design and the same seed), so they run in parallel processes
    _GRID.clear()
    keys = []
    for sname in SCENARIOS:
        sc = load_packaged(sname).updated({"horizon": T})
        designs, skipped = _designs(sc)
        notes_skipped.update({f"{sname}: {k}": v for k, v in skipped.items()})
        for J in Js:
            _GRID[(sname, J)] = (sc, _with_robust(sc, designs, J))
            keys += [(sname, J, p, T, runs, seed) for p in P]
    chains = _chains(keys)
    try:
        done = process_map(_chain, chains, desc="robustness", unit="chain")
    finally:
        _GRID.clear()
    got = {k: r for chain, res in zip(chains, done) for k, r in zip(chain, res)}
    results = [got[k] for k in keys]
    for (sname, J, p, *_), (exact, mc, analytic) in zip(keys, results):
        if exact is not None:
            for name, val in ((f"{LOSSY} (exact)", exact[0]), ("lower bound", exact[1])):
                rows.append(
                    {
                        "scenario": sname,
                        "jitter": J,
                        "p_drop": p,
                        "estimator": name,
                        "J_T (MC)": val,
                        "ci95 low": val,
                        "ci95 high": val,
                        "J_T analytic (reliable)": None,
                        "packets sent": None,
                        "dropped": None,
                    }
                )
                curves.setdefault((sname, J, name), []).append((p, val, val, val))
        for name, r in mc.items():
            lo, hi = r.ci95
            counts = r.links.counts.values() if r.links is not None else []
            sent = sum(c["sent"] for c in counts)
            lost = sum(c["dropped"] for c in counts)
            rows.append(
                {
                    "scenario": sname,
                    "jitter": J,
                    "p_drop": p,
                    "estimator": name,
                    "J_T (MC)": r.total_mean,
                    "ci95 low": lo,
                    "ci95 high": hi,
                    "J_T analytic (reliable)": analytic[name],
                    "packets sent": sent,
                    "dropped": lost,
                }
            )
            curves.setdefault((sname, J, name), []).append((p, r.total_mean, lo, hi))
    figures: list[str] = []
    if out_dir is not None and plotting_available():
        from ..plotting import _pyplot, family_style

        plt = _pyplot()
        fig, axes = plt.subplots(len(SCENARIOS), len(Js), figsize=(4.2 * len(Js), 3.6 * len(SCENARIOS)), squeeze=False)

        # one colour per family (its variants by line style: mtmse-robust dash-dot; the drop-aware design's exact
        # cost dashed and its lower bound dotted) and one marker per estimator, in every panel; the legend, beside
        # the panels, is ranked: the lowest geometric-mean cost over every panel and drop probability first
        def mean_log(name: str) -> float:
            vals = [q[1] for (_, _, n), pts in curves.items() if n == name for q in pts]
            return float(np.mean(np.log10(vals))) if vals and all(np.isfinite(v) and v > 0 for v in vals) else np.inf

        names = sorted({name for (_, _, name) in curves}, key=lambda n: (mean_log(n), n))
        style = {name: (family_style(name)["color"], "os^vDP*Xhp"[q % 10], family_style(name)["linestyle"]) for q, name in enumerate(names)}
        handles: dict[str, Any] = {}
        for a, sname in enumerate(SCENARIOS):
            for b, J in enumerate(Js):
                ax = axes[a][b]
                for (sn, jj, name), pts in sorted(curves.items()):
                    if sn != sname or jj != J:
                        continue
                    pts.sort()
                    x = np.array([q[0] for q in pts])
                    color, marker, dash = style[name]
                    if name in (LOSSY, f"{LOSSY} (exact)", "lower bound"):  # the drop-aware design: its family's colour
                        color = family_style(LOSSY)["color"]
                        dash = {LOSSY: "-", "lower bound": ":"}.get(name, "--")
                    (line,) = ax.plot(x, [q[1] for q in pts], dash, marker=marker, color=color, label=name, ms=3)
                    ax.fill_between(x, [q[2] for q in pts], [q[3] for q in pts], alpha=0.15, color=color)
                    handles.setdefault(name, line)
                ax.set_yscale("log")
                ax.set_xlabel("packet-drop probability p")
                ax.set_ylabel("J_T (Monte Carlo, 95 % CI)")
                ax.set_title(f"{sname}, jitter <= {J}")
        fig.tight_layout()
        fig.legend(  # beside the panels, never over them (the saved image widens to hold it)
            [handles[k] for k in names],
            [f"{k + 1}. {n}" for k, n in enumerate(names)],
            loc="center left",
            bbox_to_anchor=(1.0, 0.5),
            fontsize=9,
            frameon=False,
            title="ranked",
        )
        save_figure(fig, out_dir, "robustness", figures)
    skipped_txt = "; ".join(f"{k} ({v})" for k, v in notes_skipped.items())
    return ExperimentResult(
        "robustness",
        f"Team cost vs drop probability and jitter ({runs} runs, T = {T}, seed {seed})",
        rows,
        ["scenario", "jitter", "p_drop", "estimator", "J_T (MC)", "ci95 low", "ci95 high", "J_T analytic (reliable)", "packets sent", "dropped"],
        notes=(
            "Monte Carlo through the lossy runtime; mtmse-robust is designed for delays tau + J; mtmse_lossy is the drop-aware design "
            "for each (p, J) (its exact expected cost and the certified lower bound are the analytic rows). Not designed here: "
            + (skipped_txt or "none")
        ),
        figures=figures,
        data={"curves": curves},
    )
