"""Bulk-filter paper, Section 4.5: average LQ cost vs the feedback gain f (Figs. 10-11).

For a = 2 (stationary range) and a = 5 (persistently time-varying), each
f with ``|a_f| < 1`` and each N, the exact bulk filter is computed and

* the exact expected cost (1/T) sum_{k<T} E[x_k^2 + r u_k^2] per agent (from the
  closed-loop covariances; valid for any N, 10^9 included), and
* the paper's Monte Carlo estimate: 50 runs of N explicit agents over
  T = 1200 steps, each run's population-average cost, their mean and standard
  deviation (the paper's markers)

are reported. r = 1 (the paper does not state r; f* below uses it), b = c = h = 1,
unit noises, x0_mean = 0. The vertical line is the Riccati gain f*(a, r) (eq. 8).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ..control.certainty_equivalent import lq_cost, map_points, simulate_population
from ..estimators.bulk import exact_bulk_filter, riccati_feedback_gain
from ..models.population import PopulationModel
from . import ExperimentResult, plotting_available, register, save_figure

SEED = 2017
R_WEIGHT = 1.0


def lq_point(p: dict[str, Any]) -> dict[str, Any]:
    """One point {a, f, n_agents, horizon, runs, index} -> exact and Monte Carlo average LQ cost."""
    m = PopulationModel(n_agents=int(p["n_agents"]), a=float(p["a"]), f=float(p["f"]), r=R_WEIGHT)
    T = int(p["horizon"])
    bf = exact_bulk_filter(m, T)
    out = {**p, "exact_cost": lq_cost(m, T, filt=bf), "stationarity_index": bf.stationarity_index()}
    runs = int(p.get("runs", 0))
    if runs > 0:
        ss = np.random.SeedSequence(entropy=int(p.get("seed", SEED)), spawn_key=(int(p["index"]),))
        sim = simulate_population(m, T, n_runs=runs, rng=ss, filt=bf)
        out.update(mc_mean=float(np.mean(sim.lq_cost)), mc_std=float(np.std(sim.lq_cost, ddof=1)) if runs > 1 else 0.0)
    else:
        out.update(mc_mean=None, mc_std=None)
    return out


@register("bulk-lq-cost", "Average LQ cost of the bulk-filter closed loop vs f, a = 2 and a = 5 (Figs. 10-11)")
def run(out_dir: Path | None, quick: bool) -> ExperimentResult:
    T = 300 if quick else 1200
    runs = 5 if quick else 50
    Ns_sim = (10, 100) if quick else (10, 100, 1000)
    Ns_exact = (10**9,)
    afs = np.linspace(-0.8, 0.8, 5 if quick else 9)
    pts: list[dict[str, Any]] = []
    for a in (2.0, 5.0):
        fstar = riccati_feedback_gain(a, R_WEIGHT)
        fs = sorted({round(float(a - af), 6) for af in afs} | {round(fstar, 6)})
        for N in Ns_sim + Ns_exact:
            for f in fs:
                pts.append({"a": a, "f": f, "n_agents": N, "horizon": T, "runs": runs if N in Ns_sim else 0})
    for i, p in enumerate(pts):
        p["index"] = i
        p["seed"] = SEED
    res = map_points(lq_point, pts)
    rows = [
        {
            "a": r["a"],
            "f": r["f"],
            "a_f": round(r["a"] - r["f"], 6),
            "N": r["n_agents"],
            "exact cost": r["exact_cost"],
            "MC mean": r["mc_mean"],
            "MC std": r["mc_std"],
            "runs": r["runs"],
            "Delta (eq. 61)": r["stationarity_index"],
        }
        for r in res
    ]
    summary = []
    for a in (2.0, 5.0):
        fstar = riccati_feedback_gain(a, R_WEIGHT)
        for N in Ns_sim + Ns_exact:
            sub = [r for r in res if r["a"] == a and r["n_agents"] == N]
            best = min(sub, key=lambda r: r["exact_cost"])
            at_star = min(sub, key=lambda r: abs(r["f"] - fstar))
            summary.append(
                f"a={a:g} N={N:g}: argmin_f (grid) = {best['f']:.3f} (cost {best['exact_cost']:.4g}); "
                f"f* = {fstar:.3f} (cost {at_star['exact_cost']:.4g})"
            )
    notes = (
        f"T = {T}, {runs} runs per point for N in {Ns_sim}, exact expected cost for every N; r = {R_WEIGHT} (assumed: "
        "the paper does not state r). MC std is the standard deviation of the runs' population-average costs (the "
        "paper's markers). " + "; ".join(summary) + ". The Riccati gain f* is optimal (on the grid) only in the "
        "stationary range a = 2; at a = 5 the dual effect moves the optimum (Section 4.5)."
    )
    figures: list[str] = []
    data: dict[str, Any] = {"rows": rows}
    if out_dir is not None and plotting_available():
        from ..plotting import _pyplot

        plt = _pyplot()
        for a, fig_no in ((2.0, 10), (5.0, 11)):
            fig, ax = plt.subplots(figsize=(7, 4.5))
            for N in Ns_sim + Ns_exact:
                sub = sorted((r for r in res if r["a"] == a and r["n_agents"] == N), key=lambda r: r["f"])
                fv = np.array([r["f"] for r in sub])
                (line,) = ax.plot(fv, [r["exact_cost"] for r in sub], label=f"N = {N:g} (exact)")
                if N in Ns_sim:
                    mc = np.array([r["mc_mean"] for r in sub])
                    sd = np.array([r["mc_std"] for r in sub])
                    ax.plot(fv, mc, "o", color=line.get_color(), ms=4)
                    ax.plot(fv, mc + sd, "v", color=line.get_color(), ms=3)
                    ax.plot(fv, mc - sd, "^", color=line.get_color(), ms=3)
            ax.axvline(riccati_feedback_gain(a, R_WEIGHT), color="blue", label="f*(a, r=1)")
            ax.set_xlabel("f")
            ax.set_ylabel("average LQ cost per agent")
            ax.set_yscale("log")
            ax.set_title(f"Fig. {fig_no}: a = {a:g}, T = {T} (markers: {runs} runs, mean and +-std)")
            ax.legend(fontsize=8)
            save_figure(fig, out_dir, f"bulk-lq-cost-a{a:g}", figures)
    return ExperimentResult(
        "bulk-lq-cost",
        "Average LQ cost vs f (Figs. 10-11)",
        rows,
        ["a", "f", "a_f", "N", "exact cost", "MC mean", "MC std", "runs", "Delta (eq. 61)"],
        notes=notes,
        figures=figures,
        data=data,
    )
