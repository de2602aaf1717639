"""The covariance-intersection weights (active-set Newton) against SciPy's SLSQP and the KKT conditions."""

import numpy as np
import pytest
import scipy.optimize as sopt

from teamkf.estimators._consensus_common import ci_weights


def _trace_cost(w, Ys):
    return float(np.trace(np.linalg.inv(np.tensordot(w, Ys, axes=1))))


def _slsqp(Ys):
    m = len(Ys)
    res = sopt.minimize(
        lambda w: _trace_cost(w, Ys),
        np.full(m, 1.0 / m),
        method="SLSQP",
        bounds=[(0.0, 1.0)] * m,
        constraints=({"type": "eq", "fun": lambda w: np.sum(w) - 1.0},),
        options={"ftol": 1e-14, "maxiter": 500},
    )
    w = np.clip(res.x, 0.0, None)
    return w / w.sum()


def _instances(seed, count):
    rng = np.random.default_rng(seed)
    for a in range(count):
        m, d = int(rng.integers(2, 14)), int(rng.choice([1, 2, 4, 7]))
        Ys = []
        for _ in range(m):
            B = rng.standard_normal((d, max(1, d - int(rng.integers(0, 2)))))  # some nearly rank-deficient
            Ys.append(B @ B.T + float(rng.choice([1e-3, 0.1, 1.0])) * np.eye(d))
        if a % 4 == 0:
            Ys[1] = Ys[0].copy()  # a flat direction of the cost
        yield np.stack(Ys)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_ci_weights_match_slsqp_and_satisfy_kkt(seed):
    for Ys in _instances(seed, 25):
        w = ci_weights(list(Ys))
        assert w.shape == (len(Ys),) and np.all(w >= 0) and abs(w.sum() - 1.0) < 1e-12
        f, f_ref = _trace_cost(w, Ys), _trace_cost(_slsqp(Ys), Ys)
        assert f <= f_ref * (1 + 1e-9), (f, f_ref)
        # KKT: g_j = -tr(P^2 Y_j) equals λ where ω_j > 0 and is >= λ where ω_j = 0
        P = np.linalg.inv(np.tensordot(w, Ys, axes=1))
        g = -np.einsum("ab,jba->j", P @ P, Ys)
        on = w > 1e-9
        lam = g[on].mean()
        scale = np.abs(g).max()
        assert np.all(np.abs(g[on] - lam) <= 1e-6 * scale)
        assert np.all(g[~on] >= lam - 1e-6 * scale)


def test_ci_weights_never_worse_than_the_best_single_estimate():
    Y = np.diag([1.0, 1.0])
    Ys = [Y, 100.0 * Y, np.diag([200.0, 0.01])]
    w = ci_weights(Ys)
    best = min(np.trace(np.linalg.inv(y)) for y in Ys)
    assert _trace_cost(w, np.stack(Ys)) <= best + 1e-12
    assert ci_weights([Y]).tolist() == [1.0]
