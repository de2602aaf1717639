r"""Why a leaderboard row diverges: structural (its data force the cost to grow, a theorem) or parametric (its rule or parameters).

A row's estimate ẑ_i of agent i is a function of the measurements y_j, j in D_i,
that the algorithm ever lets reach agent i:

==============================================  ================================================
row                                             D_i
==============================================  ================================================
``local``                                       {i} (its own Kalman filter)
``ci`` published form (``feedback=False``)      N_i = {i} ∪ in-neighbours: local filters, fused
every other family (and ``ci`` with feedback)   the agents from which i is reachable in the graph
==============================================  ================================================

**The theorem** (:func:`forced`; time-invariant models and costs). Process
x(t+1) = A x(t) + w(t), w ~ N(0, Q), x(0) ~ N(0, Σ_x); measurements
y_j = C_j x + v_j, the v_j independent of w and x(0); team cost
c = (L x - z)' S (L x - z) with S positive definite (A1), z = (z_1, ..., z_n).
For a data set D with stacked C_D let

* U_+ be the *undetectable subspace* of (A, C_D): the unobservable subspace U
  (the largest A-invariant subspace in ker C_D) intersected with the
  generalized eigenspace of the eigenvalues of modulus >= 1. It is A-invariant
  and (A, C_D) is detectable iff U_+ = {0}. It is computed with orthonormal
  bases (:func:`teamkf._linalg.undetectable_subspace`: U by the subspace
  recursion N_0 = ker C_D, N_{j+1} = {x in N_j : A x in N_j}, then an ordered
  Schur form of A on U), never from eigenvectors, so repeated eigenvalues and
  Jordan blocks are handled;
* V_+ an orthonormal basis of U_+ and V_r one of its orthogonal complement; in
  the coordinates x_r = V_r' x, x_+ = V_+' x, A is block lower triangular
  (V_r' A V_+ = 0, U_+ being invariant): x_r(t+1) = A_r x_r + w_r is
  *autonomous*, x_+(t+1) = A_+r x_r + A_+ x_+ + w_+ (A_+ = V_+' A V_+, every
  eigenvalue of modulus >= 1), and C_D x = C_D V_r x_r;
* Q_{+|r} = Cov(w_+ | w_r) and Σ_{+|r} = Cov(x_+(0) | x_r(0)) (Schur
  complements, computed as B B' and B_0 B_0' with B = V_+' F (I - P), F F' = Q,
  P the projector on the row space of V_r' F; likewise for Σ_x).

*Lower bound.* Every y_j, j in D, is a function of the path of x_r and of the
v_j, which are independent of x. Give agent i the whole path x_r(0), x_r(1), ...
(past and future) besides: x_r determines w_r(s) = x_r(s+1) - A_r x_r(s), and
given it, x_+ is a linear Gaussian process with known input A_+r x_r, noise
covariance Q_{+|r} and initial covariance Σ_{+|r} (the w(s) are independent
over s, and future x_r depends only on w_r(s), s >= t, which x_+(t) does not).
So for every estimator z_i of agent i from D_i, with e_i = L_i x - z_i,

.. math:: \operatorname{Cov}(e_i(t)) \succeq M P_t M^\top, \quad M = L_i V_+, \quad
          P_{t+1} = A_+ P_t A_+^\top + Q_{+|r}, \quad P_0 = \Sigma_{+|r},

and the team cost is at least agent i's share:
e' S e >= e_i' Ŝ_i e_i for every e (Ŝ_i = S_ii - S_{i,-i} S_{-i,-i}^{-1} S_{-i,i},
the Schur complement, positive definite since S is: the minimum of e' S e over
the other agents' errors), whatever the other agents do. Hence E c(t) >=
λ_min(Ŝ_i) tr(M P_t M'), and the row's cost grows without bound when
M P_t M' does.

*When the bound grows* (:func:`teamkf._linalg.lyapunov_growth`). Write
M A_+^s B = M_o A_o^s B_o on the minimal part of (A_+, B, M) (the part
reachable from B and seen by M): if it is not empty, M A_+^s B does not tend
to 0 (every eigenvalue of A_o has modulus >= 1; observability and
reachability would turn M_o A_o^s B_o -> 0 into A_o^s -> 0), so
tr(M P_t M') >= sum_{s<t} tr(M A_+^s B B' A_+^s' M') grows at least linearly: **forced
by the noise**. Likewise M A_+^t B_0 is unbounded iff A_o^t is on the minimal
part of (A_+, B_0, M), i.e. iff it has an eigenvalue of modulus > 1 or a
Jordan block on the unit circle: **forced by the initial uncertainty** (an
unstable mode that no noise excites still diverges from Σ_x; a marginal one,
semisimple, does not: its error stays at its initial size).

So agent i's data **force** the row to diverge (:func:`forced`) when a mode of modulus >= 1 is
(a) undetectable from C_{D_i}, (b) excited, given what D_i measures, by the
noise (linear growth at least: a random walk gives linear growth, a Jordan
block on the unit circle faster) or, for modulus > 1 or a Jordan block, by Σ_x,
and (c) weighed by agent i's cost (L_i V_+ sees it). An undetectable mode that
agent i's cost rows do not weigh (L_i V_+ = 0 along it), or that nothing
excites, does not force anything: the row is then judged by its numbers
(:func:`teamkf.experiments.tuning.diverging`).

The test is sufficient, not necessary: a mode excited only through states
that agent i measures with noise (w_+ = 0, A_+r x_r ≠ 0, the x_r path known
only through noisy y) makes the optimal error grow too, but the lower bound
above, which gives the x_r path exactly, does not show it; such rows are
flagged by the numeric detector only, and their reason reads ``undetectable``.

**Reasons** (:func:`why_diverging`): ``structural`` when the data of some
agents force the growth (the agents, the modes, and whether noise or Σ_x
excites them, are named). The published CI fuses local Kalman filters and
feeds nothing back, so local filters that diverge (their own data force the
growth of their estimate of x) are reported with it, and whether each
in-neighbourhood's data force the agent's cost to grow. ``undetectable`` when
some data sets do not detect a mode but the test forces nothing; otherwise
``parametric``: the published parameters on this delay graph (and whether
the tuned row of the same family diverges too).
"""

from __future__ import annotations

from typing import Any

from ..estimators.checks import ForcedGrowth, forced_growth
from ..models import LinearGaussianSystem, TeamCost
from ..network import CommGraph

__all__ = ["data_sets", "forced", "forced_agents", "why_diverging"]


def _agents(idx: list[int], n: int, limit: int = 12) -> str:
    """``agents 0, 3 (2 of 10)``, ``all 10 agents``, or the first ``limit`` of them and the count."""
    if len(idx) == n:
        return f"all {n} agents"
    shown = ", ".join(map(str, idx[:limit])) + (", ..." if len(idx) > limit else "")
    return f"agents {shown} ({len(idx)} of {n})"


def data_sets(family: str, options: dict[str, Any], graph: CommGraph) -> list[list[int]]:
    """D_i of every agent (module docstring): the agents whose measurements the row's x̂_i can depend on."""
    n = graph.n_agents
    if family == "local":
        return [[i] for i in range(n)]
    if family == "ci" and not options.get("feedback", False):
        return [sorted({i, *graph.in_neighbors(i)}) for i in range(n)]
    out = []
    for i in range(n):  # the agents with a directed path to i (any graph, strongly connected or not)
        seen, todo = {i}, [i]
        while todo:
            for j in graph.in_neighbors(todo.pop()):
                if j not in seen:
                    seen.add(j)
                    todo.append(j)
        out.append(sorted(seen))
    return out


def forced_agents(
    family: str, options: dict[str, Any], system: LinearGaussianSystem, graph: CommGraph, cost: TeamCost | None = None
) -> list[ForcedGrowth] | None:
    """Per agent, the modes its data set D_i cannot detect and those that force its cost to grow (module docstring).

    ``cost`` None: every agent weighs all of x (L_i = I). ``None`` for a time-varying system or cost.
    """
    return forced_growth(system, cost, data_sets(family, options, graph))


def forced(family: str, options: dict[str, Any], system: LinearGaussianSystem, graph: CommGraph, cost: TeamCost | None = None) -> bool:
    """Divergence forced by the theorem of the module docstring: for some agent i a mode of modulus >= 1 is undetectable
    from D_i, excited (by the noise, or by Sigma_x when it is unstable or in a Jordan block) and weighed by L_i.

    Then no estimator on those data keeps the row's team cost bounded, whatever the horizon shows. (A published CI whose
    local filters diverge but whose in-neighbourhoods' data do not force it is not forced: its divergence, when the
    numbers show one, is the rule's.) ``cost`` None weighs all of x. False for time-varying models (not tested).
    """
    got = forced_agents(family, options, system, graph, cost)
    return bool(got) and any(f.forced for f in got or [])


def _lam(z: complex) -> str:
    if z.imag == 0.0:
        return f"{z.real:.4g}"
    return f"{z.real:.4g}{z.imag:+.4g}j (modulus {abs(z):.4g})"


def _modes(found: list[ForcedGrowth], which: str, limit: int = 4, why: str = "") -> str:
    """``mode λ = 1 (marginal)`` or ``modes λ = 1.02, 1.01 (unstable; why)`` over the agents, largest modulus first."""
    from .._linalg import distinct_modes

    lams = distinct_modes([z for f in found for z in getattr(f, which)])
    shown = ", ".join(_lam(z) for z in lams[:limit]) + (f", ... ({len(lams)} in all)" if len(lams) > limit else "")
    big = [abs(z) > 1.0 + 1e-6 for z in lams]
    kind = "unstable" if all(big) else ("marginal" if not any(big) else "unstable and marginal")
    return f"{'mode' if len(lams) == 1 else 'modes'} λ = {shown} ({kind}{'; ' + why if why else ''})"


def _why_forced(found: list[ForcedGrowth], who: str, weighs: str) -> str:
    """``who`` cannot detect the modes that force the growth (what excites them), which ``weighs`` weighs."""
    noise = [f for f in found if f.by_noise]
    initial = [f for f in found if f.by_initial and not f.by_noise]
    parts = []
    if noise:
        parts.append("the " + _modes(noise, "by_noise", why="excited by the process noise"))
    if initial:
        parts.append("the " + _modes(initial, "by_initial", why="excited by the initial uncertainty Sigma_x"))
    return f"{who} cannot detect {' nor '.join(parts)}, which {weighs} weighs"


def why_diverging(
    family: str,
    options: dict[str, Any],
    system: LinearGaussianSystem,
    graph: CommGraph,
    *,
    tuned: tuple[str, bool] | None = None,
    cost: TeamCost | None = None,
) -> str:
    """The reason a diverging row of ``family`` with ``options`` (its ``variant`` among them) diverges; see the module docstring.

    Parameters
    ----------
    family, options : the row's family and options (``{"variant": "honest", "feedback": True}``)
    system, graph : the network
    tuned : (options text, diverging) of the family's tuned honest row on this network, when it has one
    cost : the team cost (its L_i say what each agent weighs); None: every agent weighs all of x

    Returns
    -------
    str
        ``"structural: ..."``, ``"undetectable: ..."`` or ``"parametric: ..."``, naming the agents and the modes.
    """
    n = system.n_agents
    fg = forced_agents(family, options, system, graph, cost)
    if fg is None:
        return "not classified: the divergence test is for time-invariant models and costs, this one is time-varying"
    blind = [f for f in fg if f.forced]
    idx = [f.agent for f in blind]
    variant = str(options.get("variant", ""))
    weighs = "their cost (L_i)" if cost is not None else "their estimate (of all of x)"
    if family == "local":
        if blind:
            return (
                f"structural: no filter using only its own measurements converges for {_agents(idx, n)}: "
                f"{_why_forced(blind, 'their C_i', weighs)} (no estimator on those data keeps the cost bounded)"
            )
    elif family == "ci" and not options.get("feedback", False):
        loc = [f for f in (forced_growth(system, None) or []) if f.forced]
        if loc:
            joint = [i for i in range(n) if i not in idx]
            tail = (
                f"; the in-neighbourhood's data (own and in-neighbours' measurements) do not force the cost to grow for {_agents(joint, n)}"
                if joint
                else "; every in-neighbourhood's data (own and in-neighbours' measurements) force the cost to grow too"
            )
            if blind:
                tail += f", not for {_agents(idx, n)}, whose {_why_forced(blind, 'in-neighbourhood', weighs)} (no estimator on those data converges)"
            return (
                f"structural: the published CI fuses local Kalman filters that do not converge and feeds nothing back: for "
                f"{_agents([f.agent for f in loc], n)} {_why_forced(loc, 'C_i', 'the local filter')}{tail}; "
                "the feedback form (feedback=True) fuses into the prior"
            )
    elif blind:
        return (
            f"structural: the measurements that can reach {_agents(idx, n)} over the graph do not keep their cost bounded: "
            f"{_why_forced(blind, 'those data', weighs)} (no estimator on those data converges)"
        )
    what = "published parameters" if not _fmt(options) else f"parameters {_fmt(options)}"
    where = "with exchanges inside the step (ideal variant)" if variant == "ideal" else "on this delay graph"
    if tuned is None:
        after = "the family has no tuned row"
    elif tuned[1]:
        after = f"the tuned row ({tuned[0] or 'published defaults'}) diverges too"
    else:
        after = f"the tuned row ({tuned[0]}) does not diverge"
    unseen = [f for f in fg if f.undetected]
    if unseen:
        return (
            f"undetectable: the data that can reach {_agents([f.agent for f in unseen], n)} do not detect the "
            f"{_modes(unseen, 'undetected')}, but the divergence test does not force their cost to grow (not excited given what "
            f"they measure, or not weighed by {weighs}); the growth may come from there or from the {what} {where}; {after}"
        )
    return f"parametric: {what} {where} (the data that reach every agent detect x: not a detectability limit); {after}"


def _fmt(options: dict[str, Any]) -> str:
    return ", ".join(f"{k}={v}" for k, v in options.items() if k != "variant")
