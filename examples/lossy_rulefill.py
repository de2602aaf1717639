"""The class containing the missed-packet rule (``mtmse_lossy`` with ``fill = "held"``) against its members.

    TEAMKF_RUNS=20000 TEAMKF_PATTERNS=400 TEAMKF_KNOWN=100 PYTHONPATH=src python3 examples/lossy_rulefill.py   # docs/lossy-design.md
    PYTHONPATH=src python3 examples/lossy_rulefill.py      # a fast look (2000 runs, 60 patterns, no known-pattern bound)

Teams: the unlike-sensor line of examples/lossy_keyed.py (n = 3, T = 20) and the held-out scenarios
examples/scenarios/lossy-ring-4-unlike.toml and lossy-complete-3-unlike.toml (T = 12). For each drop
probability p: the nominal MTMSE design run over the lossy runtime with the missed-packet rule (Monte Carlo,
± 1.96 standard errors), today's drop-aware class (``items = "measurements"``, exact), the new class (its
expected cost on fresh link patterns, each pattern's moments exact, ± 1.96 standard errors; and its own Monte
Carlo), the paired difference new class − rule on the same patterns, the local filters and the known-pattern
optimum (the team told every drop, flooding relays, W = 6). Printed as a Markdown table.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

# this folder (a gallery build runs a copy in docs/_examples, without __file__, from that folder)
HERE = Path(__file__).resolve().parent if "__file__" in globals() else Path.cwd()
SCENARIOS = next(d for d in (HERE / "scenarios", HERE.parents[1] / "examples" / "scenarios") if d.is_dir())
sys.path.insert(0, str(HERE))

from lossy_keyed import unlike_line  # noqa: E402

from teamkf import CommGraph  # noqa: E402
from teamkf.estimators.team_lossy import design_mtmse_lossy, known_pattern_bound  # noqa: E402
from teamkf.simulation.links import LinkModel  # noqa: E402
from teamkf.simulation.monte_carlo import monte_carlo  # noqa: E402
from teamkf.study.scenario import load_scenario  # noqa: E402

RUNS = int(os.environ.get("TEAMKF_RUNS", "2000"))
PATTERNS = int(os.environ.get("TEAMKF_PATTERNS", "60"))
KNOWN = int(os.environ.get("TEAMKF_KNOWN", "0"))
PS = (0.3, 0.5)


def teams() -> list[tuple[str, object, object, object, int]]:
    sysm, cost = unlike_line()
    out = [("unlike line (n = 3, T = 20)", sysm, cost, CommGraph.line(3), 20)]
    for name in ("lossy-ring-4-unlike", "lossy-complete-3-unlike"):
        sc = load_scenario(SCENARIOS / f"{name}.toml")
        out.append((f"{name} (T = {sc.horizon})", sc.system, sc.cost, sc.graph, int(sc.horizon)))
    return out


def main() -> None:
    print("| team | p | rule (MC) | today's class, exact | new class | new class (MC) | new − rule (paired) | local KF | known-pattern bound |")
    print("|---|---|---|---|---|---|---|---|---|")
    for label, sysm, cost, g, T in teams():
        for p in PS:
            d = design_mtmse_lossy(sysm, cost, g, T, p_drop=p, fill="held", patterns=PATTERNS)
            r = monte_carlo({"held": d, "mtmse": d.nominal}, T, RUNS, rng=5, path="runtime", graph=g, links=LinkModel(p_drop=p))
            mc = d.info["member_costs"]
            pr = d.info["paired"].get("rule", {"diff": mc["class"]["cost"] - mc["rule"]["cost"], "sem": 0.0})
            kb = known_pattern_bound(sysm, cost, g, T, p, relay="flood", window=6, n_patterns=KNOWN, rng=0) if KNOWN else None
            kbs = f"{kb.value:.2f} ± {1.96 * kb.sem:.2f}" if kb is not None else "-"
            print(
                f"| {label} | {p} | {r['mtmse'].total_mean:.2f} ± {1.96 * r['mtmse'].total_sem:.2f} | {mc['today']['cost']:.2f} | "
                f"{d.total_cost:.2f} ± {1.96 * d.info['sem']:.2f} ({d.kept}) | {r['held'].total_mean:.2f} ± {1.96 * r['held'].total_sem:.2f} | "
                f"{pr['diff']:+.3f} ± {1.96 * pr['sem']:.3f} | {mc['local']['cost']:.2f} | {kbs} |",
                flush=True,
            )


if __name__ == "__main__":
    main()
