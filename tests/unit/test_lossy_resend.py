"""``mtmse_lossy`` with ``resend = r`` (each packet carries the sender's last r items): limits, the factorization,
Monte Carlo, the runtime agents, the known-pattern bound of the protocol, refusals."""

from __future__ import annotations

import numpy as np
import pytest

from teamkf import CommGraph, LinearGaussianSystem, TeamCost
from teamkf.estimators import _lossy_resend as LR
from teamkf.estimators._arrivals import ArrivalModel
from teamkf.estimators.registry import get_family
from teamkf.estimators.team import design_mtmse
from teamkf.estimators.team_lossy import design_mtmse_lossy, known_pattern_bound
from teamkf.exceptions import ArgumentError
from teamkf.simulation.sampling import sample_paths

from ..helpers import assert_lossy_agents_match, assert_lossy_mc_matches_exact

T = 8


def unlike_line(n: int = 3) -> tuple[LinearGaussianSystem, TeamCost]:
    """A line of agents that all estimate x₁ of an unstable process; agent 0 measures it precisely."""
    A = np.array([[1.1, 0.2], [0.0, 0.9]])
    C = [np.array([[1.0, 0.0]]) for _ in range(n)]
    sysm = LinearGaussianSystem(A=A, Q=0.5, Sigma_x=1.0, C=C, R=[0.01] + [4.0] * (n - 1))
    S = 2 * np.eye(n) - np.ones((n, n)) / n
    return sysm, TeamCost(S=S, L=np.tile([[1.0, 0.0]], (n, 1)), n_agents=n)


@pytest.fixture(scope="module")
def team():
    sysm, cost = unlike_line()
    g = CommGraph.line(3)
    return sysm, cost, g, {r: design_mtmse_lossy(sysm, cost, g, T, p_drop=0.5, items="innovations", resend=r) for r in (1, 2, 3)}


def test_limits_and_what_resending_buys(team):
    sysm, cost, g, ds = team
    for p in (0.0, 1.0):  # the ends: MTMSE, and the own-history optimum (= resend 1's)
        d = design_mtmse_lossy(sysm, cost, g, T, p_drop=p, items="innovations", resend=3)
        ref = design_mtmse(sysm, cost, g, T) if p == 0 else design_mtmse_lossy(sysm, cost, g, T, p_drop=1.0, items="innovations")
        assert d.total_cost == pytest.approx(ref.total_cost, rel=1e-9)
    for r, d in ds.items():
        assert d.lower_bound <= d.total_cost <= d.info["local_kf_cost"]
        assert d.details().get("resend", 1) == r
    # a missed innovation of the good sensor is recovered from a later packet: re-sending pays on an unstable process
    assert ds[3].total_cost < ds[2].total_cost < 0.97 * ds[1].total_cost


def test_resend_one_and_the_schur_steps_are_the_plain_design(team):
    sysm, cost, g, ds = team
    arr = ArrivalModel.build(g, 0.5, 0)
    d1 = LR.design_resend(sysm, cost, g, T, 0.5, 0, arr, ("innovations",), 1, True, False, 1)
    np.testing.assert_allclose(d1.stage_costs, ds[1].stage_costs, rtol=1e-10)  # r = 1 is today's class
    dense = LR.design_resend(sysm, cost, g, T, 0.5, 0, arr, ("innovations",), 3, True, False, 1, schur=False)
    np.testing.assert_allclose(dense.stage_costs, ds[3].stage_costs, rtol=1e-10)  # one factor + Schur = a solve per step
    for k in range(T):
        for i in range(3):
            np.testing.assert_allclose(dense.gains[k][i], ds[3].gains[k][i], rtol=1e-7, atol=1e-9)


def test_monte_carlo_agrees_with_exact_expected_cost(team):
    sysm, cost, _, ds = team
    assert_lossy_mc_matches_exact(ds[3], sysm, cost, T, 0.5)


def test_graph_agents_reproduce_errors_and_run_over_drops(team):
    sysm, cost, g, ds = team
    assert_lossy_agents_match(ds[2], sysm, cost, g, T, 0.5)


def test_known_pattern_bound_of_the_protocol():
    sysm, cost = unlike_line(2)
    g = CommGraph.complete(2, delay=1)
    b = {r: known_pattern_bound(sysm, cost, g, 4, 0.5, resend=r) for r in (1, 2, 3)}
    assert all(x.exact for x in b.values())
    assert b[3].value < b[2].value < b[1].value  # the packets carry more
    d = design_mtmse_lossy(sysm, cost, g, 4, p_drop=0.5, items="measurements", resend=2)
    assert b[2].value <= d.total_cost


def test_refusals_and_registry(team):
    sysm, cost, g, _ = team
    for bad in (0, -1, "two", 1.5, 17):
        with pytest.raises(ArgumentError, match="resend"):
            design_mtmse_lossy(sysm, cost, g, 4, p_drop=0.3, resend=bad)
    for kw in ({"keyed": 1}, {"memory": 2}):
        with pytest.raises(ArgumentError, match="resend"):
            design_mtmse_lossy(sysm, cost, g, 4, p_drop=0.3, resend=2, **kw)
    d = get_family("mtmse_lossy").build(sysm, cost, graph=g, structure=g, horizon=4, options={"p_drop": 0.3, "resend": 2})
    assert d.resend == 2 and int(d.arrays()["resend"]) == 2
    assert LR.availability_prob(d.arrivals, 2, 0, 2) == pytest.approx(1 - (1 - 0.7**2) ** 2)  # two 2-hop packets


def test_a_horizon_too_long_is_refused_with_what_fits_a_re_sending_design():
    """``resend`` takes no ``memory``: the refusal offers the longest horizon, or resend = 1 with a memory (not memory alone)."""
    from teamkf.exceptions import ResourceError

    sysm, cost = LinearGaussianSystem.platoon(4), TeamCost.platoon(4, 10.0)
    with pytest.raises(ResourceError, match=r"use a horizon of at most [\d,]+ steps \(resend = 2 takes no memory\), or resend = 1 and "):
        design_mtmse_lossy(sysm, cost, CommGraph.line(4), 5000, p_drop=0.3, items="measurements", resend=2)


def test_on_time_known_pattern_bound_lies_between():
    sysm, cost = unlike_line(3)
    g = CommGraph.complete(3, delay=1)  # a relayed copy (2 hops) is late: the design does not use it
    T3 = 3
    fl = known_pattern_bound(sysm, cost, g, T3, 0.5, relay="flood")
    for r in (1, 2):
        on = known_pattern_bound(sysm, cost, g, T3, 0.5, relay="ontime", resend=r)
        d = design_mtmse_lossy(sysm, cost, g, T3, p_drop=0.5, items="measurements", resend=r)
        assert on.exact and on.value <= d.total_cost * (1 + 1e-12)
        if r == 1:
            assert fl.value < on.value  # late copies through the third agent are worth something


def test_deployed_slices_rebuild_the_re_sending_agents_bit_for_bit() -> None:
    """``teamkf deploy`` ships slices: agent i rebuilt from its slice is the re-sending agent, not the one-item agent (whose
    estimates differ), and gives the design's own agents' numbers bit for bit over the same lossy links."""
    from teamkf.estimators._slices import SliceContext, agent_from_slice
    from teamkf.simulation import lossy
    from teamkf.simulation.links import LinkModel, LinkStats, link_streams

    sysm, cost, g = LinearGaussianSystem.platoon(3), TeamCost.platoon(3, 10.0), CommGraph.line(3)
    d = design_mtmse_lossy(sysm, cost, g, 8, p_drop=0.4, resend=2)
    ctx = SliceContext(sysm, cost, g, None, 8)
    agents = []
    for i in range(3):
        kind, arrays, meta = d.agent_slice(i)
        assert meta["resend"] == 2
        agents.append(agent_from_slice(kind, ctx, i, arrays, meta)[1])
    assert type(agents[0]) is type(d.graph_agents()[0])
    ys = list(sample_paths(sysm, 8, 3, rng=1).y)
    u, jit = lossy.draw_link_events(link_streams(2, 3), 8, len(g.edges))
    out = lossy.link_outcomes(LinkModel(p_drop=0.4), sorted(g.edges), u, jit, (False,) * 3)
    ref = lossy._run_grouped(d.graph_agents(), g, ys, out, LinkStats(), d)
    got = lossy._run_grouped(agents, g, ys, out, LinkStats(), agents[0].design)
    assert got.tobytes() == ref.tobytes()
