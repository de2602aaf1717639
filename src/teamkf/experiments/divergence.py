r"""Why a leaderboard row diverges: structural (its data cannot detect x) or parametric (its rule or parameters).

A row's estimate x̂_i is a linear function of the measurements y_j, j in D_i, that the
algorithm ever lets reach agent i:

==============================================  ================================================
row                                             D_i
==============================================  ================================================
``local``                                       {i} (its own Kalman filter)
``ci`` published form (``feedback=False``)      N_i = {i} ∪ in-neighbours: local filters, fused
every other family (and ``ci`` with feedback)   the agents from which i is reachable in the graph
==============================================  ================================================

When (A, C_{D_i}) is not detectable (PBH test on the modes with modulus >= 1,
:func:`teamkf.estimators.checks.detects`; time-invariant models) no estimator
using only those data has a bounded error covariance: the row diverges for a
**structural** reason, a theorem, not a defect of the family. The published CI
fuses local Kalman filters and feeds nothing back, so local filters that do not
converge ((A, C_i) not detectable) are reported with it, and whether each
in-neighbourhood jointly detects x. Otherwise the reason is **parametric**: the
published parameters on this delay graph (and whether the tuned row of the
same family diverges too).
"""

from __future__ import annotations

from typing import Any

from ..estimators.checks import undetecting_agents
from ..models import LinearGaussianSystem
from ..network import CommGraph

__all__ = ["data_sets", "forced", "why_diverging"]


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


def forced(family: str, options: dict[str, Any], system: LinearGaussianSystem, graph: CommGraph) -> bool:
    """Divergence forced by a theorem: some agent's data set D_i does not detect x, and Q > 0 excites every mode.

    Then no estimator on those data has a bounded error covariance, whatever the horizon shows. (A
    published CI whose local filters diverge but whose in-neighbourhoods detect x is not forced: its
    divergence, when the numbers show one, is the rule's.) False for time-varying models (not tested).
    """
    import numpy as np

    if system.is_time_varying or np.linalg.eigvalsh(0.5 * (system.Q_at(0) + system.Q_at(0).T))[0] <= 0.0:
        return False
    return bool(undetecting_agents(system, data_sets(family, options, graph)))


def why_diverging(
    family: str, options: dict[str, Any], system: LinearGaussianSystem, graph: CommGraph, *, tuned: tuple[str, bool] | None = None
) -> str:
    """The reason a diverging row of ``family`` with ``options`` (its ``variant`` among them) diverges; see the module docstring.

    Parameters
    ----------
    family, options : the row's family and options (``{"variant": "honest", "feedback": True}``)
    system, graph : the network
    tuned : (options text, diverging) of the family's tuned honest row on this network, when it has one

    Returns
    -------
    str
        ``"structural: ..."`` or ``"parametric: ..."``, naming the agents.
    """
    n = system.n_agents
    if system.is_time_varying:
        return "not classified: the detectability test is for time-invariant models, this one is time-varying"
    sets = data_sets(family, options, graph)
    blind = undetecting_agents(system, sets) or []
    variant = str(options.get("variant", ""))
    if family == "local":
        if blind:
            return f"structural: no filter using only its own measurements converges: (A, C_i) not detectable for {_agents(blind, n)}"
    elif family == "ci" and not options.get("feedback", False):
        loc = undetecting_agents(system) or []
        if loc:
            joint = [i for i in range(n) if i not in blind]
            tail = (
                f"; the in-neighbourhood (own and in-neighbours' measurements) jointly detects x for {_agents(joint, n)}"
                if joint
                else "; no in-neighbourhood (own and in-neighbours' measurements) jointly detects x either"
            )
            if blind:
                tail += f", not for {_agents(blind, n)} (no estimator on those data converges)"
            return (
                f"structural: the published CI fuses local Kalman filters that do not converge and feeds nothing back: (A, C_i) not "
                f"detectable for {_agents(loc, n)}{tail}; the feedback form (feedback=True) fuses into the prior"
            )
    elif blind:
        return (
            f"structural: the measurements that can reach {_agents(blind, n)} over the graph do not detect x (no estimator on those data converges)"
        )
    what = "published parameters" if not _fmt(options) else f"parameters {_fmt(options)}"
    where = "with exchanges inside the step (ideal variant)" if variant == "ideal" else "on this delay graph"
    if tuned is None:
        after = "the family has no tuned row"
    elif tuned[1]:
        after = f"the tuned row ({tuned[0] or 'published defaults'}) diverges too"
    else:
        after = f"the tuned row ({tuned[0]}) does not diverge"
    return f"parametric: {what} {where} (the data that reach every agent detect x: not a detectability limit); {after}"


def _fmt(options: dict[str, Any]) -> str:
    return ", ".join(f"{k}={v}" for k, v in options.items() if k != "variant")
