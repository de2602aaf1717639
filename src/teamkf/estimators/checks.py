"""Argument checks shared by the design functions of every family."""

from __future__ import annotations

from typing import Any, Iterable, Sequence

from ..exceptions import ArgumentError, GraphError
from ..models import LinearGaussianSystem, TeamCost
from ..network.graph import CommGraph

__all__ = ["check_model", "check_graph", "detects", "undetecting_agents"]


def check_model(system: Any, cost: Any) -> None:
    """``system`` is a LinearGaussianSystem and ``cost`` a TeamCost of matching size."""
    if not isinstance(system, LinearGaussianSystem):
        raise ArgumentError(f"system: expected a LinearGaussianSystem, found {type(system).__name__}", argument="system")
    if not isinstance(cost, TeamCost):
        raise ArgumentError(
            f"cost: expected a TeamCost, found {type(cost).__name__}; build one with TeamCost.mse/platoon/average_tracking", argument="cost"
        )
    cost.check_system(system.dx, system.n_agents)


def check_graph(graph: Any, n_agents: int) -> CommGraph:
    """``graph`` is a CommGraph on ``n_agents`` nodes."""
    if not isinstance(graph, CommGraph):
        raise GraphError(
            f"graph: expected a CommGraph, found {type(graph).__name__}; build one with CommGraph.complete/line/ring or CommGraph(n, edges)",
            argument="graph",
        )
    if graph.n_agents != n_agents:
        raise GraphError(f"graph: expected a graph of {n_agents} agents (as the system), found one of {graph.n_agents}", argument="graph")
    return graph


def check_information_form(system: LinearGaussianSystem, family: str) -> None:
    """Families that run in information form (P^-1) need Sigma_x positive definite, and every prior
    A P A' + Q positive definite: A invertible or Q positive definite (checked at every step)."""
    import numpy as np

    from ..exceptions import NotPositiveDefiniteError

    def pd(M: Any) -> bool:
        lam = np.linalg.eigvalsh(0.5 * (M + M.T))
        return bool(lam[0] > 1e-12 * max(1.0, float(lam[-1])))

    if not pd(system.Sigma_x):
        raise NotPositiveDefiniteError(
            f"system.Sigma_x: the {family!r} family works with information matrices P^-1 and needs a positive definite "
            "Sigma_x, found a singular one; add a small multiple of I, or use a covariance-form family (local, kcf, mtmse)",
            argument="system.Sigma_x",
        )
    for k in range(system._n_time or 1):
        A, Q = system.A_at(k), system.Q_at(k)
        if not pd(Q) and abs(np.linalg.det(A)) < 1e-12 * max(1.0, float(np.abs(A).max())) ** A.shape[0]:
            raise NotPositiveDefiniteError(
                f"system.Q: the {family!r} family needs every prior A P A' + Q positive definite, but at step {k} Q is singular "
                "and A is not invertible; give Q positive definite",
                argument="system.Q",
            )


def detects(system: LinearGaussianSystem, agents: Iterable[int]) -> bool | None:
    r"""Whether the stacked measurements of ``agents`` detect x: (A, C_J) detectable, C_J = [C_j]_{j in J} (PBH test).

    .. math:: \operatorname{rank} \begin{bmatrix} A - \lambda I \\ C_J \end{bmatrix} = d_x
              \quad \text{for every eigenvalue } \lambda \text{ of } A \text{ with } |\lambda| \ge 1

    (:func:`teamkf._linalg.unstable_unobservable_modes`). When it fails, no estimator that uses only y_j, j in J,
    has a bounded error covariance on a process whose noise excites the undetected unstable modes. ``None``
    for a time-varying model (the test is for time-invariant ones) and for an empty ``agents``.
    """
    import numpy as np

    from .._linalg import is_detectable

    J = sorted(set(int(j) for j in agents))
    if system.is_time_varying or not J:
        return None
    return bool(is_detectable(system.A_at(0), np.vstack([system.C_at(j, 0) for j in J])))


def undetecting_agents(system: LinearGaussianSystem, groups: Sequence[Iterable[int]] | None = None) -> list[int] | None:
    """The agents i whose data set ``groups[i]`` (default: {i}, its own measurements) does not detect x (:func:`detects`).

    ``None`` for a time-varying model (not tested).
    """
    if system.is_time_varying:
        return None
    sets = [[i] for i in range(system.n_agents)] if groups is None else list(groups)
    return [i for i, g in enumerate(sets) if detects(system, g) is False]
