"""Information shedding beyond Table I: the Pareto front of local-information size vs J*.

For the platoon of Section IV-B (line graph, unit delays, cost (6) with
lambda = 100, T = 100) every hop-window structure is enumerated (see
:mod:`teamkf.network.shedding`): per hop distance h a window of the m_h
newest measurements that can have arrived. Each is validated as realizable
and designed exactly (Theorem 2). The front is over (total local dimension,
J_T*): a structure is on it when no other is both smaller and better.

What we found: IS0 and IS1 are on the (dimension, cost) front, but IS2 is
not — m = (1, 1, 0) (own y(t) and the neighbours' y(t-1): 10 scalars per
... see the table) is smaller than IS2 and better. IS2 is on the front once
the number of communication links a structure relies on is a third
objective (IS2 uses none beyond the common part), which is the trade-off
the paper's discussion of IS1 vs IS2 is about.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Sequence

from ..estimators.team import design_mtmse
from ..network.shedding import HopWindows, hop_structures, pareto_front, pareto_front_nd
from . import ExperimentResult, plotting_available, register, save_figure
from ._common import platoon

LAMBDA, T = 100.0, 100
NAMED: dict[tuple[int, ...], str] = {(3, 2, 1): "IS0", (2, 1, 0): "IS1", (3, 0, 0): "IS2"}


@register("shedding", "Information shedding: Pareto front of local dimension vs J* (platoon)")
def run(out_dir: Path | None, quick: bool) -> ExperimentResult:
    system, cost, graph = platoon(LAMBDA)
    horizon = 40 if quick else T
    cands = hop_structures(graph, dy=system.dy)
    dims = [sum(h.structure.local_dims(system.dy)) for h in cands]
    links = [h.links() for h in cands]
    J = [design_mtmse(system, cost, h.structure, horizon).require_cost() for h in cands]
    front = set(pareto_front(dims, J))
    front3 = set(pareto_front_nd(list(zip(dims, links, J))))
    rows = []
    for idx in sorted(range(len(cands)), key=lambda i: (dims[i], J[i])):
        h = cands[idx]
        rows.append(
            {
                "structure": h.label,
                "paper name": NAMED.get(h.m, ""),
                "local scalars": dims[idx],
                "links": links[idx],
                "J_T*/lambda": J[idx] / LAMBDA,
                "on (dim, J) front": idx in front,
                "on (dim, links, J) front": idx in front3,
            }
        )
    figures: list[str] = []
    if out_dir is not None and plotting_available():
        from ..plotting import _pyplot

        plt = _pyplot()
        fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
        fr = sorted(front, key=lambda i: dims[i])
        jmin = min(J) / LAMBDA
        for ax, zoom in zip(axes, (False, True)):
            ax.scatter(dims, [j / LAMBDA for j in J], s=18, color="0.6", label="hop-window structures")
            ax.plot([dims[i] for i in fr], [J[i] / LAMBDA for i in fr], "o-", color="C0", label="Pareto front (dim, J)")
            for i, h in enumerate(cands):
                if h.m in NAMED:
                    ax.annotate(NAMED[h.m], (dims[i], J[i] / LAMBDA), textcoords="offset points", xytext=(5, 5), color="C3")
            ax.set_xlabel("total local dimension (scalars)")
            ax.set_ylabel("J_T*/lambda")
            if zoom:
                ax.set_ylim(0.98 * jmin, 1.2 * jmin)
                ax.set_title("zoom near the optimum")
            else:
                ax.set_yscale("log")
                ax.set_title("all structures")
                ax.legend()
        fig.suptitle(f"Information shedding on the platoon (lambda = {LAMBDA:g})")
        save_figure(fig, out_dir, "shedding", figures)
    return ExperimentResult(
        "shedding",
        f"Hop-window structures on the platoon: size vs J_T*/lambda (lambda = 100, T = {horizon})",
        rows,
        ["structure", "paper name", "local scalars", "links", "J_T*/lambda", "on (dim, J) front", "on (dim, links, J) front"],
        notes=(
            "m = (m_0, m_1, m_2): window length per hop distance. IS2 = (3,0,0) is dominated on the (dim, J) front by "
            "(1,1,0) under the stated model; with communication links as a third objective it is non-dominated."
        ),
        figures=figures,
        data={"dims": dims, "links": links, "J": J},
    )


def evaluate_structures(system: Any, cost: Any, structures: Sequence[HopWindows], horizon: int | None) -> list[float]:
    """MTMSE cost (total for a finite horizon, average otherwise) of each structure."""
    return [design_mtmse(system, cost, h.structure, horizon).require_cost() for h in structures]
