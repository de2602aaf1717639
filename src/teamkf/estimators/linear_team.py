r"""One exact engine for every linear team filter with data-independent gains (the baselines).

Every baseline family (``local``, ``diffusion``, ``ci``, the delay-compensated
``kcf``) is linear in the data with gains that do not depend on the data. A
family describes **one step** of its algorithm once, as ordinary code on
"columns" (arrays whose first axis is the vector's dimension); this module

* runs that code **symbolically** (every quantity is the coefficient matrix of
  a linear expression over the previous step's stacked *slots* and the new
  measurements) to obtain the step as a linear map

  .. math:: \xi(k) = F(k)\, \xi(k-1) + K(k)\, y(k), \qquad z(k) = H(k)\, \xi(k),

  where ξ(k) stacks every agent's state and the payloads still in flight
  (the delayed copies an honest variant needs);
* derives from it, exactly, the **error recursion**. Every slot has a
  target T x(s) (an estimate of x(s): T = I; a buffered raw measurement
  y_j(s): T = C_j(s)), so ε(k) = Π_k X - ξ(k) obeys

  .. math:: \varepsilon(k) = F(k)\,\varepsilon(k-1) - K(k)\, v(k) + \sum_{r=b}^{k-1} B_r(k)\, w(r),

  with x(0) counted as the noise w(-1) (covariance Σ_x). The coefficient of
  x(b), Z = Π_k Φ - F Π_{k-1} Φ - K C(k) Φ(k, b), vanishes for an unbiased
  filter; it is computed and checked (a family whose description is biased is
  a bug and raises), then dropped, so nothing of the size of x ever enters
  the errors (cancellation-free on unstable processes);
* propagates the joint covariance of (ε(k), buffered w) exactly: the stage
  cost is E[c] = tr(S H P_ε(k) Hᵀ) since e = L x - z = H ε;
* applies the same (F, K, B) to sampled noises (:meth:`errors`) and to given
  measurements (:meth:`_filter`): one description, three uses.

The honest variants' message-passing agents (:meth:`graph_agents`) run the same
per-agent step code numerically on what :func:`~teamkf.estimators.base.pass_messages`
delivers, so the information discipline is that of the runtime.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Sequence

import numpy as np

from .._blas import single_thread_blas
from .._lazy import scipy_linalg as sla  # SciPy / networkx load on first use
from .._linalg import block_diag, inv
from .._validation import FloatArray
from ..exceptions import DivergenceError, ShapeError, TeamkfError, UnsupportedOperationError
from ..models import LinearGaussianSystem, TeamCost
from ..network.graph import CommGraph
from ._columns import _Column, _eye
from ._kalman_common import kalman_step
from .base import Design, check_paths

__all__ = ["Slot", "LinearStep", "LinearTeamDesign", "Algorithm", "build_steps", "transition", "process_noise"]


def _memo(system: LinearGaussianSystem, table: str, k_to: int, k_from: int, compute: Callable[[], FloatArray]) -> FloatArray:
    """``compute()``, stored on ``system`` (read-only) under the lag k_to - k_from (time-invariant) or (k_to, k_from).

    The designs ask for the same Φ(k, s) and Q(k, s) tens of thousands of times (once per agent,
    neighbour and step); the value is bit for bit the one ``compute`` returns.
    """
    cache = system.__dict__.setdefault(table, {})
    key = (k_to - k_from,) if not system.is_time_varying else (k_to, k_from)
    out = cache.get(key)
    if out is None:
        out = np.asarray(compute(), dtype=float)
        out.setflags(write=False)
        cache[key] = out
    return out  # type: ignore[no-any-return]


def shared_schedules(alg: "Algorithm", table: str, compute: Callable[[], Any]) -> Any:
    """``compute()``, stored on ``alg.system`` under ``table`` and the algorithm's horizon and sources ``alg.src``.

    A family's nominal covariances depend on the model, T and which data each agent fuses, not on its
    tuning parameters (a combination rule, ε), so the designs of one tuning grid share them; the last
    four source patterns of each table are kept.
    """
    key = (alg.horizon, tuple(tuple(tuple(step) for step in row) for row in alg.src))  # type: ignore[attr-defined]
    cache: dict[Any, Any] = alg.system.__dict__.setdefault(table, {})
    if key not in cache:
        if len(cache) >= 4:
            cache.pop(next(iter(cache)))
        cache[key] = compute()
    return cache[key]


def transition(system: LinearGaussianSystem, k_to: int, k_from: int) -> FloatArray:
    """Φ(k_to, k_from) = A(k_to - 1) ... A(k_from) (memoized, read-only)."""
    return _memo(system, "_teamkf_phi", k_to, k_from, lambda: system.transition(k_to, k_from))


def process_noise(system: LinearGaussianSystem, k_to: int, k_from: int) -> FloatArray:
    """Q(k_to, k_from) = Σ_{r=k_from}^{k_to-1} Φ(k_to, r+1) Q(r) Φ(k_to, r+1)ᵀ (zero when equal; memoized, read-only)."""

    def compute() -> FloatArray:
        dx = system.dx
        Qm = np.zeros((dx, dx))
        for r in range(k_from, k_to):
            A = system.A_at(r)
            Qm = A @ Qm @ A.T + system.Q_at(r)
        return 0.5 * (Qm + Qm.T)

    return _memo(system, "_teamkf_qnoise", k_to, k_from, compute)


@dataclass(frozen=True)
class Slot:
    """One block of the stacked filter vector ξ(k).

    key : hashable name (``("state", i, "xhat")`` or ``("payload", l, s, "psi")``)
    kind : "x" (an estimate of x(step): target I) or "y" (agent ``agent``'s raw y(step): target C_agent(step))
    agent : owner (for "y": whose measurement)
    step : the step s of its target T x(s)
    dim : its dimension
    """

    key: tuple
    kind: str
    agent: int
    step: int
    dim: int


def _compact(M: FloatArray) -> Any:
    """A CSR copy of a mostly-zero matrix (selector and shift blocks dominate F), else the array itself.

    The CSR arrays are built from one scan of the nonzeros in row-major order (what
    ``scipy.sparse.csr_matrix(M)`` stores, without its COO detour and second scan).
    """
    if M.size <= 4096:
        return M
    flat = np.ascontiguousarray(M).reshape(-1)
    idx = np.flatnonzero(flat)
    if idx.size >= 0.2 * M.size:
        return M
    import scipy.sparse as sp

    rows, cols = np.divmod(idx, M.shape[1])
    indptr = np.zeros(M.shape[0] + 1, dtype=np.int64)
    np.cumsum(np.bincount(rows, minlength=M.shape[0]), out=indptr[1:])
    index_dtype = np.int32 if max(M.shape[1], idx.size) < 2**31 else np.int64
    return sp.csr_matrix((flat[idx], cols.astype(index_dtype), indptr.astype(index_dtype)), shape=M.shape)


@dataclass(frozen=True, eq=False)
class LinearStep:
    """Step k as a linear map: ξ(k) = F ξ(k-1) + K y(k); ε(k) = F ε(k-1) - K v(k) + Σ_r B[r] w(r); z = H ξ.

    ``Fs``, ``Ks``, ``Hs`` are the same matrices, stored sparse when they are mostly zero
    (``Fs @ X`` is then a sparse-dense product).
    """

    k: int
    slots: tuple[Slot, ...]
    F: FloatArray
    K: FloatArray
    H: FloatArray
    B: dict[int, FloatArray]

    def __post_init__(self) -> None:
        object.__setattr__(self, "Fs", _compact(self.F))
        object.__setattr__(self, "Ks", _compact(self.K))
        object.__setattr__(self, "Hs", _compact(self.H))


class Algorithm:
    """What a family writes: one step of its algorithm, on columns (symbolic or numeric).

    Subclasses set ``state_kinds`` and ``payload_kinds`` (name -> "x" or "y"),
    ``honest`` and ``output`` (the state entry that is x̂_i), and implement

    * ``agent_step(i, k, prev, y_i, inbox, zero) -> (state, payload)`` for an
      honest (message-passing) algorithm: ``prev`` is agent i's state dict after
      step k-1 (None at k = 0), ``y_i`` a column of agent i's y_i(k), ``inbox``
      a list of ``(l, s, payload)`` delivered by the graph at step k;
    * ``team_step(k, prev, ys, zero) -> list of state dicts`` for an ideal one
      (within-step exchanges; no graph agents).

    Only ``M @ q``, ``q + q``, ``q - q`` and scalars times q may be used on
    columns, so the same code runs on coefficient matrices and on data.
    """

    state_kinds: dict[str, str] = {"xhat": "x"}
    payload_kinds: dict[str, str] = {}
    honest: bool = True
    output: str = "xhat"
    #: families whose gains need the exact error covariance set ``exact_gains``; :func:`build_steps` then sets
    #: ``_errcov`` (an :class:`_ErrorCovariance` of the step being built) while it runs, None otherwise
    exact_gains: bool = False
    _errcov: Any = None

    def __init__(self, system: LinearGaussianSystem, cost: TeamCost, graph: Any, horizon: int):
        self.system, self.cost, self.graph, self.horizon = system, cost, graph, horizon

    def agent_step(
        self, i: int, k: int, prev: dict | None, y_i: Any, inbox: Sequence[tuple[int, int, dict]], zero: Callable[[int], Any]
    ) -> tuple[dict, dict]:
        raise NotImplementedError

    def team_step(self, k: int, prev: list[dict | None], ys: list[Any], zero: Callable[[int], Any]) -> list[dict]:
        """Default: agents in isolation (no communication)."""
        return [self.agent_step(i, k, prev[i], ys[i], [], zero)[0] for i in range(self.system.n_agents)]

    def dim(self, kind: str, agent: int) -> int:
        return self.system.dx if kind == "x" else self.system.dy[agent]

    # --- cached model quantities (time-invariant models: keyed by the lag only) --------------
    def _key(self, k: int, s: int) -> tuple[int, int]:
        return (k - s, 0) if not self.system.is_time_varying else (k, s)

    def Phi(self, k: int, s: int) -> FloatArray:
        """Φ(k, s), cached."""
        cache = self.__dict__.setdefault("_phi", {})
        key = self._key(k, s)
        if key not in cache:
            cache[key] = self.system.transition(k, s)
        return cache[key]  # type: ignore[no-any-return]

    def compensated(self, j: int, s: int, k: int) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        """(C̃, R̃, G̃ = C̃ᵀR̃⁻¹, Y = G̃ C̃) of y_j(s) as a measurement of x(k), cached."""
        cache = self.__dict__.setdefault("_comp", {})
        key = (j, *self._key(k, s))
        if key not in cache:
            Ct, Rt = compensated_measurement(self.system, j, s, k)
            if not (np.all(np.isfinite(Ct)) and np.all(np.isfinite(Rt))):
                raise DivergenceError(
                    f"y_{j}({s}) propagated to step {k} for delay compensation overflows: the process leaves the floating-point "
                    "range, so this delay-compensated filter diverges on this system (shorten the horizon or use an undelayed variant)",
                    argument="system",
                )
            G = sla.cho_solve(sla.cho_factor(Rt, lower=True), Ct).T
            cache[key] = (Ct, Rt, G, G @ Ct)
        return cache[key]  # type: ignore[no-any-return]

    def fuse_delivered(self, i: int, k: int, xbar: Any, P: FloatArray, y_i: Any, packets: Sequence[tuple[int, int, Any]]) -> tuple[Any, FloatArray]:
        """Information-form update of agent i's prior (x̄, P) with y_i(k) and every delivered y_l(s).

        Each y_l(s) of ``packets`` (payload key ``"y"``) is a measurement of x(k), delay-compensated
        (:meth:`compensated`). Returns r = Σ (G̃ y - Y x̄) over {y_i(k)} ∪ packets, in that order, and
        P⁺ = (P⁻¹ + S)⁻¹ (Joseph form, as the designs): the update is x̄ + P⁺ r, before any consensus term.
        """
        ys = [((i, k), y_i), *[((lnode, s), p["y"]) for (lnode, s, p) in packets]]
        r: Any = None
        for (lnode, s), y in ys:
            _, _, G, Y = self.compensated(lnode, s, k)
            term = G @ y - Y @ xbar
            r = term if r is None else r + term
        # the stacked C̃ and block-diagonal R̃ of these packets (cached: they depend on which packets, not on the run)
        cache = self.__dict__.setdefault("_stacked", {})
        key = (k, tuple(ls for ls, _ in ys)) if self.system.is_time_varying else tuple((ls[0], k - ls[1]) for ls, _ in ys)
        CR = cache.get(key)
        if CR is None:
            comp = [self.compensated(lnode, s, k) for (lnode, s), _ in ys]
            CR = np.vstack([c[0] for c in comp]), block_diag(*[c[1] for c in comp])
            if len(cache) < 4096:
                cache[key] = CR
        _, P_post = kalman_step(P, CR[0], CR[1])
        return r, P_post


def _target(system: LinearGaussianSystem, slot: Slot) -> FloatArray:
    return transition(system, 0, 0) if slot.kind == "x" else system.C_at(slot.agent, slot.step)  # Φ(0, 0) = I, memoized


class _TargetRows:
    """The stacked targets T_a x(s_a) of a tuple of slots, and their coefficients of w(r).

    Row block a of :meth:`rows` ``(r)`` is T_a Φ(s_a, r + 1) when r <= s_a - 1, else 0 (w(r) enters
    x(s_a) only for r < s_a). The slots' steps take a few values (the payloads in flight), so the
    rows are a few products, one per step, instead of one per slot.
    """

    def __init__(self, alg: "Algorithm", slots: Sequence[Slot]):
        sysm = alg.system
        self.alg, self.dim = alg, sum(s.dim for s in slots)
        self.T = np.vstack([_target(sysm, s) for s in slots]) if slots else np.zeros((0, sysm.dx))
        steps = np.repeat(np.asarray([s.step for s in slots], dtype=int), [s.dim for s in slots])
        self.groups = [(int(st), np.flatnonzero(steps == st)) for st in np.unique(steps)]
        self._rows: dict[int, FloatArray] = {}

    def rows(self, r: int) -> FloatArray:
        """Coefficient of w(r) in the stacked targets (cached: each r is asked for at two consecutive steps)."""
        out = self._rows.get(r)
        if out is None:
            out = np.zeros((self.dim, self.T.shape[1]))
            for st, idx in self.groups:
                if r <= st - 1:
                    out[idx] = self.T[idx] @ self.alg.Phi(st, r + 1)
            self._rows[r] = out
        return out


def _target_rows(alg: "Algorithm", slots: tuple[Slot, ...]) -> _TargetRows:
    """The :class:`_TargetRows` of ``slots``, kept for the last few slot tuples (step k's new slots are step k+1's previous ones)."""
    cache: dict[int, tuple[tuple[Slot, ...], _TargetRows]] = alg.__dict__.setdefault("_target_rows", {})
    hit = cache.get(id(slots))
    if hit is not None and hit[0] is slots:
        return hit[1]
    if len(cache) >= 3:
        cache.pop(next(iter(cache)))
    tr = _TargetRows(alg, slots)
    cache[id(slots)] = (slots, tr)
    return tr


def build_steps(alg: Algorithm) -> list[LinearStep]:
    """Run ``alg`` symbolically over its horizon: the linear description of every step (with the error terms)."""
    return _build(alg)[0]


def _stage_cost(cost: TeamCost, st: LinearStep, P: FloatArray) -> tuple[FloatArray, float]:
    """The outputs' error covariance E = H P_ε Hᵀ at step k and the stage cost tr(S E)."""
    HP = np.asarray(st.Hs @ P)  # type: ignore[attr-defined]
    E = np.asarray(st.Hs @ HP.T).T  # type: ignore[attr-defined]
    return E, float(np.sum(cost.S_at(st.k) * E))


def _build(alg: Algorithm) -> tuple[list[LinearStep], FloatArray | None]:
    """:func:`build_steps`, and the exact stage costs when the family's gains already ran the error recursion."""
    sysm, cost, T = alg.system, alg.cost, alg.horizon
    n, dx, dys = sysm.n_agents, sysm.dx, sysm.dy
    offs = np.concatenate([[0], np.cumsum(dys)]).astype(int)
    dyt = int(offs[-1])
    graph = alg.graph
    ins = (
        [[(j, graph.delay(j, i)) for j in graph.in_neighbors(i)] for i in range(n)] if (graph is not None and alg.honest) else [[] for _ in range(n)]
    )
    max_out = [0] * n
    for i in range(n):
        for j, d in ins[i]:
            max_out[j] = max(max_out[j], d)
    prev_slots: tuple[Slot, ...] = ()
    steps: list[LinearStep] = []
    exact = bool(getattr(alg, "exact_gains", False))
    Pk: FloatArray = np.zeros((0, 0))
    Xk: dict[int, FloatArray] = {}
    stage: list[float] = []
    for k in range(T):
        starts = np.concatenate([[0], np.cumsum([s.dim for s in prev_slots])]).astype(int)
        nprev = int(starts[-1])
        nb = nprev + dyt
        index = {s.key: (int(starts[a]), s) for a, s in enumerate(prev_slots)}

        def sel(pos: int, d: int, nb: int = nb) -> _Column:
            return _Column({pos: _eye(d)}, d, nb)  # [0 | I_d | 0], the identity block at column pos

        def zero(d: int, nb: int = nb) -> _Column:
            return _Column({}, d, nb)

        def get(key: tuple, index: dict = index) -> _Column:
            pos, s = index[key]
            return sel(pos, s.dim)

        ys = [sel(nprev + int(offs[i]), dys[i]) for i in range(n)]
        if exact:  # the exact error covariance of any expression of this step (families with exact gains)
            alg._errcov = _ErrorCovariance(alg, k, prev_slots, nprev, Pk, Xk)
        prev_states: list[dict | None] = [None if k == 0 else {name: get(("state", i, name)) for name in alg.state_kinds} for i in range(n)]
        new_slots: list[Slot] = []
        rows: list[Any] = []  # symbolic columns (_Column) or dense rows
        if alg.honest:
            payloads = []
            for i in range(n):
                inbox = []
                for j, d in ins[i]:
                    s = k - d
                    if s >= 0:
                        inbox.append((j, s, {name: get(("payload", j, s, name)) for name in alg.payload_kinds}))
                st, pl = alg.agent_step(i, k, prev_states[i], ys[i], inbox, zero)
                for name, kind in alg.state_kinds.items():
                    new_slots.append(Slot(("state", i, name), kind, i, k, alg.dim(kind, i)))
                    rows.append(st[name])
                payloads.append(pl)
            for j in range(n):  # payloads in flight: sent at s, needed up to s + max out-delay
                for s in range(max(0, k - max_out[j] + 1), k + 1):  # from 0: a delay beyond the horizon costs nothing
                    for name, kind in alg.payload_kinds.items():
                        new_slots.append(Slot(("payload", j, s, name), kind, j, s, alg.dim(kind, j)))
                        rows.append(payloads[j][name] if s == k else get(("payload", j, s, name)))
        else:
            states = alg.team_step(k, prev_states, ys, zero)
            for i in range(n):
                for name, kind in alg.state_kinds.items():
                    new_slots.append(Slot(("state", i, name), kind, i, k, alg.dim(kind, i)))
                    rows.append(states[i][name])
        coef = np.zeros((sum(np.shape(q)[0] for q in rows), nb))
        at = 0
        for q in rows:
            if isinstance(q, _Column):
                q.place(coef, at)
            else:
                coef[at : at + q.shape[0]] = q
            at += np.shape(q)[0]
        F, K = coef[:, :nprev], coef[:, nprev:]
        slots = tuple(new_slots)
        nstarts = np.concatenate([[0], np.cumsum([s.dim for s in slots])]).astype(int)
        pos_new = {s.key: int(nstarts[a]) for a, s in enumerate(slots)}
        H = np.zeros((n * cost.dz, int(nstarts[-1])))
        for i in range(n):
            p = pos_new[("state", i, alg.output)]
            H[i * cost.dz : (i + 1) * cost.dz, p : p + dx] = cost.L_block(i, k)
        B = _noise_terms(alg, k, prev_slots, slots, F, K)
        steps.append(LinearStep(k=k, slots=slots, F=F, K=K, H=H, B=B))
        if exact:
            Pk, Xk = _advance(sysm, steps[-1], Pk, Xk)
            with np.errstate(over="ignore", invalid="ignore"):  # as analytic(): a diverging design's cost is inf/nan
                stage.append(_stage_cost(cost, steps[-1], Pk)[1])
        prev_slots = slots
    if exact:
        alg._errcov = None
    return steps, (np.asarray(stage) if exact else None)


def _advance(system: LinearGaussianSystem, st: LinearStep, P: FloatArray, X: dict[int, FloatArray]) -> tuple[FloatArray, dict[int, FloatArray]]:
    """One step of the exact error recursion: (Cov ε(k-1), Cov(ε(k-1), w(r))) -> the same at k.

    With ε(k) = F ε(k-1) - K v(k) + Σ_r B_r w(r) and X_r = Cov(ε(k-1), w(r)) for the buffered r:

        Cov ε(k) = F P Fᵀ + K R Kᵀ + Σ_r (B_r Q_r B_rᵀ + F X_r B_rᵀ + B_r X_rᵀ Fᵀ),   X_r(k) = F X_r + B_r Q_r.

    The rank-d_x terms are one product U Vᵀ (U = [½ B_r Q_r + F X_r], V = [B_r]); the symmetrization
    0.5 (M + Mᵀ) of M = F P Fᵀ + K R Kᵀ + 2 U Vᵀ adds U Vᵀ + V Uᵀ.
    """
    F, K = st.Fs, st.Ks  # type: ignore[attr-defined]
    FP = np.asarray(F @ P)
    Pn = np.asarray(F @ FP.T)  # F P Fᵀ (P symmetric)
    if K.shape[1]:
        KR = np.asarray(K @ system.R_stack(st.k))
        Pn = Pn + np.asarray(K @ KR.T)
    U, V = [], []
    Xn: dict[int, FloatArray] = {}
    for r, Bm in st.B.items():
        BQ = Bm @ (system.Sigma_x if r == -1 else system.Q_at(r))
        if r in X:
            FX = np.asarray(F @ X[r])
            U.append(0.5 * BQ + FX)
            Xn[r] = FX + BQ
        else:
            U.append(0.5 * BQ)
            Xn[r] = BQ
        V.append(Bm)
    if U:
        Pn = Pn + 2.0 * (np.hstack(U) @ np.hstack(V).T)
    return 0.5 * (Pn + Pn.T), Xn


class _ErrorCovariance:
    """The exact joint covariance of the errors M x(k) - q of expressions q of step k (symbolic columns).

    An expression q = [F_q | K_q] over (ξ(k-1), y(k)) with target M x(k) has the error
    e = F_q ε(k-1) - K_q v(k) + Σ_r B_r w(r) (w(-1) = x(0)), B_r as in :func:`_noise_terms`; the
    covariance follows from Cov ε(k-1) and Cov(ε(k-1), w(r)) of the recursion (:func:`_advance`).
    """

    def __init__(self, alg: Algorithm, k: int, prev: Sequence[Slot], nprev: int, P: FloatArray, X: dict[int, FloatArray]):
        self.alg, self.k, self.prev, self.nprev, self.P, self.X = alg, k, prev, nprev, P, X
        sysm = alg.system
        b = min([s.step for s in prev] + [k])
        self.lo = -1 if b == 0 else b
        self.C = sysm.C_stack(k)
        self.R = sysm.R_stack(k)

    def _target_rows(self, r: int) -> FloatArray:
        return _target_rows(self.alg, tuple(self.prev)).rows(r)

    def __call__(self, items: Sequence[tuple[FloatArray, FloatArray]]) -> FloatArray:
        """Cov of the stacked errors M_a x(k) - q_a for ``items`` = [(q_a, M_a)]."""
        sysm, k = self.alg.system, self.k
        q = np.vstack([np.asarray(a, dtype=float) for a, _ in items])
        M = np.vstack([m for _, m in items])
        Fq, Kq = q[:, : self.nprev], q[:, self.nprev :]
        # the expressions read a few slots of ξ(k-1): only those rows and columns of Cov ε(k-1) enter
        cols = np.flatnonzero(np.any(Fq != 0.0, axis=0))
        Fq = Fq[:, cols]
        S = Fq @ self.P[np.ix_(cols, cols)] @ Fq.T + Kq @ self.R @ Kq.T
        for r in range(self.lo, k):
            Bq = M @ self.alg.Phi(k, r + 1) - Fq @ self._target_rows(r)[cols] - Kq @ (self.C @ self.alg.Phi(k, r + 1))
            Qr = sysm.Sigma_x if r == -1 else sysm.Q_at(r)
            S = S + Bq @ Qr @ Bq.T
            if r in self.X:
                c = Fq @ self.X[r][cols] @ Bq.T
                S = S + c + c.T
        return 0.5 * (S + S.T)


def _noise_terms(alg: Algorithm, k: int, prev: Sequence[Slot], new: Sequence[Slot], F: FloatArray, K: FloatArray) -> dict[int, FloatArray]:
    """Coefficients B[r] of w(r) in ε(k) (w(-1) = x(0)), after checking that x(b) drops out."""
    sysm = alg.system
    b = min([s.step for s in prev] + [s.step for s in new] + [k])
    C = sysm.C_stack(k)
    tnew, tprev = _target_rows(alg, tuple(new)), _target_rows(alg, tuple(prev))  # coefficient of w(r) in the targets T x(s)

    B: dict[int, FloatArray] = {}
    lo = -1 if b == 0 else b
    for r in range(lo, k):
        Bm = tnew.rows(r) - F @ tprev.rows(r)
        if r <= k - 1:
            Bm = Bm - K @ (C @ alg.Phi(k, r + 1))
        B[r] = Bm
    if b > 0:  # the coefficient of x(b) must vanish (an unbiased description): T Φ(s, b) = the rows of w(b - 1), as s >= b
        Zn, Zp, Zy = tnew.rows(b - 1), F @ tprev.rows(b - 1), K @ (C @ alg.Phi(k, b))
        Z = Zn - Zp - Zy
        scale = np.abs(Zn).max(initial=0) + np.abs(Zp).max(initial=0) + np.abs(Zy).max(initial=0) + 1e-300
        if np.abs(Z).max(initial=0) > 1e-8 * scale:
            raise TeamkfError(
                f"step {k}: the linear description is biased (the coefficient of x({b}) in the error is "
                f"{np.abs(Z).max():.3g}, relative {np.abs(Z).max() / scale:.3g}); the family's step is not an estimator of its targets"
            )
    return B


@dataclass(frozen=True, eq=False, kw_only=True)
class LinearTeamDesign(Design):
    """A design whose every step is a linear map with data-independent gains (see the module docstring).

    The baselines (``local``, ``diffusion``, ``ci``, ``icf``, ``hcmci``) and KCF's "honest" and
    "ideal" variants return one. Their estimates are linear in the primitive noises with gains that
    do not depend on the data, so the team cost is exact: the error covariance is propagated
    step by step.

    Parameters
    ----------
    estimator, horizon, system, cost, stage_costs, average_cost, info
        As in :class:`~teamkf.Design`: the family name, T (None for the steady state), the
        model, the team cost, the exact E[c(x(k), ẑ(k))] per step and the plain-data facts.
    graph : CommGraph or None
        The communication graph the agents exchange over (None for silent agents).
    variant : str
        "honest" (realizable over the graph's delays) or "ideal" (a bound).
    steps : tuple of LinearStep
        The per-step linear maps of every agent's state and estimate.
    algorithm : Algorithm
        The algorithm that produced them; its per-agent step runs the graph agents.

    See Also
    --------
    design_local, design_diffusion, design_ci, design_icf, design_hcmci, design_kcf

    Examples
    --------
    >>> from teamkf import LinearGaussianSystem, TeamCost, CommGraph, design_diffusion
    >>> d = design_diffusion(LinearGaussianSystem.platoon(4), TeamCost.platoon(4, 10.0), CommGraph.line(4), 10)
    >>> type(d).__name__, d.variant, len(d.steps)
    ('LinearTeamDesign', 'honest', 10)
    """

    graph: Any = None
    variant: str = "honest"
    steps: tuple[LinearStep, ...] = ()
    algorithm: Any = None

    # --- analytic cost -----------------------------------------------------------------------
    @staticmethod
    def analytic(system: LinearGaussianSystem, cost: TeamCost, steps: Sequence[LinearStep]) -> tuple[FloatArray, list[FloatArray]]:
        """Exact stage costs E[c(x(k), ẑ(k))] = tr(S H P_ε Hᵀ) and the error covariances of the outputs H P_ε Hᵀ."""
        P = np.zeros((0, 0))
        X: dict[int, FloatArray] = {}  # Cov(ε(k), w(r)) for buffered r
        out, covs = [], []
        for st in steps:
            P, X = _advance(system, st, P, X)
            E, c = _stage_cost(cost, st, P)
            covs.append(E)
            out.append(c)
        return np.asarray(out), covs

    # --- Monte Carlo ------------------------------------------------------------------------
    def errors(self, paths: Any) -> FloatArray:
        """e(k) = L x(k) - ẑ(k) = H ε(k), (n_runs, T', n d_z), from the primitive noises x(0), w, v."""
        check_paths(paths, self.system)
        with single_thread_blas():
            return self._errors(paths)

    def _errors(self, paths: Any) -> FloatArray:
        x0 = np.asarray(paths.x, dtype=float)[:, 0]
        w = np.asarray(paths.w, dtype=float)
        v = np.concatenate([np.asarray(vi, dtype=float) for vi in paths.v], axis=2)
        n_runs, T = v.shape[:2]
        if T > len(self.steps):
            raise ShapeError(f"paths: expected at most horizon = {len(self.steps)} steps, found {T}")
        eps = np.zeros((n_runs, 0))
        out = np.empty((n_runs, T, self.n_agents * self.cost.dz))
        for k in range(T):
            st = self.steps[k]
            e = np.asarray(st.Fs @ eps.T).T - np.asarray(st.Ks @ v[:, k].T).T  # type: ignore[attr-defined]
            for r, Bm in st.B.items():
                e = e + (x0 if r == -1 else w[:, r]) @ Bm.T
            eps = e
            out[:, k] = np.asarray(st.Hs @ eps.T).T  # type: ignore[attr-defined]
        return out

    def _filter(self, ys: list[FloatArray]) -> FloatArray:
        with single_thread_blas():
            return self._run_filter(ys)

    def _run_filter(self, ys: list[FloatArray]) -> FloatArray:
        y = np.concatenate(ys, axis=2)
        n_runs, T = y.shape[:2]
        xi = np.zeros((n_runs, 0))
        out = np.empty((n_runs, T, self.n_agents * self.cost.dz))
        for k in range(T):
            st = self.steps[k]
            xi = np.asarray(st.Fs @ xi.T).T + np.asarray(st.Ks @ y[:, k].T).T  # type: ignore[attr-defined]
            out[:, k] = np.asarray(st.Hs @ xi.T).T  # type: ignore[attr-defined]
        return out

    # --- online agents ---------------------------------------------------------------------------
    def graph_agents(self) -> list[Any]:
        """One message-passing agent per node running the family's own step code (honest variants)."""
        if not getattr(self.algorithm, "honest", False):
            raise self._unsupported(
                f"graph_agents() for the {self.variant!r} variant",
                "it exchanges neighbours' current data within the step, which no delay graph can deliver; use design.filter(y) or variant='honest'",
            )
        return [LinearAgent(self, i) for i in range(self.n_agents)]

    @property
    def delivery_graph(self) -> Any:
        return self.graph

    def agent_slice(self, i: int) -> tuple[str, dict[str, np.ndarray], dict[str, Any]]:
        """Agent i's slice, from its algorithm's ``agent_slice`` (honest variants of families that have one)."""
        fn = getattr(self.algorithm, "agent_slice", None)
        if fn is None or not getattr(self.algorithm, "honest", False):
            return super().agent_slice(i)
        kind, arrays, meta = fn(i)
        return kind, arrays, {"variant": self.variant, **meta}

    @property
    def tolerates_losses(self) -> bool:
        """True when the agents run with lost or late packets (the family defines what a missing message means)."""
        # exact gains are designed for the graph's messages: no rule for a lost one (diffusion gains="exact")
        return hasattr(self.algorithm, "agent_step_tolerant") and not getattr(self.algorithm, "exact_gains", False)

    def details(self) -> dict[str, Any]:
        return {"variant": self.variant, "realizable": bool(getattr(self.algorithm, "honest", False)), "state_dim": int(self.steps[-1].F.shape[0])}

    def arrays(self) -> dict[str, np.ndarray]:
        return {**super().arrays(), **{k: np.asarray(v) for k, v in getattr(self.algorithm, "schedules", {}).items()}}


def _in_positions(graph: CommGraph, i: int) -> dict[int, int]:
    """{in-neighbour j: its position in ``graph.in_neighbors(i)``}, cached on the (immutable) graph."""
    cache: dict[int, dict[int, int]] = graph.__dict__.setdefault("_in_positions", {})
    pos = cache.get(i)
    if pos is None:
        pos = cache[i] = {j: a for a, j in enumerate(graph.in_neighbors(i))}
    return pos


def delivered(graph: CommGraph | None, i: int, inbox: Sequence[tuple[int, int, Any]]) -> list[tuple[int, int, Any]]:
    """The packets of agent i's inbox in the nominal order: in-neighbour order (as the graph lists them), then sent step.

    On unreliable links an inbox may hold several packets of one sender (a late
    one with the current one) or none; the nominal runtime's inbox is already in
    this order, so sorting keeps the arithmetic of the reliable case. A repeated
    (sender, step) is kept once; a packet from an agent that is not an
    in-neighbour is not used.
    """
    if graph is None or not inbox:
        return []
    pos = _in_positions(graph, i)
    seen: set[tuple[int, int]] = set()
    out = []
    for l, s, p in sorted(((l, s, p) for (l, s, p) in inbox if l in pos), key=lambda e: (pos[e[0]], e[1])):
        if (l, s) not in seen:
            seen.add((l, s))
            out.append((l, s, p))
    return out


def freshest(packets: Sequence[tuple[int, int, Any]]) -> list[tuple[int, int, Any]]:
    """One packet per sender, the most recently sent one, in the order of ``packets`` (see :func:`delivered`)."""
    best: dict[int, tuple[int, int, Any]] = {}
    for l, s, p in packets:
        if l not in best or s > best[l][1]:
            best[l] = (l, s, p)
    order = list(dict.fromkeys(l for l, _, _ in packets))
    return [best[l] for l in order]


class LinearAgent:
    """Agent i of an honest linear family on the message-passing runtime (the family's step code on data)."""

    def __init__(self, design: LinearTeamDesign, index: int):
        self.design, self.index = design, index
        #: set by the lossy runtime: messages may be missing or late (only families with a tolerant step support it)
        self.tolerant = False

    def init_state(self, n_runs: int) -> dict[str, Any]:
        return {"n_runs": n_runs, "state": None}

    @property
    def restart_state(self) -> Any:
        """``(n_runs, k) -> state`` of a fresh agent at step k from the design's prior (a restarted process), or None
        when the family defines no restart (its algorithm's ``agent_restart(i, k, zero)``); only its tolerant step uses it."""
        make = getattr(self.design.algorithm, "agent_restart", None)
        if make is None:
            return None

        def restart(n_runs: int, k: int) -> dict[str, Any]:
            st = None if k == 0 else make(self.index, k, lambda dim: np.zeros((dim, n_runs)))
            return {"n_runs": n_runs, "state": st}

        return restart

    def step(self, state: dict[str, Any], k: int, own: Any, inbox: Sequence[Any]) -> tuple[dict[str, Any], FloatArray, Any]:
        d, i = self.design, self.index
        if k >= len(d.steps):
            raise ShapeError(f"k: the design has horizon = {len(d.steps)} steps, found step {k}; design a longer horizon")
        n_runs = state["n_runs"]
        y_col = np.asarray(own, dtype=float).T
        box = [(j, s, p) for (j, s, p) in inbox]

        def zero(dim: int) -> FloatArray:
            return np.zeros((dim, n_runs))

        if self.tolerant:
            step = getattr(d.algorithm, "agent_step_tolerant", None)
            if step is None:
                raise UnsupportedOperationError(
                    d.estimator,
                    "lost or late packets (unreliable links)",
                    "its agents need every message of the design; run it on reliable links (p_drop = 0, jitter = 0)",
                )
            st, pl = step(i, k, state["state"], y_col, box, zero)
        else:
            st, pl = d.algorithm.agent_step(i, k, state["state"], y_col, box, zero)
        z = (d.cost.L_block(i, k) @ st[d.algorithm.output]).T
        return {"n_runs": n_runs, "state": st}, z, pl


def finish_design(estimator: str, alg: Algorithm, variant: str, info: dict[str, Any] | None = None) -> LinearTeamDesign:
    """Build the steps of ``alg``, their exact cost, and the design object."""
    with single_thread_blas():  # many medium GEMMs: one BLAS thread is robust on a shared machine
        steps, stage = _build(alg)  # exact gains: the recursion they ran gives the cost
        if stage is None:
            with np.errstate(over="ignore", invalid="ignore"):
                stage, _ = LinearTeamDesign.analytic(alg.system, alg.cost, steps)
    # realizable exactly when the agents run one exchange per step over the graph (the honest step); an ideal
    # variant exchanges inside the step, which no delay graph delivers (Design.realizable reads this)
    inf = {"variant": variant, "cost_method": "analytic", "realizable": bool(alg.honest), **(info or {})}
    return LinearTeamDesign(
        estimator=estimator,
        horizon=alg.horizon,
        system=alg.system,
        cost=alg.cost,
        stage_costs=stage,
        info=inf,
        graph=alg.graph,
        variant=variant,
        steps=tuple(steps),
        algorithm=alg,
    )


def compensated_measurement(system: LinearGaussianSystem, j: int, s: int, k: int) -> tuple[FloatArray, FloatArray]:
    r"""y_j(s) as a measurement of x(k) (delay compensation of an information pair).

    With x(k) = Φ x(s) + n, n ~ N(0, Q(k, s)) and Φ = Φ(k, s) invertible,
    y_j(s) = C̃ x(k) + ṽ with C̃ = C_j(s) Φ⁻¹ and R̃ = R_j(s) + C̃ Q(k, s) C̃ᵀ: the
    information pair (C̃ᵀR̃⁻¹C̃, C̃ᵀR̃⁻¹y_j(s)) is the pair of y_j(s) "through the
    prediction with process noise" (its likelihood of x(k) under a flat prior on
    x(s)). For s = k it is (C_j(k), R_j(k)).
    """
    C, R = system.C_at(j, s), system.R_at(j, s)
    if s == k:
        return C, R
    Phi = system.transition(k, s)
    try:
        Ct: FloatArray = np.asarray(np.linalg.solve(Phi.T, C.T).T, dtype=float)
    except np.linalg.LinAlgError as exc:
        from ..exceptions import ArgumentError

        raise ArgumentError(
            f"system.A: the delay compensation of y_{j}({s}) at step {k} needs an invertible Φ({k}, {s}), found a singular one; "
            "use the 'ideal' variant or a model with invertible A",
            argument="system.A",
        ) from exc
    Rt = np.asarray(R + Ct @ process_noise(system, k, s) @ Ct.T, dtype=float)
    Rt = 0.5 * (Rt + Rt.T)
    if np.all(np.isfinite(Rt)):
        try:
            np.linalg.cholesky(Rt)
        except np.linalg.LinAlgError:
            from ..exceptions import ArgumentError

            raise ArgumentError(
                f"system.A: the delay compensation of y_{j}({s}) at step {k} inverts Φ({k}, {s}), whose condition number is "
                f"{np.linalg.cond(Phi):.1e}: the compensated noise covariance R̃ = R + C̃ Q C̃ᵀ is not positive definite in floating "
                "point; use the 'ideal' variant, shorter delays, or a model whose A is well conditioned",
                argument="system.A",
            ) from None
    return Ct, Rt


def compensate_information(system: LinearGaussianSystem, Y: FloatArray, s: int, k: int) -> tuple[FloatArray, FloatArray]:
    r"""An information pair (Y, Y x̃) about x(s) through the prediction with process noise to step k.

    Returns (Y', T) with Y' = (Φ Y⁻¹ Φᵀ + Q(k, s))⁻¹ and T = Y' Φ, so that the
    compensated pair is (Y', T x̃) (x̃ = Y⁻¹ y the pair's estimate of x(s)).
    """
    if s == k:
        return Y, Y
    Phi = transition(system, k, s)
    P = Phi @ inv(Y) @ Phi.T + process_noise(system, k, s)
    Yn = inv(0.5 * (P + P.T))
    Yn = 0.5 * (Yn + Yn.T)
    return Yn, np.asarray(Yn @ Phi, dtype=float)
