"""Fig. 5 of the team-MMSE paper: the 4-vehicle platoon (Section IV-B), Delta^mmse and Delta^KCF vs lambda.

The paper's A, C_i = I, Q = I, R = 0.1 I, Sigma_x = I (our choice), T = 100,
line graph with unit delays, cost (6). KCF as in Fig. 3 (both variants,
epsilon = 0.1, 1000 Monte Carlo paths). The platoon's A is strongly
non-normal (var x_4 grows to ~1e5), so the stale KCF (variant "stale"), which treats a
neighbour's one-step-old measurement as current, is far worse than MTMSE,
while the ideal KCF (current data exchanged within the step, not realizable
with unit delays) is close to the centralized filter.
"""

from __future__ import annotations

from pathlib import Path

from . import ExperimentResult, register
from ._common import platoon
from ._delta import DELTA_COLUMNS, EPSILON, delta_rows, plot_deltas

LAMBDAS = (1.0, 3.0, 10.0, 30.0, 100.0, 300.0, 1000.0)


@register("fig5", "Platoon: Delta^mmse and Delta^KCF vs lambda (Fig. 5)")
def run(out_dir: Path | None, quick: bool) -> ExperimentResult:
    T, runs = 100, (200 if quick else 1000)
    rows = delta_rows(platoon, LAMBDAS, T, runs, seed=2021, label={}, x_name="lambda", x_of=lambda lam: lam)
    figures: list[str] = []
    plot_deltas(rows, "", "lambda", "Fig. 5: vehicular platoon (line graph, unit delays)", out_dir, "fig5", figures)
    cols = ["lambda", *DELTA_COLUMNS]
    return ExperimentResult(
        "fig5",
        f"Platoon, T = {T}: relative improvement of MTMSE (KCF: {runs} Monte Carlo paths, epsilon = {EPSILON})",
        rows,
        cols,
        notes=__doc__.split("\n\n", 1)[1].strip() if __doc__ else "",
        figures=figures,
    )
