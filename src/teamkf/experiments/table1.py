"""Table I of the team-MMSE paper: information shedding on the 4-vehicle platoon.

IS0 is the line graph's full structure, IS1 keeps each vehicle's own
y(t-1:t) and its neighbours' y(t-1), IS2 only its own y(t-2:t); the common
part y(1:t-3) is the same. J_T*/lambda at lambda = 100, T = 100 comes from
Theorem 2 with the model of Section IV-B as printed (Sigma_x = I, which the
paper does not state).

Why the published column cannot be matched: every vehicle measures all
positions, y_i(t) = x(t) + v_i(t) with R = 0.1 I. Reporting z_i = [y_i(t)]_i
(one's own reading of one's own position) is a feasible strategy under every
structure, with error -(v_1,1, ..., v_n,n): its cost is 0.1 * sum_i S_ii per
step, so J_T*/lambda <= 0.1 * trace(S) * T / lambda (about 60.4 here) for
IS0, IS1 and IS2 alike — below all three published values (180.46, 193.72,
252.09). The bound is computed below, not typed in. The paper's ordering
IS0 < IS1 < IS2 does hold for our numbers; the gaps are smaller.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..estimators.team import design_mtmse
from . import ExperimentResult, plotting_available, register, save_figure
from ._common import platoon, platoon_structures

#: the paper's Table I, shown only as a comparison column
PUBLISHED = {"IS0": 180.46, "IS1": 193.72, "IS2": 252.09}
LAMBDA, T = 100.0, 100


@register("table1", "Information shedding on the platoon: IS0, IS1, IS2 (Table I)")
def run(out_dir: Path | None, quick: bool) -> ExperimentResult:
    system, cost, graph = platoon(LAMBDA)
    bound = 0.1 * float(np.trace(cost.S_at(0))) * T / LAMBDA  # own-reading strategy, see the module docstring
    rows = []
    stage: dict[str, np.ndarray] = {}
    for name, st in platoon_structures().items():
        st.validate_on(graph)
        d = design_mtmse(system, cost, st, T)
        vec = [len(st.local_lags(i)) for i in range(4)]
        stage[name] = np.asarray(d.stage_costs)
        rows.append(
            {
                "structure": name,
                "local vectors i in {1,4}": vec[0],
                "local vectors i in {2,3}": vec[1],
                "local scalars (total)": sum(st.local_dims(system.dy)),
                "J_T*/lambda (teamkf)": d.require_cost() / LAMBDA,
                "own-reading bound": bound,
                "J_T*/lambda (paper, Table I)": PUBLISHED[name],
            }
        )
    figures: list[str] = []
    if out_dir is not None and plotting_available():
        from ..plotting import _pyplot

        plt = _pyplot()
        fig, ax = plt.subplots(figsize=(6, 4))
        for name, c in stage.items():
            ax.plot(np.arange(1, T + 1), c / LAMBDA, label=name)
        ax.set_xlabel("t")
        ax.set_ylabel("stage cost / lambda")
        ax.set_title("Table I structures: stage costs (lambda = 100)")
        ax.legend()
        save_figure(fig, out_dir, "table1", figures)
    return ExperimentResult(
        "table1",
        "Table I: local-information size and J_T*/lambda (platoon, lambda = 100, T = 100)",
        rows,
        [
            "structure",
            "local vectors i in {1,4}",
            "local vectors i in {2,3}",
            "local scalars (total)",
            "J_T*/lambda (teamkf)",
            "own-reading bound",
            "J_T*/lambda (paper, Table I)",
        ],
        notes=(
            "The published column cannot come from the stated model: reporting one's own reading of one's own "
            f"position already gives J_T*/lambda <= 0.1 trace(S) T / lambda = {bound:.1f} under every structure "
            "(see the module docstring). Sigma_x = I is our choice; the paper does not state it."
        ),
        figures=figures,
        data={"stage_costs": stage},
    )
