"""Linear-algebra checks below the models layer: detectability and stabilizability (PBH tests).

(A, C) is detectable when every mode of A with |lambda| >= 1 is observable
through C; (A, Q^1/2) is stabilizable when every such mode is reachable from
the noise. The tests are Popov-Belevitch-Hautus tests on an ordered real Schur
form, with a tolerance scaled by the norms (:func:`_tol`); they are what the
steady-state designs (Theorem 3, the Riccati solver) and the Section VII
instance builder check. Moved here from :mod:`teamkf.estimators.riccati`
(which re-exports them) so that the study and models layers can use them
without importing an estimator.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from . import _validation as V
from ._lazy import scipy_linalg as sla  # SciPy loads on first use
from ._validation import FloatArray
from .exceptions import DetectabilityError, ShapeError

__all__ = ["block_diag", "inv", "unstable_unobservable_modes", "is_detectable", "is_stabilizable", "check_detectable", "check_stabilizable"]

#: relative tolerance of the PBH rank test (scaled by max(||A||_F, ||C||_F))
PBH_RTOL = 1e-8
#: eigenvalues with |lambda| >= 1 - margin - UNIT_CIRCLE_TOL count as unstable,
#: so that marginal modes computed as 0.9999999999999998 are not missed
UNIT_CIRCLE_TOL = float(np.sqrt(np.finfo(float).eps))
#: eigenvalues closer than this (relative to max(1, |lambda|)) are tested as one cluster
_CLUSTER_RTOL = 1e-6
#: above this many unstable eigenvalues, simple eigenvalues are tested with
#: their eigenvectors (O(k^3) in all) instead of one k x k SVD each (O(k^4))
_SVD_MAX_K = 96


def inv(a: FloatArray) -> FloatArray:
    """``np.linalg.inv(a)`` of one float64 square matrix, without its per-call argument checks (the same LAPACK
    routine, the same numbers: for the small matrices that the lossy runtime inverts once per agent, step and run).

    A singular matrix raises ``LinAlgError`` as ``np.linalg.inv`` does (it is handed to it when the fast path
    returns a NaN); anything but a float64 square matrix goes to ``np.linalg.inv`` directly.
    """
    if _INV is None or type(a) is not np.ndarray or a.dtype != np.float64 or a.ndim != 2 or a.shape[0] != a.shape[1] or not a.size:
        return np.asarray(np.linalg.inv(a), dtype=float)
    with np.errstate(invalid="ignore", over="ignore", divide="ignore", under="ignore"):
        out = _INV(a, signature="d->d")
    if np.isnan(out).any():  # singular (or NaN in a): np.linalg.inv raises, or returns the same NaNs
        return np.asarray(np.linalg.inv(a), dtype=float)
    return out  # type: ignore[no-any-return]


def _gufunc_inv() -> Any:
    try:
        from numpy.linalg import _umath_linalg  # the gufunc behind np.linalg.inv

        return _umath_linalg.inv
    except (ImportError, AttributeError):  # pragma: no cover - another numpy layout: the public function
        return None


_INV: Any = _gufunc_inv()


def block_diag(*blocks: ArrayLike) -> FloatArray:
    """The block-diagonal matrix diag(B_1, ..., B_m) of 2-D blocks (0-D and 1-D blocks are read as rows).

    The same matrix as :func:`scipy.linalg.block_diag` (bit for bit: it only copies), without its per-call
    overhead, which dominated the small per-step stacks of the designs (34 000 calls of about 0.5 ms each in
    one quick demo).

    Examples
    --------
    >>> block_diag(np.eye(1), 2 * np.eye(2)).tolist()
    [[1.0, 0.0, 0.0], [0.0, 2.0, 0.0], [0.0, 0.0, 2.0]]
    """
    mats = [np.atleast_2d(np.asarray(b)) for b in blocks]
    if any(m.ndim != 2 for m in mats):
        raise ShapeError(f"block_diag: every block must be at most 2-D; found shapes {[m.shape for m in mats]}")
    rows = sum(m.shape[0] for m in mats)
    cols = sum(m.shape[1] for m in mats)
    out = np.zeros((rows, cols), dtype=np.result_type(float, *mats) if mats else float)
    r = c = 0
    for m in mats:
        out[r : r + m.shape[0], c : c + m.shape[1]] = m
        r += m.shape[0]
        c += m.shape[1]
    return out


def _square(x: ArrayLike, name: str) -> FloatArray:
    a = V.matrix(x, name)
    if a.shape[0] != a.shape[1]:
        raise ShapeError(f"{name}: expected a square (d_x x d_x) state matrix, found {V.shape_str(a.shape)}")
    return a


def _psd_factor_rows(Q: FloatArray) -> FloatArray:
    """Rows ``F`` with ``F.T @ F == Q`` (Q symmetric PSD), zero directions dropped."""
    w, U = np.linalg.eigh(Q)
    scale = max(float(w[-1]), 0.0) if w.size else 0.0
    keep = w > max(scale, np.finfo(float).tiny) * Q.shape[0] * np.finfo(float).eps
    return (U[:, keep] * np.sqrt(w[keep])).T


# ----------------------------------------------------------------------------
# detectability / stabilizability
# ----------------------------------------------------------------------------


def _quasi_triangular_eigvals(T: FloatArray) -> np.ndarray:
    """Eigenvalues of a real quasi-upper-triangular (real Schur) matrix, in diagonal order."""
    n = T.shape[0]
    out = np.empty(n, dtype=complex)
    i = 0
    while i < n:
        if i + 1 < n and T[i + 1, i] != 0.0:
            out[i : i + 2] = np.linalg.eigvals(T[i : i + 2, i : i + 2])
            if out[i].imag < out[i + 1].imag:
                out[i], out[i + 1] = out[i + 1], out[i]
            i += 2
        else:
            out[i] = T[i, i]
            i += 1
    return out


def _schur_select(A: FloatArray, thr: float) -> tuple[FloatArray, FloatArray, np.ndarray]:
    """Real Schur form ``A = Z T Z'`` and the mask of diagonal positions with |lambda| >= thr."""
    T, Z = sla.schur(A, output="real")
    lam = _quasi_triangular_eigvals(T)
    sel = np.abs(lam) >= thr
    # a complex pair has one modulus, but keep the two halves consistent anyway
    i = 0
    n = T.shape[0]
    while i < n:
        if i + 1 < n and T[i + 1, i] != 0.0:
            sel[i] = sel[i + 1] = bool(sel[i] or sel[i + 1])
            i += 2
        else:
            i += 1
    return T, Z, sel


def _reorder(T: FloatArray, Z: FloatArray, sel: np.ndarray) -> tuple[FloatArray, FloatArray, int] | None:
    """Move the selected eigenvalues to the top-left (LAPACK ``dtrsen``); None if that fails."""
    if not sel.any() or sel.all():
        return T, Z, int(sel.sum())
    ts, qs, _wr, _wi, m, _s, _sep, info = sla.lapack.dtrsen(sel.astype(np.int32), T, Z, job="N")
    if info != 0 or int(m) != int(sel.sum()):
        return None
    return ts, qs, int(m)


def _cluster(lams: np.ndarray) -> list[list[int]]:
    """Group indices of (upper-half-plane) eigenvalues closer than _CLUSTER_RTOL."""
    clusters: list[list[int]] = []
    reps: list[complex] = []
    for i in np.argsort(-np.abs(lams), kind="stable"):
        lam = complex(lams[i])
        for c, rep in zip(clusters, reps):
            if abs(lam - rep) <= _CLUSTER_RTOL * max(1.0, abs(rep)):
                c.append(int(i))
                break
        else:
            clusters.append([int(i)])
            reps.append(lam)
    return clusters


def _pbh_offenders(T11: np.ndarray, Cr: np.ndarray, lams: np.ndarray, tol: float) -> list[complex]:
    """Eigenvalues ``lam`` of T11 (given) at which ``[T11 - lam I; Cr]`` is rank deficient.

    ``lams`` are the eigenvalues to test (complex pairs both listed); only the
    member with non-negative imaginary part is tested, its conjugate follows.
    """
    k = T11.shape[0]
    if k == 0 or lams.size == 0:
        return []
    if Cr.shape[0] > k:  # same singular values of the stack with Cr replaced by its R factor
        Cr = np.asarray(np.linalg.qr(Cr, mode="r"))
    upper = lams[lams.imag >= 0.0]
    eye = np.eye(k)

    def sigma_min(lam: complex) -> float:
        if lam.imag == 0.0:
            M = np.vstack([T11 - lam.real * eye, Cr])
        else:
            M = np.vstack([T11 - lam * eye, Cr.astype(complex)])
        return float(np.linalg.svd(M, compute_uv=False)[-1])

    eig_vectors: tuple[np.ndarray, np.ndarray] | None = None
    if k > _SVD_MAX_K:
        w, Vr = np.linalg.eig(T11)
        eig_vectors = (w, Vr)

    bad: list[complex] = []
    for cl in _cluster(upper):
        members = upper[cl]
        mean = complex(np.mean(members))
        if abs(mean.imag) <= 1e-14 * max(1.0, abs(mean)):
            mean = complex(mean.real, 0.0)
        if eig_vectors is not None and len(cl) == 1:
            w, Vr = eig_vectors
            j = int(np.argmin(np.abs(w - mean)))
            v = Vr[:, j]
            offending = float(np.linalg.norm(Cr @ v)) <= tol * float(np.linalg.norm(v))
        else:
            tests = [mean] + [complex(m) for m in members if abs(m - mean) > 64 * np.finfo(float).eps * max(1.0, abs(mean))]
            offending = any(sigma_min(lam) <= tol for lam in tests)
        if offending:
            bad.append(mean)
            if mean.imag != 0.0:
                bad.append(mean.conjugate())
    return bad


def _modes_from_subspace(T: FloatArray, Z: FloatArray, sel: np.ndarray, C: FloatArray, tol: float, *, left: bool) -> list[complex]:
    """Offending modes of a pair, given the Schur form of A and the unstable mask.

    ``left=False``: (A, C), unstable right invariant subspace (unstable first).
    ``left=True``: (A', C), obtained from the same Schur form of A: with the
    *stable* eigenvalues first, ``A = Z [S11 S12; 0 S22] Z'`` gives
    ``A' Z2 = Z2 S22'``, so Z2 spans the unstable invariant subspace of A'.
    """
    lam_all = _quasi_triangular_eigvals(T)
    r = _reorder(T, Z, ~sel if left else sel)
    if r is None:  # reordering failed (near-equal eigenvalues): test on the full form
        M = T.T if left else T
        return _pbh_offenders(M, C @ Z, lam_all[sel], tol)
    Ts, Zs, m = r
    if left:
        k = T.shape[0] - m
        T11 = Ts[m:, m:].T
        U1 = Zs[:, m:]
    else:
        k = m
        T11 = Ts[:k, :k]
        U1 = Zs[:, :k]
    if k == 0:
        return []
    lams = _quasi_triangular_eigvals(Ts[m:, m:] if left else T11)
    return _pbh_offenders(T11, C @ U1, lams, tol)


def _tol(A: FloatArray, C: FloatArray) -> float:
    scale = max(float(np.linalg.norm(A)), float(np.linalg.norm(C)), np.finfo(float).tiny)
    return PBH_RTOL * scale


def unstable_unobservable_modes(A: ArrayLike, C: ArrayLike, *, margin: float = 0.0) -> list[complex]:
    r"""Eigenvalues of ``A`` with :math:`|\lambda| \ge 1 - \text{margin}` that ``C`` cannot see.

    The pair :math:`(A, C)` is detectable iff every eigenvalue with
    :math:`|\lambda| \ge 1` is observable, i.e. (PBH/Hautus test)

    .. math::

        \operatorname{rank} \begin{bmatrix} A - \lambda I \\ C \end{bmatrix} = d_x .

    The test is restricted to the unstable invariant subspace: an ordered real
    Schur form :math:`A = [U_1\ U_2] \begin{bmatrix} T_{11} & T_{12} \\ 0 & T_{22}
    \end{bmatrix} [U_1\ U_2]^\top` with the :math:`k` unstable eigenvalues in
    :math:`T_{11}`, then, for each distinct eigenvalue :math:`\lambda` of
    :math:`T_{11}`, the smallest singular value of
    :math:`[T_{11} - \lambda I;\ C U_1]` is compared with
    ``PBH_RTOL * max(||A||_F, ||C||_F)``. Cost: one Schur decomposition
    (:math:`O(d_x^3)`) plus a :math:`2k \times k` SVD per distinct unstable
    eigenvalue (for :math:`k >` 96, simple eigenvalues use their eigenvectors,
    :math:`O(k^3)` in all).

    Parameters
    ----------
    A : (d_x, d_x) array_like
        State matrix.
    C : (d_y, d_x) array_like
        Output matrix (``d_y = 0`` allowed: then every unstable mode is returned).
    margin : float, optional
        Also test modes with :math:`1 - \text{margin} \le |\lambda| < 1`
        (nearly unstable). Eigenvalues within ``UNIT_CIRCLE_TOL`` (~1.5e-8)
        below the threshold are included too, so marginal modes computed with
        round-off are never missed.

    Returns
    -------
    list of complex
        The offending eigenvalues (one entry per distinct eigenvalue; complex
        pairs appear as both members), largest modulus first; empty iff the
        pair is detectable.
    """
    A_ = _square(A, "A")
    C_ = V.matrix(C, "C", (None, A_.shape[0]))
    if A_.shape[0] == 0:
        return []
    T, Z, sel = _schur_select(A_, 1.0 - float(margin) - UNIT_CIRCLE_TOL)
    if not sel.any():
        return []
    return _modes_from_subspace(T, Z, sel, C_, _tol(A_, C_), left=False)


def _stabilizability_modes(A_: FloatArray, Q_: FloatArray, margin: float = 0.0) -> list[complex]:
    D = _psd_factor_rows(Q_)  # D' D = Q
    if A_.shape[0] == 0:
        return []
    T, Z, sel = _schur_select(A_, 1.0 - float(margin) - UNIT_CIRCLE_TOL)
    if not sel.any():
        return []
    return _modes_from_subspace(T, Z, sel, D, _tol(A_, D), left=True)


def is_detectable(A: ArrayLike, C: ArrayLike) -> bool:
    """True iff every eigenvalue of ``A`` with ``|lambda| >= 1`` is observable through ``C``.

    See :func:`unstable_unobservable_modes` for the test.
    """
    return not unstable_unobservable_modes(A, C)


def is_stabilizable(A: ArrayLike, Q: ArrayLike) -> bool:
    r"""True iff :math:`(A, Q^{1/2})` is stabilizable (noise excites every unstable mode).

    With :math:`D D^\top = Q`, :math:`(A, D)` is stabilizable iff
    :math:`(A^\top, D^\top)` is detectable; and :math:`D^\top v = 0 \iff Q v = 0`
    for :math:`Q \succeq 0`, so the test is :func:`unstable_unobservable_modes`
    on :math:`(A^\top, D^\top)`, sharing one Schur decomposition of :math:`A`.
    """
    A_ = _square(A, "A")
    Q_ = V.covariance(Q, "Q", A_.shape[0])
    return not _stabilizability_modes(A_, Q_)


def _fmt_modes(modes: list[complex]) -> str:
    parts = []
    for lam in modes:
        if lam.imag == 0.0:
            parts.append(f"{lam.real:.6g}")
        else:
            parts.append(f"{lam.real:.6g}{lam.imag:+.6g}j (|lambda|={abs(lam):.6g})")
    return ", ".join(parts)


def check_detectable(A: ArrayLike, C: ArrayLike, *, what: str = "(A, C)") -> None:
    """Raise :class:`~teamkf.exceptions.DetectabilityError` unless ``(A, C)`` is detectable.

    The message names the pair (``what``), lists the unstable eigenvalues that
    the measurements cannot see, and suggests fixes.
    """
    modes = unstable_unobservable_modes(A, C)
    if modes:
        raise DetectabilityError(_detectability_message(what, modes))


def _detectability_message(what: str, modes: list[complex]) -> str:
    return (
        f"{what} is not detectable: the unstable eigenvalue(s) {_fmt_modes(modes)} of A are invisible to C "
        "(PBH rank test [A - lambda I; C] fails). Add a measurement of the mode (a row of C with a component "
        "along its eigenvector), or stabilize it; a steady-state design needs assumption (A5) of the team-MMSE "
        "paper -- use a finite horizon instead."
    )


def check_stabilizable(A: ArrayLike, Q: ArrayLike, *, what: str = "(A, Q^1/2)") -> None:
    """Raise :class:`~teamkf.exceptions.DetectabilityError` unless ``(A, Q^1/2)`` is stabilizable."""
    A_ = _square(A, "A")
    Q_ = V.covariance(Q, "Q", A_.shape[0])
    modes = _stabilizability_modes(A_, Q_)
    if modes:
        raise DetectabilityError(_stabilizability_message(what, modes))


def _stabilizability_message(what: str, modes: list[complex]) -> str:
    return (
        f"{what} is not stabilizable: the process noise Q does not excite the unstable eigenvalue(s) "
        f"{_fmt_modes(modes)} of A (PBH test on (A', Q^1/2) fails), so the steady-state Riccati solution is not "
        "stabilizing. Add process noise along the mode (make Q positive definite there), or use a finite horizon "
        "instead: a steady-state design needs assumption (A5) of the team-MMSE paper."
    )


# ----------------------------------------------------------------------------
# undetectable subspace and the growth of a Lyapunov lower bound (structural divergence)
# ----------------------------------------------------------------------------


def _orth(M: np.ndarray, tol: float) -> FloatArray:
    """Orthonormal basis (columns) of the range of ``M``: left singular vectors with singular value > ``tol``."""
    if M.size == 0:
        return np.zeros((M.shape[0], 0))
    U, s, _ = np.linalg.svd(M, full_matrices=False)
    return np.asarray(U[:, s > tol])


def _null(M: np.ndarray, tol: float) -> FloatArray:
    """Orthonormal basis (columns) of the null space of ``M``: right singular vectors with singular value <= ``tol``."""
    n = M.shape[1]
    if M.shape[0] == 0 or n == 0:
        return np.eye(n)
    _, s, Vh = np.linalg.svd(M, full_matrices=True)
    rank = int(np.sum(s > tol))
    return np.asarray(Vh[rank:].T.conj() if np.iscomplexobj(Vh) else Vh[rank:].T)


def _invariant_in_kernel(A: np.ndarray, M: np.ndarray, tol: float) -> FloatArray:
    """Orthonormal basis of the largest ``A``-invariant subspace inside ker ``M`` (the unobservable subspace of (A, M)).

    N_0 = ker M, N_{j+1} = {x in N_j : A x in N_j}: at most d_x SVDs, no powers of A (which overflow on unstable modes).
    """
    N = _null(M, tol)
    while N.shape[1]:
        N2 = N @ _null(A @ N - N @ (N.T @ (A @ N)), tol)
        if N2.shape[1] == N.shape[1]:
            return N
        N = N2
    return N


def undetectable_subspace(A: ArrayLike, C: ArrayLike) -> FloatArray:
    r"""Orthonormal basis V_+ (d_x x k) of the undetectable subspace of (A, C).

    U_+ = U ∩ X_u: the unobservable subspace U of (A, C) (the largest A-invariant subspace in ker C) intersected
    with the generalized eigenspace X_u of the eigenvalues with modulus >= 1 (``UNIT_CIRCLE_TOL`` below 1 counts).
    Both are A-invariant, so is U_+, and (A, C) is detectable iff k = 0. Computed without eigenvectors (so
    repeated eigenvalues and Jordan blocks are handled): U by :func:`_invariant_in_kernel`, then an ordered real
    Schur form of A restricted to U keeps its unstable part.
    """
    A_ = _square(A, "A")
    C_ = V.matrix(C, "C", (None, A_.shape[0]))
    tol = _tol(A_, C_)
    N = _invariant_in_kernel(A_, C_, tol)
    k = N.shape[1]
    if k == 0:
        return N
    AU = N.T @ A_ @ N
    thr = 1.0 - UNIT_CIRCLE_TOL
    try:
        _T, Z, sdim = sla.schur(AU, output="real", sort=lambda re, im: re * re + im * im >= thr * thr)
    except (np.linalg.LinAlgError, ValueError):  # reordering failed (nearly equal eigenvalues): keep all of U
        return N
    return np.asarray(N @ Z[:, : int(sdim)])


def _minimal_part(A: np.ndarray, M: np.ndarray, B: np.ndarray, tol_b: float, tol_m: float) -> FloatArray:
    """The state matrix of the part of (A, B, M) that is both reachable from B and seen by M (0 x 0 if none).

    Restrict A to the reachable subspace of (A, B) (invariant), then take the quotient by the unobservable
    subspace of (A, M) there: ``M A^t B = M_o A_o^t B_o`` with (A_o, B_o) reachable and (M_o, A_o) observable.
    """
    K = _orth(B, tol_b)
    tol_a = PBH_RTOL * max(1.0, float(np.linalg.norm(A)))
    while K.shape[1] and K.shape[1] < A.shape[0]:
        R = A @ K - K @ (K.T @ (A @ K))
        new = _orth(R, tol_a)
        if not new.shape[1]:
            break
        new = _orth(new - K @ (K.T @ new), tol_a)
        if not new.shape[1]:
            break
        K = np.hstack([K, new])
    if not K.shape[1]:
        return np.zeros((0, 0))
    Ac, Mc = K.T @ A @ K, M @ K
    N = _invariant_in_kernel(Ac, Mc, tol_m)
    Vo = _null(N.T, 0.5) if N.shape[1] else np.eye(Ac.shape[0])
    return np.asarray(Vo.T @ Ac @ Vo)


def distinct_modes(lams: ArrayLike) -> list[complex]:
    """The distinct eigenvalues among ``lams`` (clusters closer than ``_CLUSTER_RTOL`` merged, e.g. a Jordan block's
    round-off split), real when the imaginary part is round-off, largest modulus first (then the upper half first)."""
    arr = np.asarray(lams, dtype=complex).ravel()
    out = []
    for cl in _cluster(arr):
        lam = complex(np.mean(arr[cl]))
        if abs(lam.imag) <= _CLUSTER_RTOL * max(1.0, abs(lam)):
            lam = complex(lam.real, 0.0)
        out.append(lam)
    return sorted(out, key=lambda z: (-round(abs(z), 9), -z.imag))


def _not_power_bounded(Ao: np.ndarray) -> list[complex]:
    """Eigenvalues of ``Ao`` (all of modulus >= 1) that make A_o^t unbounded: modulus > 1, or on the unit circle in a Jordan block."""
    if Ao.shape[0] == 0:
        return []
    lams = np.linalg.eigvals(Ao)
    out: list[complex] = []
    scale = max(1.0, float(np.linalg.norm(Ao)))
    for cl in _cluster(lams):
        lam = complex(np.mean(lams[cl]))
        if abs(lam) > 1.0 + _CLUSTER_RTOL:
            out.append(lam)
            continue
        if abs(lam) < 1.0 - _CLUSTER_RTOL:
            continue
        # unit modulus: bounded iff semisimple (geometric multiplicity = the cluster's size)
        s = np.linalg.svd(Ao - lam * np.eye(Ao.shape[0]), compute_uv=False)
        if int(np.sum(s <= _CLUSTER_RTOL * scale)) < len(cl):
            out.append(lam)
    return distinct_modes(out)


def conditional_factor(F: ArrayLike, Vr: ArrayLike, Vp: ArrayLike, tol: float) -> FloatArray:
    r"""Factor B with B B' = Cov(V_+' u | V_r' u) for u = F e, e ~ N(0, I): ``V_+' F (I - P)``, P the projector on the rows of V_r' F."""
    F_, Vr_, Vp_ = np.asarray(F, float), np.asarray(Vr, float), np.asarray(Vp, float)
    Fr, Fp = Vr_.T @ F_, Vp_.T @ F_
    W = _orth(Fr.T, tol)
    return np.asarray(Fp - (Fp @ W) @ W.T)


def lyapunov_growth(
    A: ArrayLike, M: ArrayLike, B: ArrayLike, B0: ArrayLike, *, tol_b: float, tol_b0: float, tol_m: float
) -> tuple[list[complex], list[complex]]:
    r"""Whether M P_t M' is unbounded, P_{t+1} = A P_t A' + B B', P_0 = B0 B0', for A with every eigenvalue of modulus >= 1.

    Returns (modes driven by the noise B, modes driven by the initial B0): empty lists iff bounded.

    * Noise: M P_t M' >= sum_{s<t} (M A^s B)(M A^s B)', and a nonzero sequence M A^s B with every eigenvalue of modulus >= 1
      does not tend to 0 (on the minimal part, observability and reachability turn M A_o^s B_o -> 0 into
      A_o^s -> 0): the sum grows at least linearly iff the minimal part of (A, B, M) is not empty; its modes are
      returned.
    * Initial: M A^t B0 = M_o A_o^t B0_o on the minimal part of (A, B0, M) is bounded iff A_o^t is: every
      eigenvalue on the unit circle and semisimple. The modes of modulus > 1 or in a unit-modulus Jordan block
      are returned.
    """
    A_ = np.asarray(A, float)
    M_, B_, B0_ = np.asarray(M, float), np.asarray(B, float), np.asarray(B0, float)
    if A_.shape[0] == 0:
        return [], []
    Ao = _minimal_part(A_, M_, B_, tol_b, tol_m)
    noise = distinct_modes(np.linalg.eigvals(Ao)) if Ao.shape[0] else []
    initial = _not_power_bounded(_minimal_part(A_, M_, B0_, tol_b0, tol_m))
    return noise, initial
