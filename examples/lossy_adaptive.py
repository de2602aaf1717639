"""Pattern-adaptive features (``mtmse_lossy`` with ``resend = r`` and ``adaptive = true``) against the re-sending design
they contain, the missed-packet rule, the local filters and the lower bounds.

    PYTHONPATH=src python3 examples/lossy_adaptive.py                       # a fast look: held-out teams, 200 runs, 40 patterns
    TEAMKF_RUNS=20000 TEAMKF_PATTERNS=200 TEAMKF_KNOWN=400 PYTHONPATH=src python3 examples/lossy_adaptive.py   # docs/lossy-design.md
    TEAMKF_TEAM=platoon TEAMKF_P=0.1,0.2,0.5 PYTHONPATH=src python3 examples/lossy_adaptive.py                 # platoon-4, T = 50

Held-out teams (examples/scenarios/lossy-ring-4-unlike.toml and lossy-complete-3-unlike.toml, T = 12) at p = 0.3 and
0.5: the nominal MTMSE design over the lossy runtime with the missed-packet rule (Monte Carlo), the re-sending design
(``resend = 3``, exact), the adaptive class (the re-sending design's exact cost plus the paired difference on fresh
patterns, ± 1.96 standard errors) and its own Monte Carlo over the runtime agents, the local filters and, with
``TEAMKF_KNOWN`` patterns, the causal-knowledge bound of the same relays. The platoon: ``resend = 4`` and the adaptive
class on it at each p. Printed as Markdown rows.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

from teamkf.estimators.registry import get_family
from teamkf.estimators.team_lossy import design_mtmse_lossy, known_pattern_bound
from teamkf.simulation.links import LinkModel
from teamkf.simulation.monte_carlo import monte_carlo
from teamkf.study.scenario import load_packaged, load_scenario

# this folder (a gallery build runs a copy in docs/_examples, without __file__, from that folder)
HERE = Path(__file__).resolve().parent if "__file__" in globals() else Path.cwd()
SCENARIOS = next(d for d in (HERE / "scenarios", HERE.parents[1] / "examples" / "scenarios") if d.is_dir())

RUNS = int(os.environ.get("TEAMKF_RUNS", "200"))
PATTERNS = int(os.environ.get("TEAMKF_PATTERNS", "40"))
KNOWN = int(os.environ.get("TEAMKF_KNOWN", "0"))
R = int(os.environ.get("TEAMKF_RESEND", "3"))


def pm(x: float, h: float, digits: int = 2) -> str:
    return f"{x:.{digits}f} ± {h:.{digits}f}"


def heldout() -> None:
    print(f"| team | p | rule (MC) | resend = {R}, exact | adaptive | adaptive (MC) | local KF | causal bound (flood, resend = {R}) |")
    print("|---|---|---|---|---|---|---|---|")
    for name in ("lossy-ring-4-unlike", "lossy-complete-3-unlike"):
        sc = load_scenario(SCENARIOS / f"{name}.toml")
        T = int(sc.horizon)
        for p in (0.3, 0.5):
            d = design_mtmse_lossy(sc.system, sc.cost, sc.graph, T, p_drop=p, items="measurements", resend=R, adaptive=True, patterns=PATTERNS)
            nominal = get_family("mtmse").build(sc.system, sc.cost, graph=sc.graph, structure=sc.graph, horizon=T)
            r = monte_carlo({"ad": d, "mtmse": nominal}, T, RUNS, rng=5, path="runtime", graph=sc.graph, links=LinkModel(p_drop=p))
            kb = "-"
            if KNOWN:
                b = known_pattern_bound(
                    sc.system, sc.cost, sc.graph, T, p, relay="flood", resend=R, window=6, n_patterns=KNOWN, rng=0, knowledge="causal"
                )
                kb = pm(b.value, 1.96 * b.sem, 3)
            lo, hi = d.info["interval"]
            print(
                f"| {name} | {p} | {pm(r['mtmse'].total_mean, 1.96 * r['mtmse'].total_sem)} | {d.info['resend_cost']:.3f} | "
                f"{pm(d.total_cost, (hi - lo) / 2, 3)} ({d.info['kept']}) | {pm(r['ad'].total_mean, 1.96 * r['ad'].total_sem)} | "
                f"{d.info['local_kf_cost']:.2f} | {kb} |",
                flush=True,
            )


def platoon() -> None:
    T = int(os.environ.get("TEAMKF_T", "50"))
    sc = load_packaged("platoon-4").updated({"horizon": T})
    print("| p | resend = 4, exact | adaptive (resend = 4) | paired difference | CPU s |")
    print("|---|---|---|---|---|")
    for p in (float(x) for x in os.environ.get("TEAMKF_P", "0.5").split(",")):
        t = time.process_time()
        d = design_mtmse_lossy(sc.system, sc.cost, sc.graph, T, p_drop=p, items="measurements", resend=4, adaptive=True, patterns=PATTERNS)
        lo, hi = d.info["interval"]
        pr = d.info["paired"]
        print(
            f"| {p} | {d.info['resend_cost']:.2f} | {pm(d.total_cost, (hi - lo) / 2)} ({d.info['kept']}) | "
            f"{pm(pr['diff'], 1.96 * pr['sem'])} | {time.process_time() - t:.0f} |",
            flush=True,
        )


if __name__ == "__main__":
    {"heldout": heldout, "platoon": platoon}[os.environ.get("TEAMKF_TEAM", "heldout")]()
