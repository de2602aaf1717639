"""Argument checks shared by the design functions of every family."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Iterable, Sequence

from ..exceptions import ArgumentError, GraphError
from ..models import LinearGaussianSystem, TeamCost
from ..network.graph import CommGraph

__all__ = ["check_model", "check_graph", "detects", "undetecting_agents", "ForcedGrowth", "forced_growth"]


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


@dataclass(frozen=True)
class ForcedGrowth:
    """Why agent ``agent``'s share of the team cost must grow, whatever its estimator (:func:`forced_growth`).

    ``undetected``: the eigenvalues (modulus >= 1) of A on the undetectable subspace U_+ of its data set;
    ``by_noise``: those whose growth the process noise forces into its cost (at least linear growth);
    ``by_initial``: those whose growth the initial uncertainty Sigma_x forces (modulus > 1, or a Jordan block on
    the unit circle). ``forced`` is true iff one of the last two is not empty.
    """

    agent: int
    undetected: tuple[complex, ...]
    by_noise: tuple[complex, ...]
    by_initial: tuple[complex, ...]

    @property
    def forced(self) -> bool:
        return bool(self.by_noise or self.by_initial)


def _factor(P: Any) -> Any:
    """Columns F with F F' = P (symmetric PSD), zero directions dropped."""
    import numpy as np

    w, U = np.linalg.eigh(0.5 * (P + P.T))
    top = max(float(w[-1]), 0.0) if w.size else 0.0
    keep = w > max(top, np.finfo(float).tiny) * P.shape[0] * np.finfo(float).eps
    return U[:, keep] * np.sqrt(w[keep])


def forced_growth(
    system: LinearGaussianSystem, cost: TeamCost | None = None, groups: Sequence[Iterable[int]] | None = None
) -> list[ForcedGrowth] | None:
    r"""Per agent i: the modes of x its data set ``groups[i]`` (default {i}) cannot detect, and those that force its cost to grow.

    The test of :mod:`teamkf.experiments.divergence` (the theorem and its proof are there): with V_+ an orthonormal
    basis of the undetectable subspace of (A, C_{D_i}) (:func:`teamkf._linalg.undetectable_subspace`), V_r its
    orthogonal complement, A_+ = V_+' A V_+, B and B_0 factors of the conditional covariances of the noise and of
    x(0) along V_+ given their V_r components, and M = L_i V_+ (``cost`` None: M = V_+, agent i weighs all of x),
    the lower bound M P_t M', P_{t+1} = A_+ P_t A_+' + B B', P_0 = B_0 B_0', is tested for growth
    (:func:`teamkf._linalg.lyapunov_growth`). ``None`` for a time-varying system or cost (not tested).
    """
    import numpy as np

    from .._linalg import PBH_RTOL, _null, conditional_factor, distinct_modes, lyapunov_growth, undetectable_subspace

    if system.is_time_varying or (cost is not None and cost.is_time_varying):
        return None
    n = system.n_agents
    sets = [[i] for i in range(n)] if groups is None else [sorted(set(int(j) for j in g)) for g in groups]
    A = np.asarray(system.A_at(0), dtype=float)
    FQ, FS = _factor(np.asarray(system.Q_at(0), dtype=float)), _factor(np.asarray(system.Sigma_x, dtype=float))
    tiny = np.finfo(float).tiny
    out: list[ForcedGrowth] = []
    cache: dict[tuple[int, ...], Any] = {}
    for i, g in enumerate(sets):
        key = tuple(g)
        if key not in cache:
            C = np.vstack([system.C_at(j, 0) for j in g]) if g else np.zeros((0, system.dx))
            Vp = undetectable_subspace(A, C)
            if Vp.shape[1] == 0:
                cache[key] = None
            else:
                Vr = _null(Vp.T, 0.5)
                B = conditional_factor(FQ, Vr, Vp, PBH_RTOL * max(float(np.linalg.norm(FQ)), tiny))
                B0 = conditional_factor(FS, Vr, Vp, PBH_RTOL * max(float(np.linalg.norm(FS)), tiny))
                cache[key] = (Vp, Vp.T @ A @ Vp, B, B0)
        got = cache[key]
        if got is None:
            out.append(ForcedGrowth(i, (), (), ()))
            continue
        Vp, Ap, B, B0 = got
        Li = np.eye(system.dx) if cost is None else np.asarray(cost.L_block(i), dtype=float)
        noise, initial = lyapunov_growth(
            Ap,
            Li @ Vp,
            B,
            B0,
            tol_b=PBH_RTOL * max(float(np.linalg.norm(FQ)), tiny),
            tol_b0=PBH_RTOL * max(float(np.linalg.norm(FS)), tiny),
            tol_m=PBH_RTOL * max(float(np.linalg.norm(Li)), tiny),
        )
        out.append(ForcedGrowth(i, tuple(distinct_modes(np.linalg.eigvals(Ap))), tuple(noise), tuple(initial)))
    return out
