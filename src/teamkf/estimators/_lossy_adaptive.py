r"""Pattern-adaptive features over re-sending relays (``mtmse_lossy`` with ``resend = r`` and ``adaptive = true``).

Why
---
Every other drop-aware class applies gains fixed offline to items, so an item gets the same weight whether its
neighbours in time arrived or not. The team that is told every drop re-weights *every* held item with the realized
pattern; on the platoon that is most of what separates the re-sending design from the known-pattern optimum
(``docs/lossy-design.md``). This class gives each agent a feature that re-weights with the pattern: its exact
conditional mean of the recent states given what it holds.

The class
---------
Agent i runs the re-sending design (:mod:`teamkf.estimators._lossy_resend`, same relays, same items) and, on the
same items (available once a packet carrying them arrived on time), a **fixed-lag Kalman smoother** over the last
D + 1 states, D = ℓ_max + r − 1 (an item (j, s) is available by s + ℓ_ji + r − 1 or never, so every one lands in
the window). Its features at step k are

.. math::  φ_i(k) = \big[\hat z^r_i(k);\ E[x(k - D : k) \mid H_i(k)];\ E[x(k) \mid H_i(k - l)],\ l = 1..ℓ_{max}\big],

ẑ^r the re-sending design's estimate and H_i(k) the measurements agent i holds at k (its own y_i(0 : k) and the
others' available items). The smoother's gains depend on the realized pattern, so the conditional means are exact
for every pattern. The output is

.. math::  \hat z_i(k) = G_i(k)\, φ_i(k),

G_i(k) fixed offline. G_i = [I 0 0] is the re-sending design, which is kept when the fitted gains do not beat it.

Expected cost
-------------
Given the pattern ω (the on-time packet events), every feature is a linear map of the stacked measurements y, and ω
is independent of the Gaussian variables, so the stage cost of G given ω is an exact quadratic form in the joint
moments Σ_yy, Σ_{x(k)y} (as in :mod:`teamkf.estimators._lossy_rulefill`). Gains minimizing the average over
``patterns`` sampled patterns (ArrivalModel.sample: the on-time indicators) are fitted per step; on as many
**fresh** patterns the paired difference Δ = J(G; ω) − J(G_r; ω) is computed exactly per pattern, and the reported
cost is

.. math::  \hat J = J_r + \bar Δ \qquad (J_r \text{ the re-sending design's exact expected cost}),

an unbiased estimate (a control variate: J_r is known exactly) with the standard error of Δ̄, much smaller than that
of the cost itself. The maps are computed by the agents' own smoother arithmetic on the unit vectors of y.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from typing import Any, Sequence

import numpy as np

from .. import _validation as V
from .._blas import blas_threads
from .._validation import FloatArray
from ..exceptions import ArgumentError, TeamkfError
from ._arrivals import ArrivalModel
from ._lossy_resend import resend_agent_class, resend_design_class
from .team_lossy import _own_cols, _rows

__all__ = ["DEFAULT_PATTERNS", "Smoother", "adaptive_agent_class", "available_steps", "combine", "design_adaptive", "on_time"]

#: sampled link patterns for the fit (and as many fresh ones for the cost) when ``patterns`` is not given
DEFAULT_PATTERNS = 200
#: patterns whose feature maps are held at once
CHUNK = 32


# ---------------------------------------------------------------------------
# what is available when, and the smoother
# ---------------------------------------------------------------------------
def available_steps(arrived: np.ndarray, ell: np.ndarray, r: int) -> np.ndarray:
    """a[b, i, j, s]: the step from which agent i holds y_j(s) (T: never), from the on-time indicators ``arrived``
    (B, T, n, n) [b, τ, j, i] of the packets of origin (j, τ), each carrying y_j(τ - r + 1 : τ).

    The packet of (j, τ) is on time at τ + ℓ_ji; y_j(s) is available from the first on-time packet τ ∈ [s, s + r - 1]
    (the availability of :meth:`ResendLossyDesign.available`)."""
    B, T, n, _ = arrived.shape
    arrived = arrived.copy()
    arrived[:, :, np.arange(n), np.arange(n)] = True  # the own measurement, held at its step
    due = np.where(arrived, np.arange(T)[None, :, None, None] + ell[None, None, :, :], T)  # [b, τ, j, i]
    first = due.copy()
    for c in range(1, min(r, T)):
        first[:, : T - c] = np.minimum(first[:, : T - c], due[:, c:])
    first = np.minimum(first, T)
    return first.transpose(0, 3, 2, 1)  # type: ignore[no-any-return]


class Smoother:
    """Fixed-lag Kalman smoother over [x(k); x(k-1); ...; x(k-D)] for B patterns at once, its mean with C columns.

    The mean is M (B, (D+1) d_x, C) (C: runs, or the unit vectors of y for the maps), the covariance P (B, ., .)
    depends on the pattern only. States before step 0 are zero (variance 0, never measured)."""

    def __init__(self, system: Any, D: int, B: int, C: int):
        self.system, self.D, self.dx = system, D, system.dx
        m = (D + 1) * system.dx
        self.M = np.zeros((B, m, C))
        self.P = np.zeros((B, m, m))
        self.P[:, : self.dx, : self.dx] = system.Sigma_x

    def copy(self) -> "Smoother":
        """An independent copy (its own mean and covariance arrays)."""
        out = Smoother.__new__(Smoother)
        out.__dict__.update(self.__dict__)
        out.M, out.P = self.M.copy(), self.P.copy()
        return out

    def predict(self, k: int) -> None:
        """From k - 1 to k: shift the window, x(k) = A x(k-1) + w."""
        dx, A = self.dx, self.system.A_at(k - 1)
        M, P = self.M, self.P
        Mn = np.empty_like(M)
        Mn[:, :dx] = A @ M[:, :dx]
        Mn[:, dx:] = M[:, :-dx]
        Pn = np.empty_like(P)
        Pn[:, dx:, dx:] = P[:, :-dx, :-dx]
        Pn[:, :dx, dx:] = A @ P[:, :dx, :-dx]
        Pn[:, dx:, :dx] = Pn[:, :dx, dx:].transpose(0, 2, 1)
        Pn[:, :dx, :dx] = A @ P[:, :dx, :dx] @ A.T + self.system.Q_at(k - 1)
        self.M, self.P = Mn, Pn

    def update(self, k: int, j: int, s: int, rows: np.ndarray, values: FloatArray) -> None:
        """Condition the patterns ``rows`` on y_j(s) = C_j x(s) + v, ``values`` (len(rows) or 1, d_y^j, C)."""
        if rows.size == 0:
            return
        dx, b = self.dx, k - s
        Cm, R = self.system.C_at(j, s), self.system.R_at(j, s)
        P, M = self.P[rows], self.M[rows]
        PH = P[:, :, b * dx : (b + 1) * dx] @ Cm.T  # (B', m, d_y)
        S = Cm @ PH[:, b * dx : (b + 1) * dx] + R
        K = np.linalg.solve(S, PH.transpose(0, 2, 1)).transpose(0, 2, 1)  # P Hᵀ S⁻¹ (S symmetric)
        inn = values - Cm @ M[:, b * dx : (b + 1) * dx]
        M = M + K @ inn
        P = P - K @ PH.transpose(0, 2, 1)
        self.M[rows], self.P[rows] = M, 0.5 * (P + P.transpose(0, 2, 1))


def on_time(out: Any, arr: ArrivalModel) -> np.ndarray:
    """(R, T, n, n) [r, τ, j, i]: the packet of origin (j, τ) reached agent i on time (at τ + ℓ_ji), from the lossy runtime's
    link outcomes ``out``: some geodesic path whose every hop was delivered without extra delay (relays flood a packet
    when they first learn it, and on time is the first time)."""
    ok = out.delivered & (out.extra == 0)  # (R, T, E)
    R, T, _ = ok.shape
    if [tuple(e) for e in out.edges] != [tuple(e) for e in arr.edges]:  # pragma: no cover - both sort the graph's edges
        raise TeamkfError("the link outcomes' edges are not the arrival model's")
    d = np.zeros((R, T, arr.n_agents, arr.n_agents), dtype=bool)
    for (j, i), plist in arr.paths.items():
        acc = np.zeros((R, T), dtype=bool)
        for p in plist:
            hit = np.ones((R, T), dtype=bool)
            for e, o in p:
                hit[:, T - o :] = False  # the hop would be sent after the horizon
                hit[:, : T - o] &= ok[:, o:, e]
            acc |= hit
        d[:, :, j, i] = acc
    return d


def _lagged(system: Any, tops: dict[int, FloatArray], k: int, lags: int, shape: tuple[int, ...]) -> FloatArray:
    """[E[x(k) | H(k - l)], l = 1..lags] (zero before step 0): the smoothed E[x(m) | H(m)] of ``tops`` predicted to k."""
    dx = system.dx
    out = np.zeros(shape)
    for lg in range(1, min(lags, k) + 1):
        x = tops[k - lg]
        for m in range(k - lg, k):
            x = system.A_at(m) @ x
        out[..., (lg - 1) * dx : lg * dx, :] = x
    return out


def combine(G: FloatArray, zr: FloatArray, sm: FloatArray) -> FloatArray:
    """ẑ_i(k) = G_i(k) φ_i(k) for rows of φ = [zr (., d_z); sm (., n_f - d_z)] (G = G_i(k), d_z × n_f)."""
    dz = zr.shape[-1]
    return zr @ G[:, :dz].T + sm @ G[:, dz:].T  # type: ignore[no-any-return]


def adaptive_agent_class() -> Any:
    """The agent class of the pattern-adaptive design (for :mod:`teamkf.estimators._lossy_slice`)."""
    return _adaptive_class().Agent


# ---------------------------------------------------------------------------
# the design
# ---------------------------------------------------------------------------
_CLS: list[Any] = []


def _adaptive_class() -> Any:
    if _CLS:
        return _CLS[0]
    Base = resend_design_class()
    ResendAgent = resend_agent_class()

    @dataclass(frozen=True, eq=False, kw_only=True)
    class AdaptiveLossyDesign(Base):  # type: ignore[misc, valid-type]
        """The re-sending design plus pattern-adaptive features (module docstring).

        G : (T, n, d_z, n_f) the gains on φ = [ẑ^r; E[x(k-D : k) | H]; E[x(k) | H(k-l)], l = 1..lags]
        D : the smoother's lag; lags : ℓ_max; kept : "class" or "resend"
        """

        G: FloatArray = field(default_factory=lambda: np.zeros(0), repr=False)
        D: int = 0
        lags: int = 0
        kept: str = "class"

        @property
        def n_features(self) -> int:
            return int(self.cost.dz + (self.D + 1 + self.lags) * self.system.dx)

        # --- features -----------------------------------------------------------------
        def smoothed(self, i: int, avail: np.ndarray, values: Any, C: int) -> Any:
            """Yield, per step k, agent i's [E[x(k-D : k) | H]; E[x(k) | H(k-l)]] (B, (D+1+lags) d_x, C) for B patterns
            ``avail`` (B, n, T) [b, j, s] (the step y_j(s) becomes available to i), ``values(j, s, rows)`` the measurement."""
            sysm, D, L, dx = self.system, self.D, self.lags, self.system.dx
            B, n, T = avail.shape
            sm = Smoother(sysm, D, B, C)
            tops: dict[int, FloatArray] = {}  # E[x(m) | H(m)] of the last ``lags`` steps
            for k in range(T):
                if k:
                    sm.predict(k)
                for s in range(max(0, k - D), k + 1):
                    for j in range(n):
                        rows = np.flatnonzero(avail[:, j, s] == k)
                        if rows.size:
                            sm.update(k, j, s, rows, values(j, s, rows))
                tops[k] = sm.M[:, :dx].copy()
                lag = _lagged(sysm, tops, k, L, (B, L * dx, C))
                tops.pop(k - L, None)  # no longer needed
                yield np.concatenate([sm.M, lag], axis=1)

        # --- every run at once ----------------------------------------------------------------
        def estimates(self, ys: Sequence[FloatArray], arrived: np.ndarray) -> FloatArray:
            """ẑ (R, T, n d_z) of every run from its measurements ``ys[i]`` (R, T, d_y^i) and its on-time packet indicators
            ``arrived`` (R, T, n, n) [r, τ, j, i]: the agents' own arithmetic (:class:`AdaptiveLossyAgent`), runs stacked."""
            sysm, cost = self.system, self.cost
            R, T = ys[0].shape[:2]
            n, dz, dx = sysm.n_agents, cost.dz, sysm.dx
            Y = np.concatenate([np.asarray(y, dtype=float) for y in ys], axis=2).reshape(R, -1)  # [r, s d_y + off_j + c]
            av = available_steps(np.asarray(arrived, dtype=bool)[:, :T], np.asarray(self.arrivals.ell, dtype=int), self.resend)
            out = np.empty((R, T, n * dz))
            for i in range(n):
                xh = np.zeros((R, dx))
                gen = self.smoothed(i, av[:, i], lambda j, s, rows: ys[j][rows, s, :, None], 1) if self.kept == "class" else None
                for k in range(T):
                    xh = xh if k == 0 else xh @ sysm.A_at(k - 1).T
                    xh = xh + (ys[i][:, k] - xh @ sysm.C_at(i, k).T) @ self.K_local[k][i].T
                    z = xh @ cost.L_block(i, k).T
                    its = self.items[k][i]
                    if its:  # the re-sending estimate: available items, else their fills from the own measurements
                        fill = Y[:, _own_cols(sysm, i, k)] @ self.fills[k][i].T
                        a = np.repeat(np.stack([av[:, i, j, s] <= k for (j, s) in its], axis=1), [sysm.dy[j] for j, _ in its], axis=1)
                        z = z + np.where(a, Y[:, _rows(sysm, its)], fill) @ self.gains[k][i].T
                    if gen is not None:
                        z = combine(self.G[k][i], z, next(gen)[:, :, 0])
                    out[:, k, i * dz : (i + 1) * dz] = z
            return out

        def errors(self, paths: Any, *, p_drop: Any = None, jitter: Any = None, rng: Any = None, arrived: Any = None) -> Any:
            """Team errors e(k) = L x(k) - ẑ(k) with sampled packet events (as :meth:`LossyTeamDesign.errors`), all runs at once."""
            _, _, v, arrived = self._error_inputs(paths, p_drop, jitter, rng, arrived)
            T = v.shape[1]
            X = np.asarray(paths.x, dtype=float)[:, :T]
            Lx = np.stack([X[:, k] @ self.cost.L_at(k).T for k in range(T)], axis=1)
            return Lx - self.estimates([np.asarray(y, dtype=float)[:, :T] for y in paths.y], arrived)

        def graph_agents(self) -> list[Any]:
            return [AdaptiveLossyAgent(self, i) for i in range(self.n_agents)]

        def agent_slice(self, i: int) -> tuple[str, dict[str, np.ndarray], dict[str, Any]]:
            """The re-sending agent's slice plus its gains ``AG/k`` = G_i(k) and the smoother's ``D`` and ``lags`` in ``meta``."""
            kind, arrays, meta = super().agent_slice(i)
            T = int(self.horizon or 0)
            arrays.update({f"AG/{k}": np.asarray(self.G[k][i]) for k in range(T)})
            return kind, arrays, {**meta, "adaptive": self.kept == "class", "D": int(self.D), "lags": int(self.lags)}

        def details(self) -> dict[str, Any]:
            out = super().details()
            out["adaptive"] = True
            out["class"] = (
                f"gains per step on the re-sending design's estimate (each packet carries the sender's last {self.resend}) and the "
                "agent's exact conditional means of the recent states given what it holds (re-weighted with the realized pattern)"
            )
            out.update({key: self.info[key] for key in ("kept", "patterns", "sem", "interval", "paired", "resend_cost") if key in self.info})
            return out

        def arrays(self) -> dict[str, np.ndarray]:
            return {**super().arrays(), "G": np.asarray(self.G)}

    class AdaptiveLossyAgent(ResendAgent):  # type: ignore[misc, valid-type]
        """Agent i: the re-sending agent (its packets, its estimate ẑ^r) plus its smoother on the items it holds."""

        @staticmethod
        def run_batched(agents: Sequence[Any], ys: Sequence[FloatArray], out: Any) -> FloatArray:
            """Every agent's :meth:`step` for every run at once on the lossy runtime's link outcomes ``out``
            (:class:`teamkf.simulation.lossy.LinkOutcomes`): :meth:`AdaptiveLossyDesign.estimates` on their on-time events."""
            d = agents[0].design
            return d.estimates(ys, on_time(out, d.arrivals))  # type: ignore[no-any-return]

        def init_state(self, n_runs: int) -> dict[str, Any]:
            st = super().init_state(n_runs)
            d = self.design
            st["sm"] = Smoother(self.system, d.D, 1, n_runs)  # type: ignore[attr-defined]
            st["tops"] = {}
            return st

        def step(self, state: dict[str, Any], k: int, own: Any, inbox: Sequence[Any]) -> tuple[dict[str, Any], Any, list[Any]]:
            d: Any = self.design
            before = set(state["items"])
            sm = state["sm"].copy()  # the state given is left as it was
            new_state, zr, msgs = super().step(state, k, own, inbox)
            if d.kept != "class":
                return new_state, zr, msgs
            sysm, dx = self.system, self.system.dx
            if k:
                sm.predict(k)
            fresh = sorted((s, j) for (j, s) in new_state["items"] if (j, s) not in before and k - d.D <= s <= k)
            one = np.zeros(1, dtype=int)
            for s, j in fresh:
                val = np.asarray(new_state["items"][(j, s)], dtype=float).reshape(-1, sysm.dy[j]).T[None]
                sm.update(k, j, s, one, val)
            tops = {m: v for m, v in state["tops"].items() if m > k - 1 - d.lags}
            tops[k] = sm.M[0, :dx].copy()
            lag = _lagged(sysm, tops, k, d.lags, (d.lags * dx, sm.M.shape[2]))
            phi = np.concatenate([sm.M[0], lag], axis=0).T  # (n_runs, n_f - d_z)
            z = combine(d.G[k][self.index], np.asarray(zr).reshape(phi.shape[0], -1), phi)
            new_state["sm"], new_state["tops"] = sm, tops
            return new_state, z, msgs

    AdaptiveLossyDesign.Agent = AdaptiveLossyAgent  # type: ignore[attr-defined]
    _CLS.append(AdaptiveLossyDesign)
    return AdaptiveLossyDesign


# ---------------------------------------------------------------------------
# maps, fit and cost
# ---------------------------------------------------------------------------
def _resend_maps(d: Any, i: int, k: int, Ny: int) -> tuple[FloatArray, FloatArray, list[tuple[int, int]]]:
    """ẑ^r_i(k) = base + Σ_c a_c U_c as maps of y: base (d_z, Ny) with every item filled, U (items, d_z, Ny)."""
    sysm = d.system
    dyt, off = sysm.dy_total, sysm.offsets
    its = list(d.items[k][i])
    X = d._loc[k][i]
    base = d.cost.L_block(i, k) @ X
    U = np.zeros((len(its), d.cost.dz, Ny))
    if its:
        G = d.gains[k][i]
        F = np.zeros((d.fills[k][i].shape[0], Ny))
        F[:, _own_cols(sysm, i, k)] = d.fills[k][i]
        base = base + G @ F
        col = 0
        for c, (j, s) in enumerate(its):
            dj = int(sysm.dy[j])
            Gc = G[:, col : col + dj]
            U[c] = -Gc @ F[col : col + dj]
            U[c][:, s * dyt + int(off[j]) + np.arange(dj)] += Gc
            col += dj
    return base, U, its


def _maps(d: Any, av: np.ndarray) -> Any:
    """Per step k: Φ (B, n, n_f, Ny), every feature of every agent as a map of y, for the B patterns ``av``."""
    sysm = d.system
    n, T, dyt, off = sysm.n_agents, int(d.horizon), sysm.dy_total, sysm.offsets
    Ny = T * dyt
    B = av.shape[0]
    unit = {}
    for j in range(n):
        for s in range(T):
            e = np.zeros((1, int(sysm.dy[j]), Ny))
            e[0, :, s * dyt + int(off[j]) + np.arange(sysm.dy[j])] = np.eye(sysm.dy[j])
            unit[(j, s)] = e
    gens = [d.smoothed(i, av[:, i], lambda j, s, rows: unit[(j, s)], Ny) for i in range(n)]
    for k in range(T):
        Phi = np.zeros((B, n, d.n_features, Ny))
        for i in range(n):
            base, U, its = _resend_maps(d, i, k, Ny)
            a = np.stack([av[:, i, j, s] <= k for (j, s) in its], axis=1).astype(float) if its else np.zeros((B, 0))
            Phi[:, i, : d.cost.dz] = base[None] + np.einsum("bc,caz->baz", a, U)
            Phi[:, i, d.cost.dz :] = next(gens[i])
        yield k, Phi


def _moments(d: Any, av: np.ndarray, Syy: FloatArray, Sxy: Sequence[FloatArray]) -> tuple[FloatArray, FloatArray]:
    """Mean over the patterns of E[φ φᵀ] and E[φ x(k)ᵀ] per step: (T, n n_f, n n_f), (T, n n_f, d_x)."""
    T, n, nf, dyt = int(d.horizon), d.system.n_agents, d.n_features, d.system.dy_total
    Mff, Mfx = np.zeros((T, n * nf, n * nf)), np.zeros((T, n * nf, d.system.dx))
    P = av.shape[0]
    for a in range(0, P, CHUNK):
        for k, Phi in _maps(d, av[a : a + CHUNK]):
            c = (k + 1) * dyt  # y after step k is not used
            F = Phi.reshape(Phi.shape[0], n * nf, -1)[:, :, :c]
            Mff[k] += np.einsum("bfc,bgc->fg", F @ Syy[:c, :c], F, optimize=True) / P
            Mfx[k] += np.einsum("bfc,xc->fx", F, Sxy[k][:, :c], optimize=True) / P
    return Mff, Mfx


def pattern_costs(
    d: Any, av: np.ndarray, Gs: Sequence[FloatArray], Syy: FloatArray, Sxy: Sequence[FloatArray], Px: Sequence[FloatArray]
) -> np.ndarray:
    """(len(Gs), B, T): the exact stage cost of each gain set given each pattern."""
    T, n, dz, dyt = int(d.horizon), d.system.n_agents, d.cost.dz, d.system.dy_total
    out = np.zeros((len(Gs), av.shape[0], T))
    for a in range(0, av.shape[0], CHUNK):
        for k, Phi in _maps(d, av[a : a + CHUNK]):
            S, L = d.cost.S_at(k), d.cost.L_at(k)
            c = (k + 1) * dyt
            c0 = float(np.trace(S @ L @ Px[k] @ L.T))
            for g, G in enumerate(Gs):
                Z = np.einsum("iaf,bifc->biac", G[k], Phi[:, :, :, :c], optimize=True).reshape(Phi.shape[0], n * dz, c)
                cross = np.einsum("ax,bax->b", S @ L, Z @ Sxy[k][:, :c].T)
                quad = np.einsum("bac,bac->b", S[None] @ Z @ Syy[:c, :c], Z)
                out[g, a : a + Phi.shape[0], k] = c0 - 2.0 * cross + quad
    return out


def _check_size(d: Any, count: int) -> None:
    """Refuse, before any work, a fit whose memory or optimistic time exceeds the budget (naming ``patterns`` and the horizon).

    Memory: Σ_yy and the unit vectors of y (N_y² each, N_y = T d_y), Σ_{x(k)y}, one chunk of feature maps and
    smoothers, and the moments (T (n n_f)²). Work: per pattern (fit and fresh) and step k, Φ Σ_yy Φᵀ on the
    (k + 1) d_y columns used: 2 n n_f ((k + 1) d_y)² flops."""
    from .. import _budget

    sysm, T = d.system, int(d.horizon)
    n, nf, dyt = sysm.n_agents, d.n_features, sysm.dy_total
    Ny = T * dyt
    peak = 8.0 * (2 * Ny * Ny + T * sysm.dx * Ny + CHUNK * n * (nf + (d.D + 1) * sysm.dx) * Ny + T * (n * nf) ** 2)
    flops = 2.0 * count * sum(2.0 * n * nf * ((k + 1) * dyt) ** 2 for k in range(T))
    loops = 2.0 * count * T * n * (d.D + 1) * n  # the smoothers' updates
    what = f"the adaptive mtmse_lossy design over T = {T:,} steps with {count:,} + {count:,} link patterns"
    fix = "fewer patterns (patterns = N), a shorter horizon, or adaptive = false (the re-sending design alone, exact)"
    _budget.check_memory(peak, what, argument="patterns", fix=fix)
    _budget.announce(_budget.check_work(flops, what, argument="patterns", fix=fix, loops=loops), what)


def design_adaptive(resend_design: Any, *, patterns: int | None = None, rng: Any = 0, threads: int | None = 1) -> Any:
    """``design_mtmse_lossy(..., resend=r, adaptive=True)`` (module docstring) from the re-sending design ``resend_design``:
    gains fitted on ``patterns`` sampled link patterns, the cost on as many fresh ones (paired with the re-sending design)."""
    from ._lossy_rulefill import _joint, gains_from_moments, local_filter_maps

    rd = resend_design
    if rd.coordinates != "measurements":
        raise ArgumentError(
            f'adaptive: the smoother conditions on raw measurements, found items = "{rd.coordinates}"; set items = "measurements"',
            argument="adaptive",
        )
    count = DEFAULT_PATTERNS if patterns is None else V.integer(patterns, "patterns", minimum=2)
    cls = _adaptive_class()
    sysm, T = rd.system, int(rd.horizon)
    arr: ArrivalModel = rd.arrivals
    ell = np.asarray(arr.ell, dtype=int)
    r = int(rd.resend)
    init = {f.name: getattr(rd, f.name) for f in fields(rd) if f.init}
    D, lags = int(ell.max()) + r - 1, int(ell.max())
    d0 = cls(**{**init, "D": D, "lags": lags, "G": np.zeros((T, sysm.n_agents, rd.cost.dz, 0))})
    _check_size(d0, count)
    object.__setattr__(d0, "_loc", local_filter_maps(sysm, rd.K_local, T))
    gen = np.random.default_rng(rng)
    av_fit = available_steps(arr.sample(count, T, gen), ell, r)
    av_new = available_steps(arr.sample(count, T, gen), ell, r)  # fresh: the reported cost is unbiased
    with blas_threads(threads):  # BLAS threads change the bits of the gains: a deployment's slices and its replay must agree
        Syy, Sxy, Px = _joint(sysm, T)
        Gc = gains_from_moments(rd.cost, sysm.n_agents, d0.n_features, *_moments(d0, av_fit, Syy, Sxy))
        Gr = np.zeros_like(Gc)
        Gr[:, :, :, : rd.cost.dz] = np.eye(rd.cost.dz)
        costs = pattern_costs(d0, av_new, [Gc, Gr], Syy, Sxy, Px)
    diff = costs[0] - costs[1]  # (P, T): paired, per pattern
    dtot = diff.sum(axis=1)
    sem = float(dtot.std(ddof=1) / np.sqrt(count))
    j_r = float(np.sum(rd.stage_costs))
    kept = "class" if dtot.mean() < 0.0 else "resend"
    stage = np.asarray(rd.stage_costs, dtype=float) + (diff.mean(axis=0) if kept == "class" else 0.0)
    value = float(stage.sum())
    info = dict(rd.info)
    info.update(
        {
            "adaptive": True,
            "exact": kept != "class",  # the class's cost is estimated over sampled patterns (its interval in the table)
            "kept": kept,
            "patterns": count,
            "sem": sem if kept == "class" else 0.0,
            "interval": [value - 1.96 * sem, value + 1.96 * sem] if kept == "class" else [value, value],
            "paired": {"diff": float(dtot.mean()), "sem": sem},
            "resend_cost": j_r,
            "resend_cost_sampled": {"cost": float(costs[1].sum(axis=1).mean()), "sem": float(costs[1].sum(axis=1).std(ddof=1) / np.sqrt(count))},
            "smoother_lag": D,
        }
    )
    lb = np.minimum(np.asarray(rd.lower_bound_stages, dtype=float), stage)
    d = cls(
        **{
            **init,
            "stage_costs": stage,
            "info": info,
            "lower_bound_stages": lb,
            "D": D,
            "lags": lags,
            "G": Gc if kept == "class" else Gr,
            "kept": kept,
        }
    )
    object.__setattr__(d, "_loc", d0._loc)
    d.info["lower_bound"] = d.lower_bound
    d.info["gap"] = d.gap
    return d


from .team_lossy import register_adaptive  # noqa: E402  (this module extends team_lossy, which never imports it)

register_adaptive(design_adaptive)
