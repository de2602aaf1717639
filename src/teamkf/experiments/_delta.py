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


#: a Delta above this (in %: a million times the optimum) is drawn at the top of its panel as "diverges" (the KCF stale on an
#: unstable process grows like 1.55^t)
DIVERGED_PCT = 1e8

_X_LABELS = {"lambda/n^2": r"$\lambda / n^2$", "lambda": r"$\lambda$"}
_GROUP_MARKERS = ("o", "s", "^", "D")


def plot_deltas(rows: list[dict[str, Any]], group: str, x_name: str, title: str, out_dir: Path | None, name: str, figures: list[str]) -> None:
    """Three panels: Δ^mmse, Δ^KCF ideal (with its 95 % interval) and Δ^KCF stale (log; "diverges" past 10^8 %).

    Each family keeps its colour (:func:`~teamkf.plotting.family_color`); the groups (n = 4, 10) differ
    by marker and the KCF variants by line style, so no curve hides another; legends sit under the axes.
    """
    if out_dir is None or not plotting_available():
        return
    from ..plotting import _pyplot, family_style

    plt = _pyplot()
    fig, axes = plt.subplots(1, 3, figsize=(13, 4.4), layout="constrained")
    groups = sorted({r[group] for r in rows}) if group else [None]
    xs_all = sorted({r[x_name] for r in rows})
    top = 0.0
    for g, gval in enumerate(groups):
        rs = [r for r in rows if group == "" or r[group] == gval]
        xs = [r[x_name] for r in rs]
        suffix = f", {group} = {gval}" if group else ""
        marker = _GROUP_MARKERS[g % len(_GROUP_MARKERS)]
        axes[0].plot(xs, [r["Delta mmse %"] for r in rs], marker=marker, label="per-agent MMSE" + suffix, **family_style("mmse"))
        half = [r.get("KCF ideal 95% CI half-width %", 0.0) for r in rs]
        axes[1].errorbar(
            xs,
            [r["Delta KCF ideal %"] for r in rs],
            yerr=half,
            marker=marker,
            capsize=3,
            label="KCF ideal (Monte Carlo)" + suffix,
            **family_style("kcf ideal"),
        )
        stale = [r["Delta KCF stale %"] for r in rs]
        shown = [min(max(v, 1e-2), DIVERGED_PCT) for v in stale]
        axes[2].plot(xs, shown, marker=marker, label="KCF stale (Monte Carlo)" + suffix, **family_style("kcf stale"))
        top = max(top, *[v for v in stale if v == v])
        gone = [(x, v) for x, v in zip(xs, stale) if not v == v or v > DIVERGED_PCT]  # NaN or past the panel: diverged
        if gone:
            worst = max((v for _, v in gone if v == v), default=float("nan"))
            axes[2].annotate(
                f"{group + ' = ' + str(gval) + ': ' if group else ''}diverges (Δ up to {worst:.0e} %)",
                (gone[len(gone) // 2][0], DIVERGED_PCT),
                textcoords="offset points",
                xytext=(0, -16),
                ha="center",
                fontsize=8,
                color="0.25",
            )
    axes[0].set_title(r"(a) $\Delta^{\mathrm{mmse}}$: MTMSE vs per-agent MMSE")
    axes[1].set_title(r"(b) $\Delta^{\mathrm{KCF}}$, ideal exchange (not realizable)")
    axes[2].set_title(r"(c) $\Delta^{\mathrm{KCF}}$, stale exchange over the delays")
    axes[2].set_yscale("log")
    if top > DIVERGED_PCT:  # room above the "diverges" line for its marks
        axes[2].set_ylim(top=DIVERGED_PCT * 8)
        axes[2].axhline(DIVERGED_PCT, color="0.6", lw=0.8, ls=":")
    for ax in axes:
        ax.set_xscale("log")
        ax.set_xticks(xs_all)
        ax.set_xticklabels([f"{x:g}" for x in xs_all])
        ax.minorticks_off() if ax is not axes[2] else ax.xaxis.set_minor_locator(plt.NullLocator())
        ax.set_xlabel(_X_LABELS.get(x_name, x_name))
        ax.grid(True, which="major", color="0.92")
        ax.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.2), frameon=False, ncol=1)
    for ax in axes[:2]:
        ax.axhline(0.0, color="0.5", lw=0.8)
    axes[0].set_ylabel("relative cost of the baseline over MTMSE (%)")
    axes[1].set_ylabel("Δ (%)")
    axes[2].set_ylabel("Δ (%), log scale")
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
