r"""Transforms of a recorded log under a scenario's model: known means, innovations, the masked model.

Known means (:class:`KnownInputs`): the prior mean x̄_0, inputs B u(t) and process offsets b(t), measurement
offsets D_i u(t) + d_i(t); subtracting their propagated means leaves the zero-mean model the designs assume.
Innovations (:func:`innovations`) under the centralized filter, e(t) = y(t) - C ŷ(t|t-1) with covariance
S(t) = C P(t) Cᵀ + R, give the Gaussian log-likelihood
-1/2 Σ_t [eᵀ S⁻¹ e + log det(2π S)] over the components present. :func:`masked_system` is the model of a log
with gaps (:mod:`teamkf.study.measurements`, "Missing measurements, exactly").
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np
import scipy.linalg as sla

from ... import _validation as V
from ..._linalg import block_diag
from ..._validation import FloatArray
from ...models import LinearGaussianSystem
from .format import MeasurementFileError, MeasurementLog

__all__ = ["KnownInputs", "known_inputs", "Innovations", "innovations", "masked_system"]


@dataclass(frozen=True, eq=False)
class KnownInputs:
    r"""Known means that every agent knows: prior mean, inputs and offsets.

    .. math::

        x(0) \sim N(\bar x_0, \Sigma_x), \quad x(t+1) = A x(t) + B u(t) + b + w(t), \quad
        y_i(t) = C_i x(t) + D_i u(t) + d_i + v_i(t)

    Every family designed for the zero-mean model runs on the centred data
    y_i(t) - \bar y_i(t) and adds L_i(t) m(t), with the mean trajectory
    m(0) = \bar x_0, m(t+1) = A m(t) + B u(t) + b and \bar y_i(t) = C_i m(t) + D_i u(t) + d_i.
    For the centralized filter, MTMSE and MMSE this is the exact optimum of the
    affine problem (the errors x - m, y - \bar y are the zero-mean problem and
    the means are common knowledge); for every linear filter it is the filter
    run with the known inputs in its prediction step. Errors, and so every
    analytic and Monte Carlo cost, do not change.

    Attributes
    ----------
    x0_mean : (d_x,)
    B : (d_x, d_u) or None
    u : (d_u,) constant input, or None (then per-step inputs come with the measurements)
    b : (d_x,)
    D : tuple over agents of (d_y^i, d_u) or None
    d : tuple over agents of (d_y^i,)
    """

    x0_mean: FloatArray
    b: FloatArray
    d: tuple[FloatArray, ...]
    B: FloatArray | None = None
    u: FloatArray | None = None
    D: tuple[FloatArray, ...] | None = None

    def inputs(self, T: int, u_log: FloatArray | None) -> FloatArray | None:
        """u(0..T-1): from the log when it has them, else the constant u (None without inputs)."""
        if self.B is None and self.D is None:
            return None
        du = self.B.shape[1] if self.B is not None else self.D[0].shape[1]  # type: ignore[index]
        if u_log is not None:
            if u_log.shape[1] != du:
                raise MeasurementFileError(
                    f"u: the scenario's B/D take {du} inputs, the measurements give {u_log.shape[1]} (u0..u{u_log.shape[1] - 1})", argument="u"
                )
            if self.u is not None:
                raise MeasurementFileError("u: given both as system.u in the scenario and as u columns of the measurements; keep one", argument="u")
            return u_log[:T]
        if self.u is None:
            raise MeasurementFileError(
                f"u: the scenario has B/D but no inputs; give system.u (a constant) or u0..u{du - 1} columns in the measurements", argument="u"
            )
        return np.broadcast_to(self.u, (T, du))

    @classmethod
    def zero(cls, system: LinearGaussianSystem) -> "KnownInputs":
        """Zero prior mean and offsets, no inputs (a log's own offset columns then give the means)."""
        return cls(x0_mean=np.zeros(system.dx), b=np.zeros(system.dx), d=tuple(np.zeros(k) for k in system.dy))

    def offsets(self, T: int, b_log: FloatArray | None, d_log: Sequence[FloatArray] | None) -> tuple[FloatArray, list[FloatArray]]:
        """b(t) (T, d_x) and d_i(t) (T, d_y^i): from the log's offset columns, else the scenario's constants.

        The same offset given both ways is refused (which one is meant is not ours to guess).
        """
        if b_log is not None and np.any(self.b != 0):
            raise MeasurementFileError("b: given both as system.b in the scenario and as b columns of the measurements; keep one", argument="b")
        if d_log is not None and any(np.any(di != 0) for di in self.d):
            raise MeasurementFileError("d: given both as agents[i].d in the scenario and as d columns of the measurements; keep one", argument="d")
        b = b_log[:T] if b_log is not None else np.broadcast_to(self.b, (T, self.b.shape[0]))
        d = [di[:T] for di in d_log] if d_log is not None else [np.broadcast_to(di, (T, di.shape[0])) for di in self.d]
        return b, d

    def means(
        self,
        system: LinearGaussianSystem,
        T: int,
        u_log: FloatArray | None = None,
        b_log: FloatArray | None = None,
        d_log: Sequence[FloatArray] | None = None,
    ) -> tuple[FloatArray, list[FloatArray]]:
        """The mean trajectory m (T, d_x) and the measurement means ȳ_i (T, d_y^i).

        ``u_log``, ``b_log``, ``d_log``: the log's per-step inputs and time-varying offsets
        (:attr:`MeasurementLog.u`, ``.b``, ``.d``), used instead of the scenario's constants.
        """
        u = self.inputs(T, u_log)
        b, d = self.offsets(T, b_log, d_log)
        m = np.empty((T, system.dx))
        m[0] = self.x0_mean
        for t in range(T - 1):
            nxt = system.A_at(t) @ m[t] + b[t]
            if u is not None and self.B is not None:
                nxt = nxt + self.B @ u[t]
            m[t + 1] = nxt
        ybar = []
        for i in range(system.n_agents):
            yi = np.stack([system.C_at(i, t) @ m[t] for t in range(T)]) + d[i]
            if u is not None and self.D is not None:
                yi = yi + u @ self.D[i].T
            ybar.append(yi)
        return m, ybar


def known_inputs(scenario: Any) -> KnownInputs | None:
    """The known means of a scenario (``[system] x0_mean, B, u, b``; ``[[agents]] D, d``), validated, or None."""
    from ...exceptions import ScenarioError

    raw = scenario.raw or {}
    s = raw.get("system", {}) or {}
    agents = raw.get("agents", []) or []
    keys = ("x0_mean", "B", "u", "b")
    if not any(k in s for k in keys) and not any(isinstance(a, dict) and ("D" in a or "d" in a) for a in agents):
        return None
    sys_ = scenario.system
    dx, n = sys_.dx, sys_.n_agents

    def vec(x: Any, key: str, size: int) -> FloatArray:
        try:
            a = np.asarray(x, dtype=float)
        except (TypeError, ValueError):
            raise ScenarioError(f"{key}: expected a number or a list of {size} numbers, found {V.describe(x)}", argument=key) from None
        a = np.broadcast_to(a, (size,)).copy() if a.ndim == 0 else a
        if a.shape != (size,) or not np.all(np.isfinite(a)):
            raise ScenarioError(f"{key}: expected {size} finite numbers, found shape {a.shape}", argument=key)
        return a

    def mat(x: Any, key: str, rows: int, cols: int | None) -> FloatArray:
        try:
            a = np.asarray(x, dtype=float)
        except (TypeError, ValueError):
            raise ScenarioError(f"{key}: expected a matrix of numbers, found {V.describe(x)}", argument=key) from None
        if a.ndim != 2 or a.shape[0] != rows or (cols is not None and a.shape[1] != cols) or not np.all(np.isfinite(a)):
            want = f"{rows}x{cols}" if cols is not None else f"{rows}xd_u"
            raise ScenarioError(f"{key}: expected a finite {want} matrix, found shape {a.shape}", argument=key)
        return a

    x0 = vec(s.get("x0_mean", 0.0), "system.x0_mean", dx)
    b = vec(s.get("b", 0.0), "system.b", dx)
    B = mat(s["B"], "system.B", dx, None) if "B" in s else None
    du = B.shape[1] if B is not None else None
    Ds: list[FloatArray] | None = None
    if any("D" in a for a in agents):
        Ds = []
        for i, a in enumerate(agents):
            if "D" in a:
                Di = mat(a["D"], f"agents[{i}].D", sys_.dy[i], du)
                du = Di.shape[1] if du is None else du
            else:
                Di = None
            Ds.append(Di)  # type: ignore[arg-type]
        Ds = [Di if Di is not None else np.zeros((sys_.dy[i], du)) for i, Di in enumerate(Ds)]  # type: ignore[arg-type]
    u = vec(s["u"], "system.u", du) if "u" in s and du is not None else None
    if "u" in s and du is None:
        raise ScenarioError("system.u: inputs need system.B (or agents[i].D) to act on; add B or drop u", argument="system.u")
    d = tuple(vec(a.get("d", 0.0), f"agents[{i}].d", sys_.dy[i]) for i, a in enumerate(agents))
    if len(d) != n:
        d = tuple(np.zeros(k) for k in sys_.dy)
    return KnownInputs(x0_mean=x0, b=b, d=d, B=B, u=u, D=None if Ds is None else tuple(Ds))


@dataclass(frozen=True, eq=False)
class Innovations:
    r"""Innovations of the centralized Kalman filter on a log, and the log-likelihood of the data.

    e(t) = y(t) - C(t) x̂(t|t-1) - ȳ-terms over the components present at t,
    S(t) = C(t) P(t) C(t)' + R(t) (present rows), and

    .. math::

        \log p(y) = \sum_t -\tfrac12 \left[ m_t \log 2\pi + \log\det S(t) + e(t)' S(t)^{-1} e(t) \right]

    with m_t the number of components present at t (a step with none adds 0).

    Attributes
    ----------
    e : list over agents of (n_steps, d_y^i), NaN where missing
    loglik_steps : (n_steps,)
    """

    e: list[FloatArray]
    loglik_steps: FloatArray

    @property
    def loglik(self) -> float:
        """The sum over steps; ``-inf`` once a step's term overflows (a measurement the model makes impossible: p(y) = 0 in floats)."""
        ll = self.loglik_steps
        bad = ~np.isfinite(ll)
        if bad.any() and np.isneginf(ll[int(np.flatnonzero(bad)[0])]):
            return float("-inf")  # later steps inherit the overflowed state (NaN); the likelihood is already 0
        return float(np.sum(ll))


def innovations(system: LinearGaussianSystem, log: MeasurementLog, inputs: KnownInputs | None = None) -> Innovations:
    """Innovations and log-likelihood of ``log`` under the centralized filter (gaps: present rows only)."""
    T, n, dx = log.n_steps, system.n_agents, system.dx
    if inputs is not None:
        _, ybar = inputs.means(system, T, log.u, log.b, log.d)
        yc = [log.y[i] - ybar[i] for i in range(n)]
    else:
        yc = list(log.y)
    pres = log.present
    x, P = np.zeros(dx), np.array(system.Sigma_x, dtype=float)
    e = [np.full(y.shape, np.nan) for y in log.y]
    ll = np.zeros(T)
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):  # an overflow is reported as a non-finite log-likelihood
        _innovation_steps(system, yc, pres, x, P, e, ll)
    return Innovations(e, ll)


def _innovation_steps(system: LinearGaussianSystem, yc: list[Any], pres: Any, x: FloatArray, P: FloatArray, e: list[Any], ll: FloatArray) -> None:
    """The centralized filter's recursion of :func:`innovations` (fills ``e`` and ``ll`` in place)."""
    n, dx, T = system.n_agents, system.dx, ll.size
    for t in range(T):
        C = np.vstack([system.C_at(i, t)[pres[i][t]] for i in range(n)])
        blocks = [system.R_at(i, t)[np.ix_(pres[i][t], pres[i][t])] for i in range(n)]
        R = block_diag(*blocks)
        y = np.concatenate([yc[i][t][pres[i][t]] for i in range(n)])
        if y.size:
            S = C @ P @ C.T + R
            S = 0.5 * (S + S.T)
            r = y - C @ x
            cf = sla.cho_factor(S, lower=True, check_finite=False)
            K = sla.cho_solve(cf, C @ P, check_finite=False).T
            q = float(r @ sla.cho_solve(cf, r, check_finite=False))
            ll[t] = -np.inf if not np.isfinite(q) else -0.5 * (y.size * np.log(2 * np.pi) + 2 * np.sum(np.log(np.diag(cf[0]))) + q)
            pos = 0
            for i in range(n):
                k = int(pres[i][t].sum())
                e[i][t, pres[i][t]] = r[pos : pos + k]
                pos += k
            x = x + K @ r
            IKC = np.eye(dx) - K @ C
            P = IKC @ P @ IKC.T + K @ R @ K.T
        A = system.A_at(t)
        x = A @ x
        P = A @ P @ A.T + system.Q_at(t)


def masked_system(system: LinearGaussianSystem, present: Sequence[np.ndarray]) -> LinearGaussianSystem:
    r"""The time-varying model of a missingness pattern, with fixed dimensions.

    For every agent i and step t, with r the rows missing at t:

    .. math::

        C_i(t)[r, :] = 0, \quad R_i(t)[r, :] = R_i(t)[:, r] = 0, \quad R_i(t)[r, r] = I

    (the present rows keep C_i(t) and their block of R_i(t)). The missing rows
    become unit-variance noise independent of everything else, on which every
    optimal gain is exactly zero (module docstring): the estimates equal those
    of the model with the rows removed.

    Parameters
    ----------
    system : the model
    present : list over agents of boolean (n_steps, d_y^i) masks
    """
    T = int(present[0].shape[0])
    system.require_horizon(T)
    C, R = [], []
    for i, mask in enumerate(present):
        Ci, Ri = [], []
        for t in range(T):
            c = np.array(system.C_at(i, t), dtype=float)
            r = np.array(system.R_at(i, t), dtype=float)
            miss = ~mask[t]
            if miss.any():
                c[miss] = 0.0
                r[miss] = 0.0
                r[:, miss] = 0.0
                r[miss, miss] = 1.0
            Ci.append(c)
            Ri.append(r)
        C.append(Ci)
        R.append(Ri)
    A = system.A[0] if system.A.shape[0] == 1 else list(system.A)
    Q = system.Q[0] if system.Q.shape[0] == 1 else list(system.Q)
    return LinearGaussianSystem(A=A, Q=Q, Sigma_x=system.Sigma_x, C=C, R=R)
