r"""A drop-aware class that contains the missed-packet rule (``mtmse_lossy`` with ``fill = "held"``).

The class
---------
Every agent relays raw measurements as the nominal MTMSE relays do (forwarded once, when first
learned), so agent i holds y_j(s) from step t_i(j, s) on (the realized arrival pattern). At step k it
computes four **features** from what it holds, each online from the realized pattern:

* φ¹ = x̂_i(k|k), its own Kalman filter (prior 0, Σ_x);
* φ² = ẑ_i^rule(k), the nominal MTMSE estimate under the **missed-packet rule** (a missing
  measurement replaced by its conditional expectation given everything the agent holds,
  :meth:`teamkf.estimators.team.TeamAgent.expected_measurements`): the very agent the nominal design
  runs over drops;
* φ³ = ẑ_i^today(k), today's drop-aware estimate (``mtmse_lossy``, ``items = "measurements"``,
  ``fill = True``: pattern-independent gains on the on-time items, missed ones filled from the own items);
* φ⁴ = [E[x(k) | H]; E[y(k-W+1 : k) | H]], H = y_i(0:k) and the others' y_j(s), s > k - W, held at k: the
  agent's exact conditional mean of the state and of every item of the last W steps (``window``, default
  ℓ_max + 2), each missing item **filled from everything held** in the window;

and outputs

.. math::  \hat z_i(k) = G_i(k)\, [φ¹; φ²; φ³; φ⁴],

with offline gains G_i(k) (d_z × (2 d_x + 2 d_z + W Σ_j d_y^j)). G_i = [L_i 0 0 0] is the local filters,
[0 I 0 0] the nominal design under the missed-packet rule, [0 0 I 0] today's class: the optimum of the
class is never worse than any of them, and the design keeps the best of the four by the same cost
(below), so it is never worse by construction.

Expected cost
-------------
Given the realized link pattern ω (which packet of which edge at which step was lost) every feature is
a linear map of the stacked measurements y = (y(0), ..., y(T-1)): φ_i(k) = Φ_i(k; ω) y. Link events are
independent of the Gaussian variables, so with Σ_yy, Σ_{x(k) y} the exact joint moments

.. math::  J_k(G) = E_ω\big[\operatorname{Tr} S\,(\bar L P_x \bar L^\top - 2\,\bar L Σ_{xy} Z^\top + Z Σ_{yy} Z^\top)\big],
           \qquad Z = \operatorname{diag}_i(G_i)\, Φ(k; ω),

a convex quadratic in G whose coefficients are expectations over ω of exact Gaussian moments. The
maps Φ(k; ω) are computed by running the agents' own arithmetic on the unit vectors of y (they are
linear in y given ω). The expectation over ω is

* **exact** when the link events that matter (packets of every edge at every step that arrive within the
  horizon) number at most log₂ :data:`EXACT_LIMIT`: every pattern is enumerated with its probability;
* otherwise **Rao–Blackwellized Monte Carlo over link patterns only** (each pattern's moments exact):
  the gains are fitted on ``patterns`` sampled patterns and the cost of the fitted gains, and of the
  three members above, is estimated on ``patterns`` **fresh** patterns (independent of the fit), so the
  reported cost is unbiased, with its standard error (``info["sem"]``, ``info["interval"]`` ± 1.96).
  The member with the lowest cost on the fresh patterns is kept (the paired differences, which have
  much smaller errors than the costs, are in ``info["paired"]``).

Supported links: a drop probability (one, or per edge) with no jitter; the agents run on the lossy
runtime (:func:`teamkf.simulation.lossy.run_lossy`, every run at once) and as one-run online agents.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from .. import _validation as V
from .._lazy import scipy_linalg as sla
from .._validation import FloatArray
from ..exceptions import ArgumentError
from ._arrivals import ArrivalModel
from .base import Design

__all__ = ["EXACT_LIMIT", "RuleFillDesign", "RuleFillAgent", "design_rulefill", "flood_arrivals", "pattern_costs"]

#: enumerate every link pattern when there are at most this many (else Monte Carlo over patterns)
EXACT_LIMIT = 4096
#: sampled patterns for the fit (and as many fresh ones for the cost) when ``patterns`` is not given
DEFAULT_PATTERNS = 400
_CANDIDATES = ("class", "rule", "today", "local")


# ---------------------------------------------------------------------------
# link patterns and what the relays deliver
# ---------------------------------------------------------------------------
def flood_arrivals(edges: Sequence[tuple[int, int, int]], lost: np.ndarray, n: int, T: int) -> np.ndarray:
    """t[r, i, j, s]: the step at which agent i first holds y_j(s) (T: never), relays forwarding once, no jitter.

    ``lost`` (R, T, E) says which packet of edge e = ``edges[e]`` = (a, b, delay) sent at step k was lost; the
    same recursion as :func:`teamkf.simulation.lossy.relay_arrivals` (a packet sent at k arrives at k + delay).
    """
    R = lost.shape[0]
    t = np.full((R, n, n, T), T, dtype=np.int64)
    for i in range(n):
        t[:, i, i, :] = np.arange(T)
    for k in range(T):
        for e, (a, b, dl) in enumerate(edges):
            if k + dl > T - 1:
                continue
            ok = ~lost[:, k, e]
            if not ok.any():
                continue
            learnt = t[:, a] == k  # (R, n, T): what a learnt at k, forwarded at k
            upd = learnt & ok[:, None, None]
            np.minimum(t[:, b], np.where(upd, k + dl, T), out=t[:, b])
    return t


def local_filter_maps(system: Any, K_local: Any, T: int) -> list[list[FloatArray]]:
    """x̂_i(k|k) of the local Kalman filters (gains ``K_local[k][i]``, prior 0) as maps of y (d_x × T d_y), per step and agent."""
    dyt, off = system.dy_total, system.offsets
    out: list[list[FloatArray]] = []
    X = [np.zeros((system.dx, T * dyt)) for _ in range(system.n_agents)]
    for k in range(T):
        row = []
        for i in range(system.n_agents):
            pred = X[i] if k == 0 else system.A_at(k - 1) @ X[i]
            nu = -system.C_at(i, k) @ pred
            nu[:, k * dyt + int(off[i]) + np.arange(system.dy[i])] += np.eye(system.dy[i])
            X[i] = pred + K_local[k][i] @ nu
            row.append(X[i])
        out.append(row)
    return out


def _relevant_events(edges: Sequence[tuple[int, int, int]], T: int) -> list[tuple[int, int]]:
    return [(k, e) for k in range(T) for e, (_, _, dl) in enumerate(edges) if k + dl <= T - 1]


# ---------------------------------------------------------------------------
# joint moments of (x, y)
# ---------------------------------------------------------------------------
def _joint(system: Any, T: int) -> tuple[FloatArray, list[FloatArray], list[FloatArray]]:
    """Σ_yy (T d_y × T d_y), Σ_{x(k) y} and P_x(k) for k < T (exact, from the primitives)."""
    dx, dyt = system.dx, system.dy_total
    D = dx * T + dyt * T
    Lam = np.zeros((D, D))
    Lam[:dx, :dx] = system.Sigma_x
    for k in range(T - 1):
        Lam[dx * (k + 1) : dx * (k + 2), dx * (k + 1) : dx * (k + 2)] = system.Q_at(k)
    for k in range(T):
        o = dx * T + dyt * k
        Lam[o : o + dyt, o : o + dyt] = system.R_stack(k)
    X = np.zeros((dx, D))
    X[:, :dx] = np.eye(dx)
    Ym = np.zeros((dyt * T, D))
    Xs = []
    for k in range(T):
        Xs.append(X.copy())
        Ym[dyt * k : dyt * (k + 1)] = system.C_stack(k) @ X
        Ym[dyt * k : dyt * (k + 1), dx * T + dyt * k : dx * T + dyt * (k + 1)] += np.eye(dyt)
        if k < T - 1:
            X = system.A_at(k) @ X
            X[:, dx * (k + 1) : dx * (k + 2)] += np.eye(dx)
    Syy = Ym @ Lam @ Ym.T
    return 0.5 * (Syy + Syy.T), [Xk @ Lam @ Ym.T for Xk in Xs], [Xk @ Lam @ Xk.T for Xk in Xs]


# ---------------------------------------------------------------------------
# the design
# ---------------------------------------------------------------------------
@dataclass(frozen=True, eq=False, kw_only=True)
class RuleFillDesign(Design):
    """``mtmse_lossy`` with ``fill = "held"``: gains on four features, one of them the missed-packet rule (module docstring).

    Attributes
    ----------
    graph : CommGraph
    p_drop : the drop probability it is designed for (a number, or {(a, b): p})
    window : W, the steps of the others' held measurements in the conditional-mean feature
    nominal : the nominal MTMSE design (its agents give the rule's feature)
    today : today's drop-aware design (``items = "measurements"``, pattern-independent gains)
    G : (T, n, d_z, n_f) the gains of the kept member ([φ¹ φ² φ³ φ⁴] per agent, n_f = 2 d_x + 2 d_z + W Σ d_y)
    kept : which member was kept: "class" (the fitted optimum), "rule", "today" or "local"
    """

    graph: Any
    p_drop: Any
    window: int
    nominal: Any = field(repr=False)
    today: Any = field(repr=False)
    G: FloatArray = field(repr=False)
    kept: str = "class"
    _cache: dict[Any, Any] = field(default_factory=dict, repr=False)

    @property
    def tolerates_losses(self) -> bool:
        return True

    @property
    def cost_link_model(self) -> dict[str, Any]:
        return {"p_drop": self.p_drop, "jitter": 0}

    @property
    def lower_bound(self) -> float:
        return float(self.info.get("lower_bound", np.nan))

    @property
    def delivery_graph(self) -> Any:
        return self.graph

    @property
    def n_features(self) -> int:
        return 2 * self.system.dx + 2 * self.cost.dz + self.window * self.system.dy_total

    # --- features --------------------------------------------------------------------
    def _local_maps(self) -> list[list[FloatArray]]:
        """x̂_i(k|k) as maps of y (d_x × T d_y), per step and agent (pattern independent)."""
        got = self._cache.get("local")
        if got is None:
            got = self._cache["local"] = local_filter_maps(self.system, self.today.K_local, int(self.horizon or 0))
        return got  # type: ignore[no-any-return]

    def _cm_gain(self, i: int, k: int, held: tuple[int, ...]) -> tuple[np.ndarray, FloatArray]:
        """(columns H, [Σ_{x(k) H}; Σ_{y(k-W+1:k) H}] Σ_HH⁻¹) for agent i at k holding the others' window items ``held``."""
        key = ("cm", i, k, held)
        got = self._cache.get(key)
        if got is None:
            sysm = self.system
            dyt, off = sysm.dy_total, sysm.offsets
            own = np.concatenate([s * dyt + int(off[i]) + np.arange(sysm.dy[i]) for s in range(k + 1)])
            H = np.sort(np.concatenate([own, np.asarray(held, dtype=int)])).astype(int)
            Syy, Sxy = self._cache["Syy"], self._cache["Sxy"]
            lo = k - self.window + 1  # the window items y(k-W+1 : k), zero rows before step 0
            win = np.arange(max(lo, 0) * dyt, (k + 1) * dyt)
            tgt = np.zeros((sysm.dx + self.window * dyt, H.size))
            tgt[: sysm.dx] = Sxy[k][:, H]
            tgt[sysm.dx + (max(lo, 0) - lo) * dyt :] = Syy[np.ix_(win, H)]
            cf = sla.cho_factor(Syy[np.ix_(H, H)], lower=True, check_finite=False)
            g = sla.cho_solve(cf, tgt.T, check_finite=False).T
            got = self._cache[key] = (H, g)
            if len(self._cache) > 200000:  # bounded (patterns repeat, but need not)
                keep = {k_: v for k_, v in self._cache.items() if not (isinstance(k_, tuple) and k_[0] == "cm")}
                self._cache.clear()
                self._cache.update(keep)
        return got  # type: ignore[no-any-return]

    def features(self, k: int, Y: FloatArray, t: np.ndarray, rule: FloatArray, *, rep: int = 1, only: int | None = None) -> FloatArray:
        """φ(k) of every run: (R, n, n_f) from the stacked measurements Y (R, T d_y) (unheld entries unused),
        the arrival steps t (R / rep, n, n, T: run r has the pattern of row r // rep) and the rule's estimates ``rule``
        (R, n, d_z); ``only``: agent ``only``'s features (the others' stay 0)."""
        sysm, cost, td = self.system, self.cost, self.today
        n, dx, dz, dyt, off = sysm.n_agents, sysm.dx, cost.dz, sysm.dy_total, sysm.offsets
        R = Y.shape[0]
        ell = np.asarray(td.arrivals.ell, dtype=int)
        W = self.window
        loc = self._local_maps()[k]
        out = np.zeros((R, n, self.n_features))
        for i in range(n) if only is None else (only,):
            xh = Y @ loc[i].T
            out[:, i, :dx] = xh
            out[:, i, dx : dx + dz] = rule[:, i]
            # today's class: on-time items, else the fill from the own measurements
            z = xh @ cost.L_block(i, k).T
            its = td.items[k][i]
            if its:
                own = np.concatenate([s * dyt + int(off[i]) + np.arange(sysm.dy[i]) for s in range(k + 1)])
                fill = Y[:, own] @ td.fills[k][i].T
                parts, col = [], 0
                for j, s in its:
                    dj = int(sysm.dy[j])
                    on = np.repeat(t[:, i, j, s] == s + int(ell[j, i]), rep)
                    cols = s * dyt + int(off[j]) + np.arange(dj)
                    parts.append(np.where(on[:, None], Y[:, cols], fill[:, col : col + dj]))
                    col += dj
                z = z + np.concatenate(parts, axis=1) @ td.gains[k][i].T
            out[:, i, dx + dz : dx + 2 * dz] = z
            # the conditional mean given the own history and the others' window items held at k
            slots = [(j, s) for s in range(max(0, k - W + 1), k + 1) for j in range(n) if j != i]
            if slots:
                bits = np.stack([t[:, i, j, s] <= k for (j, s) in slots], axis=1)
                codes, inv = np.unique(bits, axis=0, return_inverse=True)
                inv = np.repeat(np.asarray(inv).ravel(), rep)
            else:
                codes, inv = np.zeros((1, 0), dtype=bool), np.zeros(R, dtype=int)
            for c in range(codes.shape[0]):
                rows = np.flatnonzero(inv == c)
                held = tuple(
                    int(v) for (j, s), b in zip(slots, codes[c].tolist()) if b for v in (s * dyt + int(off[j]) + np.arange(sysm.dy[j])).tolist()
                )
                H, g = self._cm_gain(i, k, held)
                out[rows, i, dx + 2 * dz :] = Y[np.ix_(rows, H)] @ g.T  # [E[x(k) | H]; E[y(k-W+1 : k) | H]]
        return out

    def combine(self, k: int, phi: FloatArray) -> FloatArray:
        """ẑ(k) = G_i(k) φ_i(k) for every run: (R, n d_z)."""
        z = np.einsum("iaf,rif->ria", self.G[k], phi)
        return z.reshape(phi.shape[0], -1)  # type: ignore[no-any-return]

    # --- runtime -------------------------------------------------------------------------
    def graph_agents(self) -> list[Any]:
        """One agent per node: the nominal relay (its rule's estimate) plus the features and the gains."""
        return [RuleFillAgent(self, i) for i in range(self.n_agents)]

    def details(self) -> dict[str, Any]:
        return {
            "p_drop": self.p_drop if not isinstance(self.p_drop, dict) else {f"{a}->{b}": v for (a, b), v in self.p_drop.items()},
            "fill": "held",
            "class": "gains per step on [own KF, nominal MTMSE under the missed-packet rule, today's drop-aware estimate, "
            "conditional mean given what is held]",
            "kept": self.kept,
            "window": self.window,
            **{
                key: self.info[key] for key in ("exact", "patterns", "sem", "interval", "member_costs", "paired", "local_kf_cost") if key in self.info
            },
        }

    def arrays(self) -> dict[str, np.ndarray]:
        return {**super().arrays(), "G": np.asarray(self.G)}


class RuleFillAgent:
    """Agent i of a :class:`RuleFillDesign` on the message-passing runtime: the nominal MTMSE relay with the
    missed-packet rule (its messages are the relay's), plus the held measurements and their arrival steps."""

    def __init__(self, design: RuleFillDesign, index: int):
        from .base import MeasurementRelay

        self.design = design
        self.index = index
        self.system = design.system
        inner = design.nominal.agents()[index]
        inner.tolerant = True
        self.relay = MeasurementRelay(inner)
        self.tolerant = True

    def init_state(self, n_runs: int) -> dict[str, Any]:
        T, n = int(self.design.horizon or 0), self.system.n_agents
        return {"relay": self.relay.init_state(n_runs), "Y": np.zeros((n_runs, T * self.system.dy_total)), "t": np.full((n, T), T, dtype=np.int64)}

    def step(self, state: dict[str, Any], k: int, own: Any, inbox: Sequence[Any]) -> tuple[dict[str, Any], FloatArray, list[Any]]:
        d, i, sysm = self.design, self.index, self.system
        self.relay.inner.tolerant = True  # type: ignore[attr-defined]
        relay_state, z_rule, new = self.relay.step(state["relay"], k, own, inbox)
        Y, t = state["Y"].copy(), state["t"].copy()
        dyt, off = sysm.dy_total, sysm.offsets
        for j, s, v in new:
            if 0 <= s < t.shape[1]:
                t[j, s] = k
                Y[:, s * dyt + int(off[j]) : s * dyt + int(off[j]) + sysm.dy[j]] = np.asarray(v, dtype=float).reshape(Y.shape[0], -1)
        R, n = Y.shape[0], sysm.n_agents
        tt = np.full((R, n, n, t.shape[1]), t.shape[1], dtype=np.int64)
        tt[:, i] = t[None]
        rule = np.zeros((R, n, d.cost.dz))
        rule[:, i] = z_rule
        phi = d.features(k, Y, tt, rule, only=i)[:, i]
        z = phi @ d.G[k][i].T
        return {"relay": relay_state, "Y": Y, "t": t}, z, new


# ---------------------------------------------------------------------------
# the rule's maps at design time: the nominal agents on the unit vectors of y
# ---------------------------------------------------------------------------
def _rule_maps(nominal: Any, t: np.ndarray, T: int, cache: dict[Any, Any]) -> FloatArray:
    """(P, T, n, d_z, T d_y): the nominal agents' estimates under the missed-packet rule as maps of y, per pattern."""
    sysm = nominal.system
    n, dyt, off = sysm.n_agents, sysm.dy_total, sysm.offsets
    dz = nominal.cost.dz
    Ny = T * dyt
    P = t.shape[0]
    agents = cache.get("rule_agents")
    if agents is None:
        agents = cache["rule_agents"] = nominal.agents()
        for ag in agents:
            ag.tolerant = True
    eye = np.eye(Ny)
    out = np.zeros((P, T, n, dz, Ny))
    for i in range(n):
        for p in range(P):
            key = ("rule", i, t[p, i].tobytes())
            got = cache.get(key)
            if got is None:
                st = agents[i].init_state(Ny)
                zs = []
                for k in range(T):
                    js, ss = np.nonzero(t[p, i] == k)
                    rec = [(int(j), int(s), eye[:, s * dyt + int(off[j]) : s * dyt + int(off[j]) + sysm.dy[j]]) for j, s in zip(js, ss)]
                    rec.sort(key=lambda x: (x[1], x[0]))
                    st, z = agents[i].step(st, k, rec)
                    zs.append(np.asarray(z).T)
                got = cache[key] = np.stack(zs)
            out[p, :, i] = got
    return out


def _pattern_maps(d: RuleFillDesign, t: np.ndarray) -> list[FloatArray]:
    """Per step, Φ (P, n, n_f, T d_y): every feature as a map of y, per pattern."""
    T = int(d.horizon or 0)
    Ny = T * d.system.dy_total
    P, n = t.shape[0], d.system.n_agents
    rmaps = _rule_maps(d.nominal, t, T, d._cache)
    Yb = np.tile(np.eye(Ny), (P, 1))
    out = []
    for k in range(T):
        rule = rmaps[:, k].transpose(0, 3, 1, 2).reshape(P * Ny, n, -1)  # run (p, column c): map column c
        phi = d.features(k, Yb, t, rule, rep=Ny)  # (P Ny, n, nf)
        out.append(phi.reshape(P, Ny, n, -1).transpose(0, 2, 3, 1))
    return out


#: link patterns whose feature maps are held at once (memory: chunk × T × n × n_f × T d_y floats)
CHUNK = 64


def _chunks(d: RuleFillDesign, t: np.ndarray) -> Any:
    """(first pattern, Φ of :func:`_pattern_maps`) over chunks of :data:`CHUNK` patterns."""
    for a in range(0, t.shape[0], CHUNK):
        yield a, _pattern_maps(d, t[a : a + CHUNK])


def pattern_costs(d: RuleFillDesign, t: np.ndarray, Gs: Sequence[FloatArray]) -> np.ndarray:
    """(len(Gs), P, T): the exact stage cost of each gain set (T, n, d_z, n_f) given each pattern (arrivals ``t``)."""
    Syy, Sxy, Px = d._cache["Syy"], d._cache["Sxy"], d._cache["Px"]
    T, P = int(d.horizon or 0), t.shape[0]
    out = np.zeros((len(Gs), P, T))
    n, dz = d.system.n_agents, d.cost.dz
    for a, Phi in _chunks(d, t):
        p = Phi[0].shape[0]
        for k in range(T):
            S, L = d.cost.S_at(k), d.cost.L_at(k)
            c0 = float(np.trace(S @ L @ Px[k] @ L.T))
            SL = S @ L
            for g, G in enumerate(Gs):
                Z = np.einsum("iaf,pifc->piac", G[k], Phi[k], optimize=True).reshape(p, n * dz, -1)  # ẑ = Z y
                cross = np.einsum("ax,pax->p", SL, Z @ Sxy[k].T)
                quad = np.einsum("pac,pac->p", S[None] @ Z @ Syy, Z)  # Tr S Z Σ_yy Zᵀ
                out[g, a : a + p, k] = c0 - 2.0 * cross + quad
    return out


def _fit(d: RuleFillDesign, t: np.ndarray, w: FloatArray) -> FloatArray:
    """The gains minimizing Σ_ω w(ω) J_k(G; ω) at every step (Γ g = η; least squares where Γ is singular)."""
    Syy, Sxy = d._cache["Syy"], d._cache["Sxy"]
    T = int(d.horizon or 0)
    n, nf = d.system.n_agents, d.n_features
    Mffs = np.zeros((T, n * nf, n * nf))
    Mfxs = np.zeros((T, n * nf, d.system.dx))
    for a, Phi in _chunks(d, t):
        for k in range(T):
            P, Ny = Phi[k].shape[0], Phi[k].shape[3]
            F = Phi[k].reshape(P, n * nf, Ny)
            Fw = (F * w[a : a + P, None, None]).transpose(1, 0, 2).reshape(n * nf, P * Ny)
            Mffs[k] += (Fw.reshape(n * nf * P, Ny) @ Syy).reshape(n * nf, P * Ny) @ F.transpose(1, 0, 2).reshape(n * nf, P * Ny).T
            Mfxs[k] += (Fw.reshape(n * nf * P, Ny) @ Sxy[k].T).reshape(n * nf, P, -1).sum(axis=1)
    return gains_from_moments(d.cost, n, nf, Mffs, Mfxs)


def gains_from_moments(cost: Any, n: int, nf: int, Mffs: FloatArray, Mfxs: FloatArray) -> FloatArray:
    """Per step, the gains G_i(k) (d_z × n_f) minimizing E Tr S (L x - ẑ)(L x - ẑ)ᵀ, ẑ_i = G_i φ_i, given the features'
    moments Mffs[k] = E[φ φᵀ] (n n_f × n n_f) and Mfxs[k] = E[φ x(k)ᵀ]: Γ g = η (least squares where Γ is singular)."""
    T, dz = Mffs.shape[0], cost.dz
    G = np.zeros((T, n, dz, nf))
    for k in range(T):
        S, L = cost.S_at(k), cost.L_at(k)
        Mff, Mfx = Mffs[k].reshape(n, nf, n, nf), Mfxs[k].reshape(n, nf, -1)
        Gam = np.einsum("iajb,ifjh->iafjbh", S.reshape(n, dz, n, dz), Mff).reshape(n * dz * nf, -1)
        eta = np.einsum("iax,ifx->iaf", (S @ L).reshape(n, dz, -1), Mfx).ravel()
        Gam = 0.5 * (Gam + Gam.T)
        sc = max(float(np.max(np.abs(np.diag(Gam)))), 1e-300)
        try:
            g = sla.solve(Gam + 1e-12 * sc * np.eye(Gam.shape[0]), eta, assume_a="pos", check_finite=False)
        except np.linalg.LinAlgError:  # pragma: no cover - redundant features: any solution has the same cost
            g = np.linalg.lstsq(Gam, eta, rcond=1e-12)[0]
        G[k] = g.reshape(n, dz, nf)
    return G


def _members(d: RuleFillDesign) -> dict[str, FloatArray]:
    """The gains of the rule, today's class and the local filters inside the class."""
    T, n, dx, dz = int(d.horizon or 0), d.system.n_agents, d.system.dx, d.cost.dz
    out = {}
    for name in ("rule", "today", "local"):
        G = np.zeros((T, n, dz, d.n_features))
        for k in range(T):
            for i in range(n):
                if name == "local":
                    G[k, i, :, :dx] = d.cost.L_block(i, k)
                elif name == "rule":
                    G[k, i, :, dx : dx + dz] = np.eye(dz)
                else:
                    G[k, i, :, dx + dz : dx + 2 * dz] = np.eye(dz)
        out[name] = G
    return out


def _patterns(arr: ArrivalModel, T: int, n: int, *, count: int, rng: np.random.Generator) -> tuple[np.ndarray, FloatArray]:
    """(t, weights): every pattern with its probability (``count`` = 0), or ``count`` sampled ones (weights 1/count)."""
    edges = list(arr.edges)
    q = np.asarray(arr.q, dtype=float)
    if count == 0:
        ev = _relevant_events(edges, T)
        m = len(ev)
        bits = ((np.arange(1 << m)[:, None] >> np.arange(m)[None, :]) & 1).astype(bool)  # 1: delivered
        lost = np.ones((1 << m, T, len(edges)), dtype=bool)
        w = np.ones(1 << m)
        for c, (k, e) in enumerate(ev):
            lost[:, k, e] = ~bits[:, c]
            w *= np.where(bits[:, c], q[e], 1.0 - q[e])
        return flood_arrivals(edges, lost, n, T), w
    lost = rng.random((count, T, len(edges))) >= q[None, None, :]
    return flood_arrivals(edges, lost, n, T), np.full(count, 1.0 / count)


def design_rulefill(
    system: Any,
    cost: Any,
    graph: Any,
    T: int,
    p: Any,
    J: Any,
    arr: ArrivalModel,
    *,
    patterns: int | None = None,
    keyed: int = 0,
    memory: int | None = None,
    window: int | None = None,
    rng: Any = 0,
) -> RuleFillDesign:
    """``design_mtmse_lossy(..., fill="held")`` (module docstring): exact over every pattern when there are at most
    :data:`EXACT_LIMIT`, else fitted on ``patterns`` sampled patterns and costed on as many fresh ones."""
    from .registry import get_family
    from .team_lossy import design_mtmse_lossy

    if keyed or memory is not None:
        raise ArgumentError(f"fill: 'held' has no keyed or memory variant, found keyed = {keyed}, memory = {memory}; drop them", argument="fill")
    patterns = None if patterns is None else V.integer(patterns, "patterns", minimum=2)
    if (isinstance(J, dict) and any(J.values())) or (not isinstance(J, dict) and J):
        raise ArgumentError(f"fill: 'held' supports links without jitter, found jitter = {J}; use fill = true or jitter = 0", argument="fill")
    n = system.n_agents
    nominal = get_family("mtmse").build(system, cost, graph=graph, structure=graph, horizon=T)
    today = design_mtmse_lossy(system, cost, graph, T, p_drop=p, items="measurements", bound=False)
    W = int(arr.ell.max()) + 2 if window is None else V.integer(window, "held_window", minimum=1)
    Syy, Sxy, Px = _joint(system, T)
    d0 = RuleFillDesign(
        estimator="mtmse_lossy",
        horizon=T,
        system=system,
        cost=cost,
        stage_costs=np.zeros(T),
        graph=graph,
        p_drop=p,
        window=W,
        nominal=nominal,
        today=today,
        G=np.zeros((T, n, cost.dz, 2 * system.dx + 2 * cost.dz + W * system.dy_total)),
    )
    d0._cache.update({"Syy": Syy, "Sxy": Sxy, "Px": Px})
    gen = np.random.default_rng(rng)
    m = len(_relevant_events(list(arr.edges), T))
    exact = patterns is None and (1 << m) <= EXACT_LIMIT if m < 60 else False
    members = _members(d0)
    if exact:
        t, w = _patterns(arr, T, n, count=0, rng=gen)
        Gc = _fit(d0, t, w)
        cand = {"class": Gc, **members}
        costs = pattern_costs(d0, t, list(cand.values()))  # (C, P, T)
        stage = {c: np.einsum("p,pk->k", w, costs[a]) for a, c in enumerate(cand)}
        sem = {c: 0.0 for c in cand}
        paired: dict[str, Any] = {}
        count = int(t.shape[0])
    else:
        count = DEFAULT_PATTERNS if patterns is None else int(patterns)
        t_fit, w_fit = _patterns(arr, T, n, count=count, rng=gen)
        Gc = _fit(d0, t_fit, w_fit)
        cand = {"class": Gc, **members}
        t_new, _ = _patterns(arr, T, n, count=count, rng=gen)  # fresh: the reported cost is unbiased
        costs = pattern_costs(d0, t_new, list(cand.values()))
        tot = costs.sum(axis=2)  # (C, P)
        stage = {c: costs[a].mean(axis=0) for a, c in enumerate(cand)}
        sem = {c: float(tot[a].std(ddof=1) / np.sqrt(count)) for a, c in enumerate(cand)}
        paired = {
            c: {"diff": float((tot[0] - tot[a]).mean()), "sem": float((tot[0] - tot[a]).std(ddof=1) / np.sqrt(count))}
            for a, c in enumerate(cand)
            if a
        }
    totals = {c: float(np.sum(stage[c])) for c in cand}
    kept = min(_CANDIDATES, key=lambda c: totals[c])  # never worse than the rule, today's class or the local filters
    value = totals[kept]
    info = {
        "p_drop": p,
        "jitter": 0,
        "fill": "held",
        "exact": bool(exact),
        "patterns": count,
        "sem": sem[kept],
        "interval": [value - 1.96 * sem[kept], value + 1.96 * sem[kept]],
        "member_costs": {c: {"cost": totals[c], "sem": sem[c]} for c in cand},
        "paired": paired,
        "kept": kept,
        "local_kf_cost": totals["local"],
        "rule_cost": totals["rule"],
        "today_cost": totals["today"],
        "window": W,
    }
    lb = np.minimum(np.asarray(nominal.stage_costs, dtype=float), stage[kept])
    info["lower_bound"] = float(np.sum(lb))
    return RuleFillDesign(
        estimator="mtmse_lossy",
        horizon=T,
        system=system,
        cost=cost,
        stage_costs=np.asarray(stage[kept], dtype=float),
        info=info,
        graph=graph,
        p_drop=p,
        window=W,
        nominal=nominal,
        today=today,
        G=cand[kept],
        kept=kept,
        _cache=d0._cache,
    )


from .team_lossy import register_held  # noqa: E402  (this module extends team_lossy, which never imports it)

register_held(design_rulefill)
