"""Relative improvements Delta^mmse and Delta^KCF of MTMSE over the baselines (Figs. 3 and 5)."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Callable, Sequence

from .._progress import progress
from ..estimators.kalman import design_centralized
from ..estimators.kcf import design_kcf
from ..estimators.team import design_mmse, design_mtmse
from ..simulation.monte_carlo import monte_carlo
from . import plotting_available, save_figure

EPSILON = 0.1  # consensus step of the KCF (our choice; the paper does not state it)


def delta_rows(
    build: Callable[[float], tuple[Any, Any, Any]],
    lams: Sequence[float],
    T: int,
    runs: int,
    seed: int,
    label: dict[str, Any],
    x_name: str,
    x_of: Callable[[float], float],
) -> list[dict[str, Any]]:
    """One row per lambda: J_T of every estimator and Delta = (J_baseline - J*) / J* in %."""
    rows = []
    for lam in progress(lams, desc="lambda grid", unit="point"):
        system, cost, graph = build(lam)
        t, m, c = design_mtmse(system, cost, graph, T), design_mmse(system, cost, graph, T), design_centralized(system, cost, horizon=T)
        kcf = {v: design_kcf(system, cost, graph, T, epsilon=EPSILON, variant=v) for v in ("stale", "ideal")}
        mc = monte_carlo({f"kcf-{v}": d for v, d in kcf.items()}, T, runs, rng=seed)
        J = t.require_cost()
        row = {
            **label,
            x_name: x_of(lam),
            "lambda": lam,
            "J* (MTMSE)": J,
            "J mmse": m.require_cost(),
            "J centralized": c.require_cost(),
            "J KCF stale (MC)": mc["kcf-stale"].total_mean,
            "J KCF ideal (MC)": mc["kcf-ideal"].total_mean,
            "Delta mmse %": 100 * (m.require_cost() - J) / J,
            "Delta KCF stale %": 100 * (mc["kcf-stale"].total_mean - J) / J,
            "Delta KCF ideal %": 100 * (mc["kcf-ideal"].total_mean - J) / J,
            "KCF ideal 95% CI half-width %": 100 * 1.96 * mc["kcf-ideal"].total_sem / J,
        }
        rows.append(row)
    return rows


def plot_deltas(rows: list[dict[str, Any]], group: str, x_name: str, title: str, out_dir: Path | None, name: str, figures: list[str]) -> None:
    if out_dir is None or not plotting_available():
        return
    from ..plotting import _pyplot

    plt = _pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    groups = sorted({r[group] for r in rows}) if group else [None]
    for gval in groups:
        rs = [r for r in rows if group == "" or r[group] == gval]
        xs = [r[x_name] for r in rs]
        suffix = f" ({group} = {gval})" if group else ""
        axes[0].plot(xs, [r["Delta mmse %"] for r in rs], "o-", label="MMSE" + suffix)
        axes[1].plot(xs, [max(r["Delta KCF stale %"], 1e-3) for r in rs], "o-", label="KCF stale" + suffix)
        axes[1].plot(xs, [r["Delta KCF ideal %"] for r in rs], "s--", label="KCF ideal" + suffix)
    axes[0].set_title("(a) Delta^mmse")
    axes[1].set_title("(b) Delta^KCF")
    axes[1].set_yscale("symlog", linthresh=1.0)
    for ax in axes:
        ax.set_xscale("log")
        ax.set_xlabel(x_name)
        ax.set_ylabel("relative improvement of MTMSE (%)")
        ax.axhline(0.0, color="0.5", lw=0.8)
        ax.legend(fontsize=8)
    fig.suptitle(title)
    save_figure(fig, out_dir, name, figures)


#: the columns of a delta_rows row after its x columns (fig3, fig5)
DELTA_COLUMNS = [
    "J* (MTMSE)",
    "J mmse",
    "J centralized",
    "J KCF stale (MC)",
    "J KCF ideal (MC)",
    "Delta mmse %",
    "Delta KCF stale %",
    "Delta KCF ideal %",
    "KCF ideal 95% CI half-width %",
]
