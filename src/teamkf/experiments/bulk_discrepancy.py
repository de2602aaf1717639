"""Bulk-filter paper, Sections 4.2-4.3: discrepancy index (62) vs a (Fig. 6) and the printed gain vectors.

delta_p = ||K_T - K_isolated|| (eq. 62) compares the exact gains at T = 1000
with the isolated Kalman FIR sequence K'_j = (a_f (1 - c K*))^{j-1} K*
(Proposition 1). In the stationary range it shrinks as N grows (the
interference of the mean vanishes); past a_m(a_f) it does not. The table
reports the gain vectors the paper prints (a = 2.5, f = 2 with N = 1000 and
N = 10^9) beside ours, and delta_p at a few a. Model: b = c = h = 1, unit
noises, x0_mean = 0.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ..control.certainty_equivalent import a_m_of_af, map_points
from ..estimators.bulk import exact_bulk_filter, isolated_gains, isolated_kalman_gain
from ..models.population import PopulationModel
from . import ExperimentResult, plotting_available, register, save_figure
from .bulk_stationarity import stationarity_point

#: last gains printed in the paper (comparison only), newest last
PAPER_VECTORS = {
    "bulk a=2.5 f=2 N=1000 (Sec. 4.2)": [-0.0006, 0.0015, 0.0018, 0.0615, 0.8628],
    "bulk a=2.5 f=2 N=1e9 (Sec. 4.3)": [0.0003, 0.0039, 0.0584, 0.8650],
    "isolated a=2.5 f=2 (Sec. 4.3)": [0.00026616, 0.0039, 0.0584, 0.8650],
}
NS = (100, 1000, 10000, 10**9)


def _fmt(v: Any, digits: int = 4) -> str:
    return "[..., " + ", ".join(f"{x:.{digits}f}" for x in v) + "]"


@register("bulk-discrepancy", "Bulk filter vs isolated Kalman sequence: discrepancy index vs a (Fig. 6)")
def run(out_dir: Path | None, quick: bool) -> ExperimentResult:
    T = 200 if quick else 1000
    afs = (0.5, 0.99)
    a_grid = np.round(np.arange(1.5, 4.01, 0.25 if quick else 0.05), 4)
    Ns = (100, 10**9) if quick else NS
    pts = [{"a": float(a), "a_f": af, "n_agents": N, "horizon": T} for af in afs for N in Ns for a in a_grid]
    res = map_points(stationarity_point, pts)
    data: dict[str, Any] = {"a": a_grid, "horizon": T}
    for af in afs:
        for N in Ns:
            data[f"delta_p a_f={af} N={N}"] = np.array([r["discrepancy"] for r in res if r["a_f"] == af and r["n_agents"] == N])
    rows: list[dict[str, Any]] = []
    # the printed vectors
    for N, key in ((1000, "bulk a=2.5 f=2 N=1000 (Sec. 4.2)"), (10**9, "bulk a=2.5 f=2 N=1e9 (Sec. 4.3)")):
        m = PopulationModel(n_agents=N, a=2.5, f=2.0)
        bf = exact_bulk_filter(m, T)
        K = bf.final_gains()
        pv = PAPER_VECTORS[key]
        rows.append(
            {
                "quantity": f"K_T, a=2.5 f=2 N={N:g}",
                "ours": _fmt(K[-len(pv) :]),
                "paper": _fmt(pv),
                "max |ours - paper|": float(np.max(np.abs(K[-len(pv) :] - np.array(pv)))),
            }
        )
    m = PopulationModel(n_agents=1, a=2.5, f=2.0)
    iso = isolated_gains(m, 4)
    pv = PAPER_VECTORS["isolated a=2.5 f=2 (Sec. 4.3)"]
    rows.append(
        {
            "quantity": "K_isolated, a=2.5 f=2",
            "ours": "[..., " + ", ".join(f"{x:.8f}" for x in iso) + "]",
            "paper": "[..., 0.00026616, 0.0039, 0.0584, 0.8650]",
            "max |ours - paper|": float(np.max(np.abs(iso - np.array(pv)))),
        }
    )
    rows.append(
        {
            "quantity": "K*(5) (eq. 6)",
            "ours": f"{isolated_kalman_gain(5.0):.4f}",
            "paper": "0.9616",
            "max |ours - paper|": abs(isolated_kalman_gain(5.0) - 0.9616),
        }
    )
    for af in afs:
        for a in (2.0, 2.5, 3.0, 3.5):
            j = int(np.argmin(np.abs(a_grid - a)))
            vals = {N: float(data[f"delta_p a_f={af} N={N}"][j]) for N in Ns}
            rows.append(
                {
                    "quantity": f"delta_p a_f={af} a={a_grid[j]:g}",
                    "ours": ", ".join(f"N={N:g}: {v:.2e}" for N, v in vals.items()),
                    "paper": "(Fig. 6, not tabulated)",
                    "max |ours - paper|": None,
                }
            )
    figures: list[str] = []
    if out_dir is not None and plotting_available():
        from ..plotting import _pyplot

        plt = _pyplot()
        fig, axes = plt.subplots(2, 1, figsize=(7, 7), sharex=True)
        for ax, af in zip(axes, afs):
            for N in Ns:
                ax.semilogy(a_grid, np.maximum(data[f"delta_p a_f={af} N={N}"], 1e-18), marker=".", label=f"N = {N:g}")
            ax.axvline(a_m_of_af(af), color="red", label="a_m(a_f)")
            ax.set_ylabel("delta_p (eq. 62)")
            ax.set_title(f"a_f = {af}, T = {T}")
            ax.legend(fontsize=8)
        axes[-1].set_xlabel("a")
        save_figure(fig, out_dir, "bulk-discrepancy", figures)
    notes = (
        f"Exact gains K_T over T = {T} against the isolated sequence of Proposition 1. The 'paper' column is "
        "printed text, for comparison only (the paper rounds to 4 decimals). Below a_m(a_f) delta_p falls like 1/N "
        "(the interference enters through Var m = O(1/N)); for N = 1e9 it jumps by orders of magnitude exactly at "
        "a_m(a_f), where the naive pair (K*(a), a_f) leaves S(a). Past it delta_p depends on the phase of the "
        "persistent oscillation at step T (Section 4.4) and is 1e-5 .. 1e-1."
    )
    return ExperimentResult(
        "bulk-discrepancy",
        "Discrepancy between bulk and isolated Kalman gains (Fig. 6)",
        rows,
        ["quantity", "ours", "paper", "max |ours - paper|"],
        notes=notes,
        figures=figures,
        data=data,
    )
