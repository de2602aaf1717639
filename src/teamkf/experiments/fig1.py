"""Fig. 1 of the team-MMSE paper: relative improvement of the best linear MTMSE estimator over MMSE.

Two agents observe x ~ N(0, 1) through y_i = x + v_i, v_i ~ N(0, sigma^2), and
pay eq. (1): sum_i (x - z_i)^2 + lambda (x - (z_1 + z_2)/2)^2. Both costs come
from :func:`teamkf.static_team_estimate` (Theorem 1) on the joint covariance;
the closed forms of the introduction are the tests' independent check.
Delta = (J_mmse - J*) / J* tends to sigma^2 / (2 (1 + sigma^2)^2) as lambda grows
(12.5 % at sigma = 1; 11.8 % at lambda = 100).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..estimators.team import static_team_estimate
from ..models import TeamCost
from . import ExperimentResult, plotting_available, register, save_figure

LAMBDAS = (1.0, 10.0, 100.0, 1000.0)


def improvement(sigma: float, lam: float) -> tuple[float, float, float]:
    """(J_mmse, J*, Delta) for the two-agent example."""
    s2 = sigma**2
    Sig = np.array([[1, 1, 1], [1, 1 + s2, 1], [1, 1, 1 + s2]], dtype=float)
    est = static_team_estimate(Sig, (1, 0, 1, 1), TeamCost.common_target(2, 1, lam))
    return est.mmse_cost, est.cost, (est.mmse_cost - est.cost) / est.cost


@register("fig1", "Two-agent example: improvement of MTMSE over MMSE vs sigma (Fig. 1)")
def run(out_dir: Path | None, quick: bool) -> ExperimentResult:
    sigmas = np.linspace(0.05, 3.0, 25 if quick else 120)
    curves = {lam: np.array([improvement(s, lam)[2] for s in sigmas]) for lam in LAMBDAS}
    rows = []
    for lam in LAMBDAS:
        j = int(np.argmax(curves[lam]))
        rows.append(
            {"lambda": lam, "max Delta %": 100 * curves[lam][j], "at sigma": float(sigmas[j]), "Delta % at sigma=1": 100 * improvement(1.0, lam)[2]}
        )
    limit = sigmas**2 / (2 * (1 + sigmas**2) ** 2)  # lambda -> infinity (alpha -> 1/2)
    j = int(np.argmax(limit))
    rows.append(
        {
            "lambda": float("inf"),
            "max Delta %": 100 * float(limit[j]),
            "at sigma": float(sigmas[j]),
            "Delta % at sigma=1": 100 * improvement(1.0, 1e12)[2],
        }
    )
    figures: list[str] = []
    if out_dir is not None and plotting_available():
        from ..plotting import _pyplot

        plt = _pyplot()
        fig, ax = plt.subplots(figsize=(6, 4))
        for lam in LAMBDAS:
            ax.plot(sigmas, 100 * curves[lam], label=f"lambda = {lam:g}")
        ax.set_xlabel("sigma")
        ax.set_ylabel("Delta (%)")
        ax.set_title("Fig. 1: MTMSE vs MMSE, two agents")
        ax.legend()
        save_figure(fig, out_dir, "fig1", figures)
    return ExperimentResult(
        "fig1",
        "Relative improvement Delta of MTMSE over MMSE (two-agent example)",
        rows,
        ["lambda", "max Delta %", "at sigma", "Delta % at sigma=1"],
        notes="The last row is the lambda -> infinity limit sigma^2/(2(1+sigma^2)^2), maximal (12.5 %) at sigma = 1; "
        "its last column is computed at lambda = 1e12.",
        figures=figures,
        data={"sigma": sigmas, **{f"lambda={k:g}": v for k, v in curves.items()}},
    )
