r"""Theorem 3 of Das & Moura (2016): the tracking capacity of a system on a graph.

.. math::

    C = \max_{B^C, B^I \text{ structured}} \frac{\lambda_1}{\lambda_m \, \| I - B^C - B^I \tilde D_H \|_2}

(λ_1, λ_m: the smallest and largest non-zero eigenvalues of G; B^C with the graph's Laplacian block pattern,
B^I block-diagonal). :func:`tracking_capacity` solves the norm minimization as an SDP (cvxpy, small problems);
:func:`tracking_capacity_upper_bound` is a graph-independent closed-form bound that needs no solver.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ... import _validation as V
from ...models import LinearGaussianSystem
from ...network.graph import CommGraph
from .model import _neighbors, pseudo_state_model

__all__ = ["TrackingCapacity", "tracking_capacity_upper_bound", "tracking_capacity"]


@dataclass(frozen=True, eq=False)
class TrackingCapacity:
    """The tracking capacity of Theorem 3 and the structured gains that attain it.

    Attributes
    ----------
    capacity : float           C = λ_1 / (λ_m min ||M||_2)  (inf when min ||M|| = 0)
    min_norm : float           min over structured B^C, B^I of ||I - B^C - B^I D̃_H||_2 (on range(G)^N)
    lower_bound_norm : float   min over B^I alone of ||M (1 ⊗ I)|| / sqrt(N): M (1 ⊗ y) does not depend on
                               B^C, so every graph — the complete one too — has min_norm >= this
    capacity_upper : float     λ_1 / (λ_m lower_bound_norm): no graph exceeds it
    lambda_ratio : float       λ_1 / λ_m
    B_cons, B_innov : tuples   optimal reduced-coordinate blocks (per agent)
    status : str               solver status
    """

    capacity: float
    min_norm: float
    lower_bound_norm: float
    capacity_upper: float
    lambda_ratio: float
    B_cons: tuple
    B_innov: tuple
    status: str


def tracking_capacity_upper_bound(system: LinearGaussianSystem) -> float:
    r"""A graph-independent closed-form upper bound on Theorem 3's capacity (no solver needed).

    Since B^C (1 ⊗ y) = 0, ||M|| >= ||stack_n(I - B_u^n C̃_n)|| / sqrt(N) (see :func:`tracking_capacity`), and
    ||X||_2^2 >= ||X||_F^2 / r with ||I - B C̃_n||_F^2 >= r - rank(C̃_n), so

    .. math::

        \min ||I - B^C - B^I \tilde D_H||_2 \ge \sqrt{1 - \textstyle\sum_n \operatorname{rank}(H_n U) / (N r)}, \qquad
        C \le \frac{\lambda_1}{\lambda_m} \Big/ \sqrt{1 - \textstyle\sum_n \operatorname{rank}(H_n U)/(N r)}

    for every graph (inf when the agents' ranks add up to N r, e.g. every agent observes range(G)).
    """
    model = pseudo_state_model(system)
    N, r = system.n_agents, model.rank
    ranks = sum(int(np.linalg.matrix_rank(c)) for c in model.C_tilde)
    frac = 1.0 - ranks / (N * r)
    ratio = model.lambda_1 / model.lambda_m
    return float("inf") if frac <= 0 else ratio / float(np.sqrt(frac))


def tracking_capacity(system: LinearGaussianSystem, graph: CommGraph, *, solver: str | None = None, zero_tol: float = 1e-7) -> TrackingCapacity:
    r"""Theorem 3: C = max over structured B^C, B^I of λ_1 / (λ_m ||I - B^C - B^I D̃_H||_2), with cvxpy.

    B^C has the graph's Laplacian block pattern ([B^C]_{nl} = -B^{nl}, [B^C]_{nn} = Σ_l B^{nl}) and B^I is
    block-diagonal; minimizing the spectral norm of this affine map is a convex (SDP) problem. It is
    solved in reduced coordinates on range(G)^N (B_r^{nl}: r x r, B_u^n: r x M_n), which equals the
    paper's problem when G is invertible and is its meaningful restriction when G is singular (on
    null(G)^N the printed M is the identity). For small problems only (the SDP has N r rows).

    Needs the optional extra ``cvx`` (``pip install 'teamkf[cvx]'``).

    Also returned: a graph-independent lower bound on the norm. Since B^C (1 ⊗ y) = 0,
    M (1 ⊗ y) = [(I - B_u^n C̃_n) y]_n whatever the graph, so even the complete graph has a finite
    capacity unless every agent alone observes range(G) (then B_u^n C̃_n = I is possible and C = inf).
    On every connected graph we tried the optimum *attains* this bound (line = ring = complete): the
    capacity (53) depends on the graph only through whether each connected component jointly observes
    range(G) (``docs/cikf.md``).
    """
    cp = V.require("cvxpy", "cvx")
    model = pseudo_state_model(system)
    N = system.n_agents
    nbrs = _neighbors(graph, N)
    r = model.rank
    Ct = model.C_tilde
    Bc = {(n, l): cp.Variable((r, r)) for n in range(N) for l in nbrs[n]}
    Bu = [cp.Variable((r, Ct[n].shape[0])) for n in range(N)]
    eye = np.eye(r)
    blocks = []
    for n in range(N):
        row = []
        for l in range(N):
            if l == n:
                expr = eye - Bu[n] @ Ct[n]
                for q in nbrs[n]:
                    expr = expr - Bc[(n, q)]
                row.append(expr)
            elif l in nbrs[n]:
                row.append(Bc[(n, l)])
            else:
                row.append(np.zeros((r, r)))
        blocks.append(row)
    Mexpr = cp.bmat(blocks)
    prob = cp.Problem(cp.Minimize(cp.sigma_max(Mexpr)))
    prob.solve(solver=solver)
    min_norm = float(prob.value)
    # graph-independent lower bound: M (1 ⊗ I_r) / sqrt(N) = stack_n (I - B_u^n C̃_n) / sqrt(N)
    Bu2 = [cp.Variable((r, Ct[n].shape[0])) for n in range(N)]
    stack = cp.vstack([eye - Bu2[n] @ Ct[n] for n in range(N)]) / np.sqrt(N)
    prob2 = cp.Problem(cp.Minimize(cp.sigma_max(stack)))
    prob2.solve(solver=solver)
    lb = float(prob2.value)
    ratio = model.lambda_1 / model.lambda_m
    cap = float("inf") if min_norm <= zero_tol else ratio / min_norm
    cap_up = float("inf") if lb <= zero_tol else ratio / lb
    return TrackingCapacity(
        cap,
        min_norm,
        lb,
        cap_up,
        ratio,
        tuple(np.hstack([Bc[(n, l)].value for l in nbrs[n]]) if nbrs[n] else np.zeros((r, 0)) for n in range(N)),
        tuple(Bu[n].value for n in range(N)),
        str(prob.status),
    )
