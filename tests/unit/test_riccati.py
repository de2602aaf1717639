"""Tests of teamkf.estimators.riccati: steady-state filter Riccati solutions and (A5) checks."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg as sla
from hypothesis import given, settings
from hypothesis import strategies as st

from teamkf import _linalg
from teamkf.estimators import riccati as ric
from teamkf.estimators.riccati import (
    check_detectable,
    check_stabilizable,
    is_detectable,
    is_stabilizable,
    riccati_residual,
    solve_filter_dare,
    steady_state_kalman,
    unstable_unobservable_modes,
)
from teamkf.exceptions import (
    ArgumentError,
    ConvergenceError,
    DetectabilityError,
    NotPositiveDefiniteError,
    ShapeError,
    TeamkfError,
)

# ---------------------------------------------------------------------------
# helpers
# ---------------------------------------------------------------------------


def random_system(seed: int, dx: int, dy: int, rho: float):
    """A generic (hence detectable and stabilizable) system with spectral radius ``rho``."""
    rng = np.random.default_rng(seed)
    A = rng.standard_normal((dx, dx))
    A *= rho / max(np.abs(np.linalg.eigvals(A)))
    C = rng.standard_normal((dy, dx))
    Bq = rng.standard_normal((dx, max(1, dx // 2)))
    Q = Bq @ Bq.T + 0.01 * np.eye(dx)
    Br = rng.standard_normal((dy, dy))
    R = Br @ Br.T + 0.5 * np.eye(dy)
    return A, C, Q, R


def finite_horizon_limit(A, C, Q, R, steps: int = 20000):
    """Iterate P(t+1) = A (P - P C'(C P C' + R)^-1 C P) A' + Q from P(1) = 0."""
    P = np.zeros_like(A)
    for _ in range(steps):
        S = C @ P @ C.T + R
        P_new = A @ (P - P @ C.T @ np.linalg.solve(S, C @ P)) @ A.T + Q
        P_new = 0.5 * (P_new + P_new.T)
        if np.linalg.norm(P_new - P) <= 1e-15 * np.linalg.norm(P_new):
            return P_new
        P = P_new
    return P


def closed_loop_radius(A, C, R, P):
    K = P @ C.T @ np.linalg.inv(C @ P @ C.T + R)
    return max(np.abs(np.linalg.eigvals(A - A @ K @ C)))


def brute_undetectable(A, C) -> bool:
    """PBH on all eigenvalues: some |lambda| >= 1 with rank [A - lambda I; C] < n."""
    n = A.shape[0]
    tol = ric.PBH_RTOL * max(np.linalg.norm(A), np.linalg.norm(C), np.finfo(float).tiny)
    for lam in np.linalg.eigvals(A):
        if abs(lam) >= 1.0 - ric.UNIT_CIRCLE_TOL:
            M = np.vstack([A - lam * np.eye(n), C.astype(complex)])
            if np.linalg.svd(M, compute_uv=False)[-1] <= tol:
                return True
    return False


def rel(X, Y):
    return np.linalg.norm(X - Y) / np.linalg.norm(Y)


CASES = [
    (seed, dx, dy, rho)
    for seed, (dx, dy, rho) in enumerate(
        [
            (1, 1, 0.5),
            (1, 1, 2.0),
            (2, 1, 1.3),
            (3, 2, 0.9),
            (5, 1, 1.2),
            (5, 3, 1.5),
            (8, 2, 1.1),
            (10, 1, 0.95),
            (10, 4, 1.4),
            (15, 3, 1.05),
            (20, 5, 1.2),
            (20, 1, 0.8),
            (25, 8, 1.3),
            (30, 3, 1.1),
            (30, 12, 1.6),
            (30, 30, 2.0),
        ]
    )
]


# ---------------------------------------------------------------------------
# solver accuracy
# ---------------------------------------------------------------------------


@pytest.mark.parametrize("seed,dx,dy,rho", CASES)
def test_sda_agrees_with_scipy(seed, dx, dy, rho):
    A, C, Q, R = random_system(seed, dx, dy, rho)
    P_sda = solve_filter_dare(A, C, Q, R, method="sda")
    P_sp = solve_filter_dare(A, C, Q, R, method="scipy")
    assert rel(P_sda, P_sp) < 1e-9
    assert np.allclose(P_sda, P_sda.T, rtol=0, atol=0)
    assert riccati_residual(A, C, Q, R, P_sda) < 1e-12
    assert closed_loop_radius(A, C, R, P_sda) < 1.0
    assert np.linalg.eigvalsh(P_sda)[0] > 0  # Q > 0 here, so P >= Q > 0


@pytest.mark.parametrize("seed,dx,dy,rho", CASES[::2])
def test_sda_equals_finite_horizon_limit(seed, dx, dy, rho):
    A, C, Q, R = random_system(seed, dx, dy, rho)
    P = solve_filter_dare(A, C, Q, R, method="sda")
    assert rel(P, finite_horizon_limit(A, C, Q, R)) < 1e-10


def test_scipy_transpose_convention_is_the_filter_equation():
    # a non-symmetric A and a wide C distinguish eq. 37 from the control DARE
    A = np.array([[1.2, 0.7, 0.0], [0.0, 0.5, 0.3], [0.1, 0.0, 0.9]])
    C = np.array([[1.0, 0.0, 0.0]])
    Q, R = np.diag([1.0, 0.5, 0.2]), np.array([[0.3]])
    P = solve_filter_dare(A, C, Q, R, method="scipy")
    rhs = A @ P @ A.T - A @ P @ C.T @ np.linalg.inv(C @ P @ C.T + R) @ C @ P @ A.T + Q
    assert np.allclose(P, rhs, rtol=1e-12, atol=1e-12)
    assert rel(P, finite_horizon_limit(A, C, Q, R)) < 1e-10


def test_singular_q_and_scalar_covariances():
    # Q singular but (A, Q^1/2) stabilizable: noise enters one state, couplings spread it
    A2 = np.array([[1.1, 0.0], [0.4, 0.8]])  # x2 driven by x1; noise only on x1
    Q2 = np.diag([1.0, 0.0])
    C2 = np.array([[0.0, 1.0]])  # x1 visible through x2's dynamics
    assert is_detectable(A2, C2) and is_stabilizable(A2, Q2)
    P = solve_filter_dare(A2, C2, Q2, 0.2)
    assert rel(P, solve_filter_dare(A2, C2, Q2, 0.2, method="scipy")) < 1e-9
    assert rel(P, finite_horizon_limit(A2, C2, Q2, np.array([[0.2]]))) < 1e-10
    # scalars mean multiples of I
    A3, C3, _, _ = random_system(3, 4, 2, 1.2)
    assert np.allclose(solve_filter_dare(A3, C3, 1.0, 0.5), solve_filter_dare(A3, C3, np.eye(4), 0.5 * np.eye(2)))


def test_steady_state_kalman_outputs():
    A, C, Q, R = random_system(7, 6, 2, 1.3)
    P, K, Pf = steady_state_kalman(A, C, Q, R)
    assert np.allclose(P, solve_filter_dare(A, C, Q, R), rtol=1e-13, atol=0)
    K_ref = P @ C.T @ np.linalg.inv(C @ P @ C.T + R)
    assert np.allclose(K, K_ref, rtol=1e-10, atol=1e-12)
    Pf_ref = P - P @ C.T @ np.linalg.inv(C @ P @ C.T + R) @ C @ P
    assert np.allclose(Pf, Pf_ref, rtol=1e-10, atol=1e-12)
    assert np.array_equal(Pf, Pf.T)
    # the predictor covariance is the time update of the filtered one
    assert np.allclose(P, A @ Pf @ A.T + Q, rtol=1e-10, atol=1e-12)
    assert K.shape == (6, 2) and Pf.shape == (6, 6)


def test_uav_formation_example():
    # team-MMSE paper: A = 0.55 I + 0.1 11', agent 1 measures 2 * sum, agent i >= 2 measures 0.1 x_i
    n = 40
    A = 0.55 * np.eye(n) + 0.1 * np.ones((n, n))
    C = np.vstack([2.0 * np.ones(n), 0.1 * np.eye(n)[1:]])
    assert max(abs(np.linalg.eigvals(A))) == pytest.approx(0.55 + 0.1 * n)
    P_sda = solve_filter_dare(A, C, np.eye(n), 0.1, method="sda")
    P_sp = solve_filter_dare(A, C, np.eye(n), 0.1, method="scipy")
    assert rel(P_sda, P_sp) < 1e-9
    assert closed_loop_radius(A, C, 0.1 * np.eye(n), P_sda) < 1.0


def test_sda_max_iter_raises_and_auto_falls_back():
    A, C, Q, R = random_system(11, 8, 2, 1.3)
    with pytest.raises(ConvergenceError, match=r"did not converge in 1 iterations"):
        solve_filter_dare(A, C, Q, R, method="sda", max_iter=1)
    P_auto = solve_filter_dare(A, C, Q, R, method="auto", max_iter=1)  # falls back to scipy
    assert rel(P_auto, solve_filter_dare(A, C, Q, R, method="scipy")) < 1e-12


def test_verification_rejects_a_non_stabilizing_solution():
    # (A, Q^1/2) not stabilizable; without the check, the limit from P = 0 is not stabilizing
    A = np.diag([1.5, 0.5])
    C = np.eye(2)
    Q = np.diag([0.0, 1.0])
    R = np.eye(2)
    with pytest.raises(DetectabilityError):
        solve_filter_dare(A, C, Q, R)
    # SDA finds the non-stabilizing P = diag(0, p); the closed-loop check rejects it
    with pytest.raises(ConvergenceError, match=r"spectral radius"):
        solve_filter_dare(A, C, Q, R, method="sda", check=False)


# ---------------------------------------------------------------------------
# detectability / stabilizability
# ---------------------------------------------------------------------------


def _rotate(A, C, seed=0):
    """Same system in random orthogonal coordinates (so no test relies on a diagonal A)."""
    n = A.shape[0]
    U, _ = np.linalg.qr(np.random.default_rng(seed).standard_normal((n, n)))
    return U @ A @ U.T, C @ U.T, U


def test_unstable_invisible_mode_is_not_detectable():
    A, C, _ = _rotate(np.diag([1.5, 0.5, 0.8]), np.array([[0.0, 1.0, 1.0]]))
    assert is_detectable(A, C) is False
    modes = unstable_unobservable_modes(A, C)
    assert len(modes) == 1 and modes[0] == pytest.approx(1.5, rel=1e-10)
    with pytest.raises(DetectabilityError, match=r"\(A, C\) is not detectable.*1\.5") as ei:
        check_detectable(A, C)
    msg = str(ei.value)
    assert "add a measurement" in msg.lower() and "(A5)" in msg
    with pytest.raises(DetectabilityError, match=r"1\.5"):
        solve_filter_dare(A, C, np.eye(3), 1.0)
    with pytest.raises(DetectabilityError, match=r"^\(A1, C1\) is not detectable"):
        check_detectable(A, C, what="(A1, C1)")


def test_stable_unobservable_mode_is_detectable():
    A, C, _ = _rotate(np.diag([0.5, 1.5, 0.9]), np.array([[0.0, 1.0, 1.0]]))
    assert unstable_unobservable_modes(A, C) == []
    assert is_detectable(A, C)
    check_detectable(A, C)
    P = solve_filter_dare(A, C, np.eye(3), 1.0)
    assert riccati_residual(A, C, np.eye(3), 1.0, P) < 1e-12


def test_complex_pair_and_marginal_modes():
    th = 0.7
    rot = 1.2 * np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
    A = sla.block_diag(rot, 0.3)
    A, C, _ = _rotate(A, np.array([[0.0, 0.0, 1.0]]), seed=3)
    modes = unstable_unobservable_modes(A, C)
    assert len(modes) == 2
    assert sorted(m.imag for m in modes) == pytest.approx([-1.2 * np.sin(th), 1.2 * np.sin(th)])
    assert all(abs(abs(m) - 1.2) < 1e-10 for m in modes)
    # a random walk (|lambda| = 1 exactly) that is not measured is not detectable
    assert not is_detectable(np.eye(2), np.array([[1.0, 0.0]]))
    assert is_detectable(np.eye(2), np.eye(2))
    # a pure rotation (|lambda| = 1 up to round-off) is caught too
    rot1 = np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
    assert len(unstable_unobservable_modes(rot1, np.zeros((1, 2)))) == 2
    # Jordan block: only the eigenvector direction matters
    J = np.array([[1.0, 1.0], [0.0, 1.0]])
    assert not is_detectable(J, np.array([[0.0, 1.0]]))
    assert is_detectable(J, np.array([[1.0, 0.0]]))
    # no outputs at all
    assert unstable_unobservable_modes(np.diag([2.0, 0.1]), np.zeros((0, 2))) == [2.0]


def test_margin_flags_nearly_unstable_modes():
    A = np.diag([0.99, 0.5])
    C = np.array([[0.0, 1.0]])
    assert unstable_unobservable_modes(A, C) == []
    assert unstable_unobservable_modes(A, C, margin=0.05) == [pytest.approx(0.99)]


def test_many_unstable_modes_repeated_eigenvalue_is_fast_and_correct():
    # 300 identical unstable modes: one cluster, one SVD
    n = 300
    A = 1.01 * np.eye(n)
    C = np.eye(n)
    assert is_detectable(A, C)
    C2 = np.eye(n)[:-1]
    assert unstable_unobservable_modes(A, C2) == [pytest.approx(1.01)]


@pytest.mark.parametrize("seed", range(4))
def test_eigenvector_path_agrees_with_svd_path(seed, monkeypatch):
    # k > _SVD_MAX_K distinct unstable eigenvalues; one hidden unstable mode, one hidden stable mode
    rng = np.random.default_rng(seed)
    k = 110
    lam = rng.uniform(1.1, 3.0, k) * rng.choice([-1, 1], k)
    D = np.diag(np.concatenate([lam, [0.4]]))
    C = rng.standard_normal((2, k + 1))
    C[:, 5] = 0.0  # hide the unstable mode lam[5]
    C[:, -1] = 0.0  # hide the stable mode
    S = np.eye(k + 1) + 0.1 * rng.standard_normal((k + 1, k + 1)) / np.sqrt(k)
    A = S @ D @ np.linalg.inv(S)
    Cs = C @ np.linalg.inv(S)
    fast = unstable_unobservable_modes(A, Cs)
    assert len(fast) == 1 and fast[0] == pytest.approx(lam[5], rel=1e-8)
    monkeypatch.setattr(_linalg, "_SVD_MAX_K", 10**9)
    slow = unstable_unobservable_modes(A, Cs)
    assert len(slow) == 1 and slow[0] == pytest.approx(fast[0], rel=1e-10)


def test_stabilizability():
    A, _, U = _rotate(np.diag([1.5, 0.5, 0.2]), np.zeros((0, 3)), seed=5)
    Q_bad = U @ np.diag([0.0, 1.0, 1.0]) @ U.T  # no noise on the unstable mode
    Q_ok = U @ np.diag([1.0, 0.0, 0.0]) @ U.T  # noise only on the unstable mode
    assert not is_stabilizable(A, Q_bad)
    assert is_stabilizable(A, Q_ok)
    check_stabilizable(A, Q_ok)
    with pytest.raises(DetectabilityError, match=r"not stabilizable.*1\.5") as ei:
        check_stabilizable(A, Q_bad)
    assert "finite horizon" in str(ei.value)
    C = np.ones((1, 3))
    with pytest.raises(DetectabilityError, match=r"stabilizable"):
        solve_filter_dare(A, C, Q_bad, 1.0)
    # left eigenvectors matter: noise on x1 reaches the unstable x2 through A
    A2 = np.array([[0.5, 0.0], [1.0, 1.5]])
    assert is_stabilizable(A2, np.diag([1.0, 0.0]))
    assert not is_stabilizable(A2.T, np.diag([1.0, 0.0]))


@pytest.mark.parametrize("seed", range(6))
def test_stabilizability_matches_detectability_of_transpose(seed):
    rng = np.random.default_rng(seed)
    n = 7
    A = 1.3 * rng.standard_normal((n, n)) / np.sqrt(n)
    lam, Wl = np.linalg.eig(A.T)
    real_unstable = [i for i in np.flatnonzero(abs(lam) >= 1) if lam[i].imag == 0]
    B = rng.standard_normal((n, 2))  # Q = B B' of rank 2
    hide = bool(seed % 2) and bool(real_unstable)
    if hide:  # make Q miss the left eigenvector of an unstable mode
        v = np.real(Wl[:, real_unstable[0]])
        B -= np.outer(v, v @ B) / (v @ v)
    Q = B @ B.T
    w, U = np.linalg.eigh(Q)
    Dt = (U * np.sqrt(np.clip(w, 0, None))).T  # Dt' Dt = Q
    assert is_stabilizable(A, Q) == (unstable_unobservable_modes(A.T, Dt) == []) == (not hide)


# ---------------------------------------------------------------------------
# property test against a brute-force PBH test
# ---------------------------------------------------------------------------


@st.composite
def pairs(draw):
    n = draw(st.integers(1, 6))
    dy = draw(st.integers(0, 3))
    hidden = draw(st.integers(0, n))
    seed = draw(st.integers(0, 2**32 - 1))
    scale_obs = draw(st.sampled_from([0.3, 0.8, 1.5, 3.0]))
    scale_hid = draw(st.sampled_from([0.3, 0.8, 1.5, 3.0]))
    rng = np.random.default_rng(seed)
    m = n - hidden
    A11 = scale_obs * rng.standard_normal((m, m)) / np.sqrt(max(m, 1))
    A22 = scale_hid * rng.standard_normal((hidden, hidden)) / np.sqrt(max(hidden, 1))
    A21 = rng.standard_normal((hidden, m))
    A = np.block([[A11, np.zeros((m, hidden))], [A21, A22]])
    C = np.hstack([rng.standard_normal((dy, m)), np.zeros((dy, hidden))])
    S = rng.standard_normal((n, n)) + 2.0 * np.eye(n)  # change of coordinates
    Si = np.linalg.inv(S)
    return S @ A @ Si, C @ Si


@settings(deadline=None, max_examples=30)
@given(pairs())
def test_detectability_matches_brute_pbh(pair):
    A, C = pair
    assert is_detectable(A, C) == (not brute_undetectable(A, C))


# ---------------------------------------------------------------------------
# bad input
# ---------------------------------------------------------------------------


def test_bad_shapes_name_the_argument():
    A, C, Q, R = random_system(0, 3, 2, 0.9)
    with pytest.raises(ShapeError, match=r"^A: .*square"):
        solve_filter_dare(np.ones((3, 2)), C, Q, R)
    with pytest.raises(ShapeError, match=r"^A: "):
        solve_filter_dare(np.ones(3), C, Q, R)
    with pytest.raises(ShapeError, match=r"^C: expected a kx3 matrix, found 2x4"):
        solve_filter_dare(A, np.ones((2, 4)), Q, R)
    with pytest.raises(ShapeError, match=r"^Q: expected a 3x3"):
        solve_filter_dare(A, C, np.eye(2), R)
    with pytest.raises(ShapeError, match=r"^R: expected a 2x2"):
        solve_filter_dare(A, C, Q, np.eye(3))
    with pytest.raises(ShapeError, match=r"^C: "):
        unstable_unobservable_modes(A, np.ones((1, 2)))
    with pytest.raises(ShapeError, match=r"^Q: "):
        is_stabilizable(A, np.eye(4))
    with pytest.raises(ShapeError, match=r"^A: .*NaN"):
        solve_filter_dare(np.full((3, 3), np.nan), C, Q, R)


def test_bad_covariances_name_the_argument():
    A, C, Q, R = random_system(0, 3, 2, 0.9)
    with pytest.raises(NotPositiveDefiniteError, match=r"^R: .*positive definite"):
        solve_filter_dare(A, C, Q, np.diag([1.0, 0.0]))
    with pytest.raises(NotPositiveDefiniteError, match=r"^R: "):
        steady_state_kalman(A, C, Q, -np.eye(2))
    with pytest.raises(NotPositiveDefiniteError, match=r"^Q: .*semi-definite"):
        solve_filter_dare(A, C, -np.eye(3), R)
    with pytest.raises(TeamkfError, match=r"^Q: .*symmetric"):
        solve_filter_dare(A, C, np.triu(np.ones((3, 3))), R)


def test_bad_options():
    A, C, Q, R = random_system(0, 3, 2, 0.9)
    with pytest.raises(ValueError, match=r"method"):
        solve_filter_dare(A, C, Q, R, method="newton")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match=r"tol"):
        solve_filter_dare(A, C, Q, R, tol=-1.0)
    with pytest.raises(ArgumentError, match=r"max_iter"):
        solve_filter_dare(A, C, Q, R, max_iter=0)


def test_exceptions_are_teamkf_errors():
    assert issubclass(DetectabilityError, TeamkfError)
    with pytest.raises(TeamkfError):
        check_detectable(np.diag([2.0]), np.zeros((1, 1)))
