"""Gamma F = eta: the operator, the dense assembly and the solvers agree with an explicit Kronecker matrix."""

import numpy as np
import pytest

from teamkf.estimators.gamma import GammaProblem
from teamkf.exceptions import ConvergenceError


def problem(rng, n=4, dz=2, D=12, sparse_S=False):
    M = rng.standard_normal((D, D + 3))
    Sigma = M @ M.T / D + 0.1 * np.eye(D)
    idx = [np.sort(rng.choice(D, size=int(rng.integers(1, 6)), replace=False)) for _ in range(n)]
    B = rng.standard_normal((n * dz, n * dz))
    S = B @ B.T + np.eye(n * dz)
    if sparse_S:  # tridiagonal agent coupling
        for i in range(n):
            for j in range(n):
                if abs(i - j) > 1:
                    S[i * dz : (i + 1) * dz, j * dz : (j + 1) * dz] = 0
        S += n * np.eye(n * dz)
    return GammaProblem(S, Sigma, idx, dz)


def explicit_gamma(g):
    """Column-major vec, Gamma_ij = Sigma_ij (x) S_ij (Lemma 5), with np.kron."""
    dz = g.dz
    sizes = [dz * len(ix) for ix in g.idx]
    o = np.concatenate([[0], np.cumsum(sizes)])
    G = np.zeros((o[-1], o[-1]))
    for i, ii in enumerate(g.idx):
        for j, jj in enumerate(g.idx):
            G[o[i] : o[i + 1], o[j] : o[j + 1]] = np.kron(g.Sigma[np.ix_(ii, jj)], g.S[i * dz : (i + 1) * dz, j * dz : (j + 1) * dz])
    return G, o


@pytest.mark.parametrize("seed", range(5))
@pytest.mark.parametrize("sparse_S", [False, True])
def test_operator_dense_and_kron_agree(seed, sparse_S):
    rng = np.random.default_rng(seed)
    g = problem(rng, sparse_S=sparse_S)
    F = [rng.standard_normal((g.dz, len(ix))) for ix in g.idx]
    x = g.flatten(F)
    np.testing.assert_allclose(g.apply_flat(x), g.dense() @ x, rtol=1e-12, atol=1e-12)
    G, o = explicit_gamma(g)
    y = G @ np.concatenate([f.ravel(order="F") for f in F])
    out = g.apply(F)
    for i in range(len(F)):
        np.testing.assert_allclose(out[i].ravel(order="F"), y[o[i] : o[i + 1]], rtol=1e-12, atol=1e-12)
    assert np.all(np.linalg.eigvalsh(g.dense()) > 0)  # Lemma 5: S > 0, Sigma_ii > 0 => Gamma > 0


@pytest.mark.parametrize("seed", range(4))
def test_dense_and_cg_solutions_agree(seed):
    rng = np.random.default_rng(seed)
    g = problem(rng, n=6, dz=2, D=20)
    eta = [rng.standard_normal((g.dz, len(ix))) for ix in g.idx]
    Fd = g.solve(eta, method="dense")
    Fc = g.solve(eta, method="cg", rtol=1e-13)
    assert g.method_used == "cg" and g.iterations > 0
    for a, b in zip(Fd, Fc):
        np.testing.assert_allclose(a, b, rtol=1e-8, atol=1e-10)
    res = g.apply(Fd)
    for r, e in zip(res, eta):
        np.testing.assert_allclose(r, e, rtol=1e-9, atol=1e-10)


def test_auto_switches_to_cg_when_dense_would_not_fit():
    rng = np.random.default_rng(0)
    g = problem(rng)
    assert g.choose("auto") == "dense"
    assert g.choose("auto", dense_max_bytes=8) == "cg"


def test_cg_reports_non_convergence():
    rng = np.random.default_rng(0)
    g = problem(rng, n=6, D=20)
    eta = [rng.standard_normal((g.dz, len(ix))) for ix in g.idx]
    with pytest.raises(ConvergenceError, match="conjugate gradients"):
        g.solve(eta, method="cg", max_iter=1, rtol=1e-15)


def test_empty_local_information():
    g = GammaProblem(np.eye(2), np.eye(3), [np.zeros(0, int), np.zeros(0, int)], 1)
    F = g.solve([np.zeros((1, 0)), np.zeros((1, 0))])
    assert [f.shape for f in F] == [(1, 0), (1, 0)]
