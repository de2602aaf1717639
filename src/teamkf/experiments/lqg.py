"""Appendix D of the team-MMSE paper: decentralized LQG with one-step delayed sharing, through MTMSE.

Two agents, each controlling one input and measuring one state of a coupled,
unstable plant:

    A = [[1.05, 0.3], [0.2, 0.95]],  B = [[1, 0.6], [0.4, 1]],  Q = 0.5 I,  Sigma_x = I,
    y_1 = x_1 + v_1, y_2 = x_2 + v_2 with R = diag(0.3, 0.2),  Q_x = I,  R_u = rho I,  T = 20.

Theorem 4's controller (70) is compared with the certainty-equivalent one that
uses each agent's own MMSE estimate (the same structure with the per-agent MMSE
gains), analytically (Lemma 6 plus the MTMSE stage costs) and by closed-loop
Monte Carlo. The Kalman gain K of the common predictor does not depend on rho;
the MTMSE gains F_i do: estimation and control do not separate.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .._progress import progress
from ..control.lqg import LQGProblem, design_lqg, simulate_closed_loop
from ..models import LinearGaussianSystem
from . import ExperimentResult, plotting_available, register, save_figure

RHOS = (0.01, 0.1, 1.0, 10.0)


def problem(rho: float) -> LQGProblem:
    system = LinearGaussianSystem(A=[[1.05, 0.3], [0.2, 0.95]], Q=0.5, Sigma_x=1.0, C=[[[1.0, 0.0]], [[0.0, 1.0]]], R=[0.3, 0.2])
    return LQGProblem(system, B=[[1.0, 0.6], [0.4, 1.0]], Q_x=np.eye(2), R_u=rho * np.eye(2))


@register("lqg", "Decentralized LQG (one-step delayed sharing) via MTMSE vs certainty equivalence (Appendix D)")
def run(out_dir: Path | None, quick: bool) -> ExperimentResult:
    T, runs = 20, (4000 if quick else 20000)
    rows = []
    F_hist = []
    for rho in progress(RHOS, desc="rho", unit="point"):
        prob = problem(rho)
        opt, ce = design_lqg(prob, T), design_lqg(prob, T, kind="mmse")
        mc_opt, mc_ce = simulate_closed_loop(opt, runs, rng=7), simulate_closed_loop(ce, runs, rng=7)
        k = T // 2
        F = [float(f.ravel()[0]) for f in opt.F_at(k)]
        F_hist.append(F)
        rows.append(
            {
                "rho": rho,
                "J* (Thm 4)": opt.cost,
                "J CE": ce.cost,
                "CE excess %": 100 * (ce.cost - opt.cost) / opt.cost,
                "MC J* ": mc_opt["mean"],
                "MC J* 95% half-width": 1.96 * mc_opt["sem"],
                "MC J CE": mc_ce["mean"],
                "F_1(T/2)": F[0],
                "F_2(T/2)": F[1],
                "K(T/2)[0,0]": float(opt.estimation.K_at(k)[0, 0]),
            }
        )
    figures: list[str] = []
    if out_dir is not None and plotting_available():
        from ..plotting import _pyplot

        plt = _pyplot()
        fig, axes = plt.subplots(1, 2, figsize=(10, 4))
        axes[0].plot(RHOS, [r["J* (Thm 4)"] for r in rows], "o-", label="Theorem 4 (analytic)")
        axes[0].plot(RHOS, [r["J CE"] for r in rows], "s--", label="certainty equivalent (analytic)")
        axes[0].errorbar(RHOS, [r["MC J* "] for r in rows], yerr=[r["MC J* 95% half-width"] for r in rows], fmt="k.", label="Theorem 4 (MC)")
        axes[0].set_xscale("log")
        axes[0].set_xlabel("rho (R_u = rho I)")
        axes[0].set_ylabel("expected total cost J")
        axes[0].legend()
        Fh = np.array(F_hist)
        axes[1].plot(RHOS, Fh[:, 0], "o-", label="F_1(T/2)")
        axes[1].plot(RHOS, Fh[:, 1], "s-", label="F_2(T/2)")
        axes[1].plot(RHOS, [r["K(T/2)[0,0]"] for r in rows], "k--", label="K(T/2)[0,0] (Kalman)")
        axes[1].set_xscale("log")
        axes[1].set_xlabel("rho")
        axes[1].set_title("MTMSE gains change with the control weight")
        axes[1].legend()
        save_figure(fig, out_dir, "lqg", figures)
    return ExperimentResult(
        "lqg",
        f"Decentralized LQG, T = {T}: optimal (Theorem 4) vs certainty equivalence ({runs} closed-loop runs)",
        rows,
        list(rows[0].keys()),
        notes="K does not depend on rho; the MTMSE gains F_i do (no separation).",
        figures=figures,
    )
