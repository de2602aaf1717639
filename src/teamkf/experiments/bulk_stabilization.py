"""Bulk-filter paper, Sections 4.1 and 4.6: stabilization by finite-memory filters (Fig. 12; Figs. 2-4).

For memories n = 3, 5, 10, 50, N = 100 agents and T = 1000 steps, each point
(a, a_f) of the grid gets its memory-n gains (Theorem 2, exact for the
finite-memory closed loop; teamkf.estimators.bulk.finite_memory_filter), one
closed-loop run of 100 explicit agents, and the cost ``max_i |x_{T,i}|`` saturated
at 1000 (Fig. 12). A point counts as stabilized when the cost is below 1000.
The table also reports the exact (growing-memory) filter at a = 10, 100, 1000
with a_f = 0.9, N = 100 (Figs. 2-4): the paper's claim that it keeps the
closed loop bounded.

The paper does not give Fig. 12's grid; ours is a in [0.5, 8] (step 0.5) and
a_f in [0, 0.9] (step 0.1). Model: b = c = h = 1, unit noises, x0_mean = 0.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ..control.certainty_equivalent import map_points, simulate_population
from ..estimators.bulk import exact_bulk_filter, finite_memory_filter
from ..models.population import PopulationModel
from . import ExperimentResult, plotting_available, register, save_figure

SEED = 12
SATURATE = 1000.0
#: the exact closed loop counts as bounded when Var x_T <= BOUNDED_RATIO * Var x_{T/2}
BOUNDED_RATIO = 10.0
MEMORIES = (3, 5, 10, 50)


def stabilization_point(p: dict[str, Any]) -> dict[str, Any]:
    """One point {a, a_f, memory, n_agents, horizon, index[, seed]} -> ``max_i |x_{T,i}|`` (saturated)."""
    m = PopulationModel.from_af(int(p["n_agents"]), float(p["a"]), float(p["a_f"]), memory=int(p["memory"]))
    T = int(p["horizon"])
    ss = np.random.SeedSequence(entropy=int(p.get("seed", SEED)), spawn_key=(int(p["index"]),))
    if m.memory > 0:
        filt: Any = finite_memory_filter(m, T)
        if filt.diverged_at is not None:
            return {
                **p,
                "cost": SATURATE,
                "max_abs": float("inf"),
                "diverged_at": filt.diverged_at,
                "final_state_variance": float("inf"),
                "state_variance_ratio": float("inf"),
            }
    else:
        filt = exact_bulk_filter(m, T)
    sim = simulate_population(m, T, n_runs=1, rng=ss, filt=filt)
    sv = filt.covariances.state_variance
    v = float(sv[-1])
    with np.errstate(invalid="ignore", over="ignore"):
        raw = float(np.max(np.abs(sim.final_states[0])))
        ratio = float(sv[-1] / sv[len(sv) // 2])
    return {
        **p,
        "cost": float(sim.max_abs_final(SATURATE)[0]),
        "max_abs": raw if np.isfinite(raw) else float("inf"),
        "diverged_at": None,
        "final_state_variance": v if np.isfinite(v) else float("inf"),
        "state_variance_ratio": ratio if np.isfinite(ratio) else float("inf"),
    }


@register("bulk-stabilization", "Finite-memory bulk filters: stabilization map max_i |x_T,i| over (a, a_f) (Fig. 12)")
def run(out_dir: Path | None, quick: bool) -> ExperimentResult:
    T = 200 if quick else 1000
    N = 100
    a_grid = np.array([1.0, 3.0, 5.0, 7.0]) if quick else np.round(np.arange(0.5, 8.01, 0.5), 4)
    af_grid = np.array([0.2, 0.5, 0.8]) if quick else np.round(np.arange(0.0, 0.91, 0.1), 4)
    mems = (3, 10) if quick else MEMORIES
    pts = [{"a": float(a), "a_f": float(af), "memory": n, "n_agents": N, "horizon": T} for n in mems for af in af_grid for a in a_grid]
    for i, p in enumerate(pts):
        p["index"] = i
        p["seed"] = SEED
    res = map_points(stabilization_point, pts)
    maps = {n: np.array([[r["cost"] for r in res if r["memory"] == n and r["a_f"] == af] for af in af_grid]) for n in mems}
    ratios = {n: np.array([[r["state_variance_ratio"] for r in res if r["memory"] == n and r["a_f"] == af] for af in af_grid]) for n in mems}
    rows: list[dict[str, Any]] = []
    for n in mems:
        M = maps[n]
        ok = M < SATURATE
        bounded = ratios[n] < BOUNDED_RATIO
        row: dict[str, Any] = {
            "filter": f"memory n={n}",
            "stabilized points": int(ok.sum()),
            "of": int(ok.size),
            "bounded (exact)": int(bounded.sum()),
            "largest stabilized a (any a_f)": float(a_grid[np.flatnonzero(ok.any(axis=0))[-1]]) if ok.any() else None,
        }
        for af in (0.5, 0.9):
            j = int(np.argmin(np.abs(af_grid - af)))
            okj = np.flatnonzero(ok[j])
            row[f"largest stabilized a at a_f={af_grid[j]:g}"] = float(a_grid[okj[-1]]) if okj.size else None
        rows.append(row)
    # Figs. 2-4: the exact filter at very unstable a
    exact_pts = [
        {"a": a, "a_f": 0.9, "memory": 0, "n_agents": N, "horizon": 200 if quick else T, "index": 10**6 + i, "seed": SEED}
        for i, a in enumerate((10.0, 100.0) if quick else (10.0, 100.0, 1000.0))
    ]
    for r in map_points(stabilization_point, exact_pts):
        rows.append(
            {
                "filter": f"exact, a={r['a']:g} a_f=0.9 (Figs. 2-4)",
                "max_i |x_T,i| (not saturated)": r["max_abs"],
                "Var x_T (exact)": r["final_state_variance"],
                "Var x_T / Var x_T/2": r["state_variance_ratio"],
            }
        )
    columns = [
        "filter",
        "stabilized points",
        "of",
        "bounded (exact)",
        "largest stabilized a (any a_f)",
        "largest stabilized a at a_f=0.5",
        "largest stabilized a at a_f=0.9",
        "max_i |x_T,i| (not saturated)",
        "Var x_T (exact)",
        "Var x_T / Var x_T/2",
    ]
    figures: list[str] = []
    if out_dir is not None and plotting_available():
        from ..plotting import _pyplot

        plt = _pyplot()
        fig, axes = plt.subplots(1, len(mems), figsize=(4.2 * len(mems), 4), sharey=True)
        axes = np.atleast_1d(axes)
        for ax, n in zip(axes, mems):
            im = ax.pcolormesh(a_grid, af_grid, np.log10(np.maximum(maps[n], 1e-3)), shading="nearest", vmin=0, vmax=3, cmap="viridis")
            ax.set_title(f"memory n = {n}")
            ax.set_xlabel("a")
        axes[0].set_ylabel("a_f")
        fig.colorbar(im, ax=list(axes), label="log10 max_i |x_T,i| (saturated at 1000)")
        save_figure(fig, out_dir, "bulk-stabilization", figures)
    counts = ", ".join(f"n={n}: {int((maps[n] < SATURATE).sum())}" for n in mems)
    notes = (
        f"N = {N}, T = {T}, one run per point (seed {SEED}, one stream per point); cost saturated at {SATURATE:g}; "
        f"a point is 'stabilized' when the cost is below the saturation ({counts} of {maps[mems[0]].size}). "
        "Stabilization improves with the memory n, as in the paper's Fig. 12, but not point by point: at a = 8, "
        "a_f = 0.4 the memory-50 closed loop diverges while memory 10..30 stay bounded (the same in 80-bit arithmetic, "
        "so it is the filter, not round-off). 'bounded (exact)' counts the points whose exact memory-n closed-loop "
        f"variance does not grow (Var x_T <= {BOUNDED_RATIO:g} Var x_T/2), independent of the "
        "random run. Grid chosen by us (the paper gives none). The exact-filter rows (Figs. 2-4) give the exact "
        "state variance at T and its ratio to the variance at T/2 (1 = bounded, stationary in size); their states are "
        "large (sd ~ a^1.5 .. a^2) but bounded, as the paper reports."
    )
    return ExperimentResult(
        "bulk-stabilization",
        "Stabilization map of finite-memory bulk filters (Fig. 12)",
        rows,
        columns,
        notes=notes,
        figures=figures,
        data={"a": a_grid, "a_f": af_grid, **{f"cost n={n}": maps[n] for n in mems}},
    )
