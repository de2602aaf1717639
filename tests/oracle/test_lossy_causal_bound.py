"""The causal-knowledge bound (``knowledge="causal"``) against brute force.

At step k every agent is told the link events due before k and its own arrivals of step k, nothing of the
others' arrivals at k. Brute force: every edge-step pattern enumerated, the relays simulated packet by packet
(``_held`` of the known-pattern oracle), and at each step, for each pattern of the events due before k, the
team's expected cost written as a quadratic in **every** agent's gains for **every** one of its private
configurations by enumerating the joint configuration of all agents' arrivals at k (each term on the full joint
Gaussian law of (x, y): no common-data window, no Kalman filter, no Radner weighting), and minimized by a
least-squares solve. Then its place: above the bound of a team told every drop, below every design of the
drop-aware family (every protocol, with relay "all"), equal to MTMSE at p = 0 and the own-history optimum at p = 1.
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from teamkf import CommGraph
from teamkf.estimators.registry import get_family
from teamkf.estimators.team_lossy import design_mtmse_lossy, known_pattern_bound
from teamkf.exceptions import ArgumentError

from .test_lossy_known_pattern import _held, _joint, _tiny

T = 3


def _brute_causal(system, cost, graph, p, relay):
    n, dx, dyt, off = system.n_agents, system.dx, system.dy_total, system.offsets
    Cz = _joint(system, T)
    edges = sorted((int(a), int(b), int(d)) for (a, b, d) in graph.edges)
    events = [(a, b, t) for (a, b, _) in edges for t in range(T)]
    stages = np.zeros(T)
    for k in range(T):
        S, L = cost.S_at(k), cost.L_at(k)
        xk = np.arange(k * dx, (k + 1) * dx)
        now = [(a, b, k - d) for (a, b, d) in edges if k - d >= 0]  # the events due at k
        before = [e for e in events if e not in now]
        for bits_before in itertools.product([False, True], repeat=len(before)):
            pc = float(np.prod([(1 - p) if x else p for x in bits_before]))
            # each agent's private configurations: the bits of its in-edges due at k
            mine = [[e for e in now if e[1] == i] for i in range(n)]
            confs = [list(itertools.product([False, True], repeat=len(m))) for m in mine]
            blocks = {}  # (i, conf) -> (column offset, held rows)
            width = 0
            for i in range(n):
                for c in confs[i]:
                    ok = dict(zip(before, bits_before))
                    ok.update({e: True for e in now})  # others' bits do not change what i holds at k
                    ok.update(dict(zip(mine[i], c)))
                    held = _held(graph, ok, n, relay)[k][i]
                    rows = [T * dx + s * dyt + int(off[j]) + r for (j, s) in sorted(held) for r in range(system.dy[j])]
                    blocks[(i, c)] = (width, rows)
                    width += len(rows)
            Q = np.zeros((width, width))
            q = np.zeros(width)
            c0 = 0.0
            for joint in itertools.product(*confs):  # every agent's arrivals at k together
                pj = float(np.prod([(1 - p) if x else p for i in range(n) for x in joint[i]]))
                # cost = Tr S L Cxx L' - 2 sum_i (S L Cxy)_i g_i + sum_il S_il g_i' Cov(Y_i, Y_l) g_l, dz = 1
                for i in range(n):
                    oi, ri = blocks[(i, joint[i])]
                    q[oi : oi + len(ri)] += pj * sum(S[i, l] * (L[l] @ Cz[np.ix_(xk, ri)]) for l in range(n))
                    for l in range(n):
                        ol, rl = blocks[(l, joint[l])]
                        Q[oi : oi + len(ri), ol : ol + len(rl)] += pj * S[i, l] * Cz[np.ix_(ri, rl)]
                c0 += pj * float(np.trace(S @ L @ Cz[np.ix_(xk, xk)] @ L.T))
            g = np.linalg.lstsq(Q, q, rcond=None)[0]
            stages[k] += pc * (c0 - g @ q)
    return stages


@pytest.mark.parametrize("relay", ["flood", "all"])
@pytest.mark.parametrize(("n", "graph", "p"), [(2, CommGraph.complete(2, delay=1), 0.3), (3, CommGraph.line(3), 0.4)])
def test_causal_bound_by_enumeration(n, graph, p, relay):
    sysm, cost = _tiny(n)
    b = known_pattern_bound(sysm, cost, graph, T, p, relay=relay, knowledge="causal")
    assert b.exact and b.knowledge == "causal" and b.as_dict()["knowledge"] == "causal"
    np.testing.assert_allclose(b.stages, _brute_causal(sysm, cost, graph, p, relay), rtol=1e-10)


@pytest.mark.parametrize("p", [0.0, 0.3, 0.6, 1.0])
def test_causal_bound_between_the_told_team_and_every_design(p):
    sysm, cost = _tiny(3)
    g, Tn = CommGraph.line(3), 4
    every = known_pattern_bound(sysm, cost, g, Tn, p, relay="all")
    causal = known_pattern_bound(sysm, cost, g, Tn, p, relay="all", knowledge="causal")
    assert every.exact and causal.exact
    assert np.all(causal.stages >= every.stages - 1e-9)  # told less
    designs = [
        design_mtmse_lossy(sysm, cost, g, Tn, p_drop=p, items="measurements"),
        design_mtmse_lossy(sysm, cost, g, Tn, p_drop=p, items="innovations"),
        design_mtmse_lossy(sysm, cost, g, Tn, p_drop=p, items="measurements", resend=3),
        design_mtmse_lossy(sysm, cost, g, Tn, p_drop=p, summary=2),
        design_mtmse_lossy(sysm, cost, g, Tn, p_drop=p, items="measurements", keyed=1),
    ]
    for d in designs:  # relay "all": a bound for every protocol, and every design knows at most this much
        assert np.all(causal.stages <= np.asarray(d.stage_costs) + 1e-9)
    if p == 0.0:
        full = get_family("mtmse").build(sysm, cost, graph=g, structure=g, horizon=Tn)
        np.testing.assert_allclose(causal.stages, full.stage_costs, rtol=1e-9)
    if p == 1.0:
        np.testing.assert_allclose(causal.stages, designs[0].stage_costs, rtol=1e-9)
    if 0.0 < p < 1.0:
        assert causal.value > every.value + 1e-6  # not knowing the others' arrivals of the step costs something


def test_causal_bound_monte_carlo_agrees_with_enumeration():
    sysm, cost = _tiny(3)
    g = CommGraph.line(3)
    exact = known_pattern_bound(sysm, cost, g, 4, 0.5, knowledge="causal")
    mc = known_pattern_bound(sysm, cost, g, 4, 0.5, knowledge="causal", n_patterns=300, rng=5)
    assert exact.exact and not mc.exact
    assert abs(mc.value - exact.value) < 4 * mc.sem


def test_causal_knowledge_refuses_jitter_and_unknown_names():
    sysm, cost = _tiny(2)
    g = CommGraph.complete(2, delay=1)
    with pytest.raises(ArgumentError, match="knowledge.*jitter"):
        known_pattern_bound(sysm, cost, g, 3, 0.2, jitter=1, knowledge="causal")
    with pytest.raises(ArgumentError, match="knowledge"):
        known_pattern_bound(sysm, cost, g, 3, 0.2, knowledge="some")


def test_every_design_form_reports_the_bound_it_is_asked_for():
    sysm, cost = _tiny(3)
    g = CommGraph.line(3)
    exact = known_pattern_bound(sysm, cost, g, 4, 0.5, relay="flood", resend=2, knowledge="causal")
    d = design_mtmse_lossy(sysm, cost, g, 4, p_drop=0.5, items="measurements", resend=2, known_bound=10, known_knowledge="causal")
    kb = d.info["known_pattern_bound"]
    assert kb["exact"] and kb["knowledge"] == "causal" and kb["relay"] == "flood"
    assert kb["value"] == pytest.approx(exact.value, rel=1e-12)  # its own protocol: measurements re-sent r = 2
    assert d.details()["known_pattern_gap"] == pytest.approx((d.total_cost - exact.value) / exact.value)
    assert 0.0 < d.info["known_pattern_gap"]
    for kw in ({"keyed": 1}, {"summary": 1}, {"fill": "held", "patterns": 20}):
        dk = design_mtmse_lossy(sysm, cost, g, 4, p_drop=0.5, known_bound=10, known_knowledge="causal", **kw)
        assert dk.info["known_pattern_bound"]["knowledge"] == "causal"
    with pytest.raises(ArgumentError, match="known_knowledge.*jitter"):
        design_mtmse_lossy(sysm, cost, g, 4, p_drop=0.5, jitter=1, known_bound=10, known_knowledge="causal")


def test_evaluate_prints_and_records_the_gap(tmp_path, capsys):
    import json

    from teamkf.cli import main

    sp = tmp_path / "pl.toml"
    sp.write_text(
        'name = "pl"\nhorizon = 5\nestimators = ["mtmse_lossy", "local"]\n'
        "[system]\nA = [[0.9, 0.0], [0.7, 0.9]]\nQ = 1.0\nSigma_x = 1.0\n"
        "[[agents]]\nC = [[1, 0], [0, 1]]\nR = 0.1\n[[agents]]\nC = [[1, 0], [0, 1]]\nR = 0.1\n"
        '[graph]\nkind = "line"\ndelay = 1\n[cost]\nkind = "platoon"\nlambda = 10.0\n[network]\np_drop = 0.5\n'
        '[mtmse_lossy]\nitems = "measurements"\nresend = 2\nknown_bound = 20\nknown_knowledge = "causal"\n'
    )
    assert main(["--quiet", "evaluate", str(sp), "--json"]) == 0
    entry = json.loads(capsys.readouterr().out)["estimators"]["mtmse_lossy"]
    kb, gap = entry["known_pattern_bound"], entry["known_pattern_gap"]
    assert kb["knowledge"] == "causal" and kb["relay"] == "flood" and kb["resend"] == 2 and kb["exact"]
    assert gap == pytest.approx((entry["total_cost"] - kb["value"]) / kb["value"]) and gap > 0
    assert main(["--quiet", "evaluate", str(sp)]) == 0
    out = capsys.readouterr().out
    assert f"mtmse_lossy: {100 * gap:.2f} % above the known-pattern bound" in out
    assert "(causal); relays flood, re-sending 2; exact)" in out
