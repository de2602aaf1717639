"""Decentralized LQG control with one-step delayed sharing, through MTMSE (team-MMSE paper, Appendix D).

Model (eqs. 59-64; steps 0-based, the paper's t = k + 1; horizon T, controls at k = 0..T-2):

    x(k+1) = A x(k) + B u(k) + w(k),   w ~ N(0, Q),  x(0) ~ N(0, Sigma_x)
    y_i(k) = C_i x(k) + v_i(k),        v_i ~ N(0, R_i)
    I_i(k) = {y_i(k), y(0:k-1), u(0:k-1)}                              (62)
    J = E[ sum_{k<T-1} x'Q_x x + u'R_u u + x(T-1)' Q_x x(T-1) ]        (64)

Backward Riccati: P(T-1) = Q_x, P(k) = Q_x + A'P(k+1)A - A'P(k+1)B S(k)^-1 B'P(k+1)A,
S(k) = R_u + B'P(k+1)B, L(k) = S(k)^-1 B'P(k+1)A. Lemma 6:
J = tr(Sigma_x P(0)) + sum_k tr(Q P(k+1)) + sum_k E[(u + L x)' S (u + L x)]  (66, with the
x(0) term once — the printed (66) puts it inside the sum). With x = x-bar + x~ (control-free part
x~) and z_i = -(u_i + L_i x-bar), the last sum is an MTMSE filtering cost for the control-free
system with weight S(k) and L(k) (67), under one-step delayed sharing. Theorem 4 gives

    u_i(k) = -L_i(k) x^(k) - F_i(k) (y_i(k) - C_i x^(k))                (70)

with x^(k) = E[x(k) | y(0:k-1), u(0:k-1)] the centralized predictor including the controls
and F_i(k) the MTMSE gains of Theorem 2 for the weight S(k): they change with the control
weights, which is why estimation and control do not separate.

The certainty-equivalent baseline uses each agent's own MMSE estimate:
u_i = -L_i(k) E[x(k) | I_i(k)], i.e. the per-agent MMSE gains in (70).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.linalg as sla

from .. import _validation as V
from .._validation import FloatArray
from ..estimators.team import TeamDesign, design_mmse, design_mtmse
from ..exceptions import ShapeError
from ..models import LinearGaussianSystem, TeamCost
from ..network.information import InformationStructure

__all__ = ["LQGProblem", "LQGDesign", "backward_riccati", "design_lqg", "simulate_closed_loop"]


@dataclass(frozen=True, eq=False)
class LQGProblem:
    """A decentralized LQG problem: the system, the input matrix and the quadratic weights.

    Parameters
    ----------
    system : LinearGaussianSystem (time-invariant)
    B : (d_x, n d_u) array, columns of agent i's input u_i in block i
    Q_x : (d_x, d_x) PSD state weight
    R_u : (n d_u, n d_u) PD control weight
    """

    system: LinearGaussianSystem
    B: Any
    Q_x: Any
    R_u: Any

    def __post_init__(self) -> None:
        self.system.require_time_invariant("decentralized LQG")
        dx, n = self.system.dx, self.system.n_agents
        B = V.matrix(self.B, "B", (dx, None))
        if B.shape[1] % n:
            raise ShapeError(f"B: expected n d_u columns (a multiple of n_agents = {n}), found {B.shape[1]}")
        object.__setattr__(self, "B", V.frozen(B))
        object.__setattr__(self, "Q_x", V.frozen(V.covariance(self.Q_x, "Q_x", dx)))
        object.__setattr__(self, "R_u", V.frozen(V.covariance(self.R_u, "R_u", B.shape[1], definite=True)))

    @property
    def du(self) -> int:
        return int(self.B.shape[1] // self.system.n_agents)


def backward_riccati(problem: LQGProblem, horizon: int) -> tuple[FloatArray, FloatArray, FloatArray]:
    """P(0..T-1), S(0..T-2), L(0..T-2) of the backward Riccati equation (Appendix D-B)."""
    T = V.positive_int(horizon, "horizon", minimum=2)
    A, B, Qx, Ru = problem.system.A_at(0), problem.B, problem.Q_x, problem.R_u
    dx, m = A.shape[0], B.shape[1]
    P = np.empty((T, dx, dx))
    S = np.empty((T - 1, m, m))
    L = np.empty((T - 1, m, dx))
    P[T - 1] = Qx
    for k in range(T - 2, -1, -1):
        S[k] = Ru + B.T @ P[k + 1] @ B
        L[k] = sla.solve(S[k], B.T @ P[k + 1] @ A, assume_a="pos")
        Pk = Qx + A.T @ P[k + 1] @ A - A.T @ P[k + 1] @ B @ L[k]
        P[k] = 0.5 * (Pk + Pk.T)
    return P, S, L


@dataclass(frozen=True, eq=False)
class LQGDesign:
    """Theorem 4's controller (or the certainty-equivalent baseline) and its analytic cost.

    Attributes
    ----------
    estimation : TeamDesign   the MTMSE (or MMSE) design of problem (67)
    P, S, L : Riccati solutions
    cost : float              the expected total cost J (64)
    base_cost : float         the strategy-independent part of (66)
    """

    problem: LQGProblem
    horizon: int
    kind: str
    estimation: TeamDesign
    P: FloatArray
    S: FloatArray
    L: FloatArray
    cost: float
    base_cost: float

    def F_at(self, k: int) -> tuple:
        return self.estimation.gain_at(k)


def design_lqg(problem: LQGProblem, horizon: int, *, kind: str = "mtmse") -> LQGDesign:
    """Design the optimal controller (``kind="mtmse"``, Theorem 4) or the CE baseline (``kind="mmse"``)."""
    if kind not in ("mtmse", "mmse"):
        raise ShapeError(f"kind: expected 'mtmse' (Theorem 4) or 'mmse' (certainty equivalence), found {kind!r}")
    T = V.positive_int(horizon, "horizon", minimum=2)
    sys = problem.system
    P, S, L = backward_riccati(problem, T)
    cost = TeamCost(S=S, L=L, n_agents=sys.n_agents)  # weight S(k), target L(k) x~(k)   (67)
    structure = InformationStructure.delayed_sharing(sys.n_agents, 1)
    est = (design_mtmse if kind == "mtmse" else design_mmse)(sys, cost, structure, T - 1)
    base = float(np.trace(sys.Sigma_x @ P[0]) + sum(np.trace(sys.Q_at(k) @ P[k + 1]) for k in range(T - 1)))
    return LQGDesign(problem, T, kind, est, P, S, L, base + est.require_cost(), base)


def simulate_closed_loop(design: LQGDesign, n_runs: int, *, rng: Any) -> dict[str, Any]:
    """Closed-loop Monte Carlo of the controller (70): every agent uses only I_i(k).

    Returns the per-run total costs (64) and the mean with its standard error.
    """
    from ..simulation.sampling import sample_paths

    prob, T = design.problem, design.horizon
    sys = prob.system
    n, du = sys.n_agents, prob.du
    A, B, Qx, Ru = sys.A_at(0), prob.B, prob.Q_x, prob.R_u
    # primitive noises from the sampler (x there is the control-free part x~)
    paths = sample_paths(sys, T, n_runs, rng=rng)
    x = paths.x[:, 0].copy()
    xhat = np.zeros_like(x)  # E[x(0)] = 0: the common predictor with controls
    total = np.zeros(n_runs)
    est = design.estimation
    for k in range(T):
        if k == T - 1:
            total += np.einsum("ra,ab,rb->r", x, Qx, x)
            break
        y = [x @ sys.C_at(i, k).T + paths.v[i][:, k] for i in range(n)]
        F = est.gain_at(k)
        u = np.empty((n_runs, n * du))
        for i in range(n):  # u_i = -L_i x^ - F_i (y_i - C_i x^)            (70)
            blk = slice(i * du, (i + 1) * du)
            u[:, blk] = -xhat @ design.L[k][blk].T - (y[i] - xhat @ sys.C_at(i, k).T) @ F[i].T
        total += np.einsum("ra,ab,rb->r", x, Qx, x) + np.einsum("ra,ab,rb->r", u, Ru, u)
        ystack = np.concatenate(y, axis=1)
        K = est.K_at(k)
        xhat = (xhat + (ystack - xhat @ sys.C_stack(k).T) @ K.T) @ A.T + u @ B.T  # predictor with the known u
        x = x @ A.T + u @ B.T + paths.w[:, k]
    return {"costs": total, "mean": float(total.mean()), "sem": float(total.std(ddof=1) / np.sqrt(n_runs))}
