r"""The known-pattern optimum: a lower bound of the expected team cost over lossy links.

A team whose agents are told every link event (which packet was lost, how late each one was)
holds, at step k, a set of measurements fixed by the realized pattern ω. Given ω the problem is a
static Gaussian team problem per step (Theorem 1 with the agents' held measurement sets): agent i's
best estimate is linear in what it holds, and the optimum J_k*(ω) solves the Radner conditions

.. math::  \sum_l S_{il}\,\big(L_l\,\mathrm{cov}(x(k), Y_i) - G_l\,\mathrm{cov}(Y_l, Y_i)\big) = 0 .

The link events are independent of the noises, so no strategy that uses less knowledge of ω (the
drop-aware design, the missed-packet rule, the local filters) can cost less than

.. math::  J^{kp} = \sum_k E_\omega\big[J_k^*(\omega)\big],

computed exactly by enumerating the patterns of a tiny team, and by Monte Carlo over sampled
patterns elsewhere (each sample exact given its pattern; the interval is the sampling interval).

What an agent holds under a pattern depends on what the packets carry (``relay``):

* ``"flood"``: every agent forwards each raw measurement once, when it first learns it (the
  drop-aware design's relays with ``items="measurements"``): the known-pattern optimum of that class.
* ``"all"``: a packet carries everything its sender holds (own measurements and everything received):
  the most any protocol can deliver over these links, so a bound for every design (re-sends,
  summaries, innovations). The held sets are prefixes y_j(0 : h_ji(k)).

What an agent is told of the pattern (``knowledge``):

* ``"every"``: every link event, the others' arrivals of the current step included (the bound above);
* ``"causal"``: the events due before step k, and its own arrivals of step k (the bits b_i of the
  packets due at k on its in-edges), nothing of the others' arrivals of step k. No protocol can tell
  an agent more by step k: what reaches it was sent before k, by agents that knew at most the events
  due by then. So this is still a lower bound for every design over the same relays, and a tighter one.
  Given the earlier events (common to all), the bits of different agents are independent (disjoint
  in-edges) and independent of the noises; linear strategies in the held data, one per (i, b_i), that
  satisfy the Radner conditions averaged over the others' bits are team-optimal,

  .. math::  \sum_l S_{il} \big(L_l\, \mathrm{cov}(x(k), Y_i^{b_i})
             - \sum_{b_l} \pi_l(b_l)^{[l \ne i]}\, G_l^{b_l}\, \mathrm{cov}(Y_l^{b_l}, Y_i^{b_i})\big) = 0,

  (for l = i, only b_l = b_i, weight 1): one symmetric positive semidefinite system over the pairs (i, b_i) per step
  and pattern of the earlier events. No jitter (a late packet's fate is not one bit at its due step).

Computation. Data that every agent holds, Y(0:m) for the largest such m, is common: conditioning on
it (the centralized Kalman filter's P(m+1|m)) leaves a static team problem on the residuals of the
window y(m+1 : k) only (exact: a linear strategy splits into a function of the common data, best
taken as L_i E[x|Y(0:m)], and one of the independent residuals). ``window = W`` gives every agent all
data older than k - W as well (a more informed team: still a lower bound, looser, and converging to
the exact one as W grows; it bounds the work of teams where little is common).
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import product
from typing import Any

import numpy as np

from .. import _validation as V
from .._lazy import scipy_linalg as sla
from .._validation import FloatArray
from ..exceptions import ArgumentError, ResourceError

__all__ = [
    "KnownPatternBound",
    "known_pattern_bound",
    "known_pattern_stats",
    "KnownRequest",
    "check_knowledge",
    "relay_of",
    "EXACT_LIMIT",
    "MAX_UNKNOWNS",
]

#: patterns enumerated exactly when there are at most this many (else Monte Carlo)
EXACT_LIMIT = 4096
#: at most this many unknowns in one step's static team problem (else: a window, or relay="all")
MAX_UNKNOWNS = 4000


@dataclass(frozen=True)
class KnownPatternBound:
    """The known-pattern optimum J^kp (module docstring).

    value : float              exact (enumeration) or the Monte Carlo mean over sampled patterns
    stages : (T,) array        per-step parts of ``value``
    sem : float                standard error of ``value`` (0 when exact)
    n_patterns : int           patterns enumerated or sampled
    exact : bool               every pattern enumerated
    relay : str                "flood", "ontime" or "all"
    window : int or None       data older than k - window given to every agent (None: exact)
    knowledge : str            "every": every agent told every link event; "causal": the events due before
                               the step and its own arrivals of the step (module docstring)
    resend : int               with relay "flood" or "ontime": the sender's last measurements each packet carries
    """

    value: float
    stages: FloatArray
    sem: float
    n_patterns: int
    exact: bool
    relay: str
    window: int | None
    knowledge: str = "every"
    resend: int = 1

    @property
    def interval(self) -> tuple[float, float]:
        """95 % interval (value ± 1.96 sem; a point when exact)."""
        return (self.value - 1.96 * self.sem, self.value + 1.96 * self.sem)

    def as_dict(self) -> dict[str, Any]:
        lo, hi = self.interval
        return {
            "value": self.value,
            "sem": self.sem,
            "interval": [lo, hi],
            "n_patterns": self.n_patterns,
            "exact": self.exact,
            "relay": self.relay,
            "window": self.window,
            "knowledge": self.knowledge,
            "resend": self.resend,
        }


# ---------------------------------------------------------------------------
# link patterns: delay[t, e] = the delay of the packet sent on edge e at step t, or -1 (lost)
# ---------------------------------------------------------------------------
def _edge_params(graph: Any, p_drop: Any, jitter: Any) -> tuple[list[tuple[int, int, int]], np.ndarray, np.ndarray]:
    edges = sorted((int(a), int(b), int(d)) for (a, b, d) in graph.edges)

    def per_edge(x: Any, e: tuple[int, int]) -> float:
        return float(x.get(e, 0.0)) if isinstance(x, dict) else float(x)

    p = np.array([per_edge(p_drop, (a, b)) for (a, b, _) in edges])
    J = np.array([int(per_edge(jitter, (a, b))) for (a, b, _) in edges])
    return edges, p, J


def _enumerate(edges: list[tuple[int, int, int]], p: np.ndarray, J: np.ndarray, T: int) -> list[tuple[np.ndarray, float]] | None:
    """Every pattern of the packets that can arrive within the horizon with its probability, or None if too many."""
    events = [(t, e) for e, (_, _, d) in enumerate(edges) for t in range(T) if t + d <= T - 1]
    outcomes = []
    count = 1
    for t, e in events:
        d = edges[e][2]
        opts = [(-1, p[e])] if p[e] > 0 else []
        if p[e] < 1:
            late = [d + x for x in range(int(J[e]) + 1)]
            inside = [dl for dl in late if t + dl <= T - 1]
            share = (1.0 - p[e]) / (J[e] + 1)
            opts += [(dl, share) for dl in inside]
            if len(inside) < len(late):  # arrives after the horizon: the same as lost
                opts.append((-1, share * (len(late) - len(inside))))
        outcomes.append(opts)
        count *= len(opts)
        if count > EXACT_LIMIT:
            return None
    out = []
    for combo in product(*outcomes):
        delay = np.full((T, len(edges)), -1, dtype=int)
        prob = 1.0
        for (t, e), (dl, pr) in zip(events, combo):
            delay[t, e] = dl
            prob *= pr
        out.append((delay, prob))
    return out


def _sample(edges: list[tuple[int, int, int]], p: np.ndarray, J: np.ndarray, T: int, rng: np.random.Generator) -> np.ndarray:
    lost = rng.random((T, len(edges))) < p
    extra = np.floor(rng.random((T, len(edges))) * (J + 1)).astype(int)
    base = np.array([d for (_, _, d) in edges], dtype=int)
    return np.where(lost, -1, base + extra)  # type: ignore[no-any-return]


def held_sets(delay: np.ndarray, edges: list[tuple[int, int, int]], n: int, T: int, relay: str, resend: int = 1) -> np.ndarray:
    """held[k, j, s, i]: agent i holds y_j(s) at step k under the pattern ``delay`` (s <= k).

    ``resend = r`` (relay "flood"): the packet of (j, τ) carries y_j(τ - r + 1 : τ) and is flooded once, so
    y_j(s) is held from the first arrival of a packet τ ∈ [s, s + r - 1]."""
    steps = np.arange(T)
    if relay == "all":
        h = np.full((T, n, n), -1, dtype=int)  # h[t, j, i]: i holds y_j(0 : h) after step t's arrivals
        t0s, es = np.nonzero(delay >= 0)
        due = t0s + delay[t0s, es]
        for t in range(T):
            cur = h[t - 1].copy() if t else np.full((n, n), -1, dtype=int)
            cur[np.arange(n), np.arange(n)] = t
            for t0, e in zip(t0s[due == t].tolist(), es[due == t].tolist()):  # a packet sent at t0 carries what its sender held
                a, b = edges[e][0], edges[e][1]
                cur[:, b] = np.maximum(cur[:, b], h[t0][:, a])
            h[t] = cur
        return steps[None, None, :, None] <= h[:, :, None, :]  # type: ignore[no-any-return]
    big = 10 * T + 10
    learn = np.full((n, T, n), big, dtype=int)  # learn[j, s, u]: when u first holds y_j(s)
    for j in range(n):
        learn[j, :, j] = steps
    for t in range(T):
        for e, (a, b, _) in enumerate(edges):
            dl = delay[t, e]
            if dl < 0:
                continue
            now = learn[:, :, a] == t  # forwarded once, at the step it was learned
            learn[:, :, b] = np.where(now, np.minimum(learn[:, :, b], t + dl), learn[:, :, b])
    if relay == "ontime":  # only packets on time (at τ + ℓ_ju, ℓ the geodesic delay) are held: the drop-aware design's use
        ell = np.full((n, n), big, dtype=int)
        np.fill_diagonal(ell, 0)
        for _ in range(n):
            for a, b, d in edges:
                ell[:, b] = np.minimum(ell[:, b], ell[:, a] + d)
        due = steps[None, :, None] + ell[:, None, :]
        learn = np.where(learn == due, learn, big)
    first = learn.copy()  # first[j, τ, u]: when u first holds the packet of (j, τ)
    for t in range(1, min(resend, T)):  # the packet of (j, s + t) also carries y_j(s)
        learn[:, : T - t] = np.minimum(learn[:, : T - t], first[:, t:])
    return learn[None, :, :, :] <= steps[:, None, None, None]  # type: ignore[no-any-return]


# ---------------------------------------------------------------------------
# the static team problem of one step given the held sets
# ---------------------------------------------------------------------------
class _Windows:
    """Moments of the window y(m+1 : k) given Y(0:m) (centralized Kalman filter), cached by (m, k)."""

    def __init__(self, system: Any, T: int):
        self.system, self.T = system, T
        dx = system.dx
        self.Pp = []  # P(t | t-1), t = 0..T-1
        P = np.array(system.Sigma_x, dtype=float)
        for t in range(T):
            self.Pp.append(P)
            C, R = system.C_stack(t), system.R_stack(t)
            if C.size:
                Sy = C @ P @ C.T + R
                K = sla.solve(Sy, C @ P, assume_a="pos").T
                Pf = (np.eye(dx) - K @ C) @ P
            else:
                Pf = P
            P = system.A_at(t) @ Pf @ system.A_at(t).T + system.Q_at(t)
            P = 0.5 * (P + P.T)
        self.cache: dict[tuple[int, int], tuple[FloatArray, FloatArray, FloatArray]] = {}
        self.stage_cache: dict[tuple[int, int, bytes], float] = {}
        self.causal_cache: dict[tuple[Any, ...], float] = {}

    def get(self, m: int, k: int) -> tuple[FloatArray, FloatArray, FloatArray]:
        """(Cyy, Cxy, Pk): cov of the residuals ỹ(m+1:k), cov(x̃(k), ỹ), cov(x̃(k)) given Y(0:m)."""
        key = (m, k)
        if key in self.cache:
            return self.cache[key]
        sysm, dx, dyt = self.system, self.system.dx, self.system.dy_total
        steps = list(range(m + 1, k + 1))
        P = [self.Pp[m + 1]]
        for s in steps[:-1]:
            Pn = sysm.A_at(s) @ P[-1] @ sysm.A_at(s).T + sysm.Q_at(s)
            P.append(0.5 * (Pn + Pn.T))
        W = len(steps)
        # Phi[a][b] = transition from steps[b] to steps[a] (a >= b)
        Phi = [[np.eye(dx)] * W for _ in range(W)]
        for b in range(W):
            M = np.eye(dx)
            for a in range(b, W):
                Phi[a][b] = M
                M = sysm.A_at(steps[a]) @ M
        Cyy = np.zeros((W * dyt, W * dyt))
        Cxy = np.zeros((dx, W * dyt))
        for a in range(W):
            Ca = sysm.C_stack(steps[a])
            for b in range(a + 1):
                Cb = sysm.C_stack(steps[b])
                blk = Ca @ Phi[a][b] @ P[b] @ Cb.T
                if a == b:
                    blk = blk + sysm.R_stack(steps[a])
                Cyy[a * dyt : (a + 1) * dyt, b * dyt : (b + 1) * dyt] = blk
                Cyy[b * dyt : (b + 1) * dyt, a * dyt : (a + 1) * dyt] = blk.T
            Cxy[:, a * dyt : (a + 1) * dyt] = Phi[W - 1][a] @ P[a] @ Ca.T
        out = (Cyy, Cxy, P[-1])
        if len(self.cache) < 4 * self.T * self.T:
            self.cache[key] = out
        return out


def _last_common(common: np.ndarray, k: int, window: int | None) -> int:
    """m: y(0:m) is held by every agent (``common[s]``), or given to every agent as older than k - window."""
    m = int(np.argmin(common)) - 1 if not common.all() else k
    return m if window is None else max(m, k - window - 1)


def _memo(cache: dict[Any, float], key: Any, solve: Any) -> float:
    """``cache[key]``, computed by ``solve()`` the first time (the cache is bounded)."""
    hit = cache.get(key)
    if hit is None:
        hit = solve()
        if len(cache) < 200_000:
            cache[key] = hit
    return hit


def _held_rows(sysm: Any, h: np.ndarray, m: int, k: int) -> list[int]:
    """Rows of the window y(m+1 : k) that an agent holding h[j, s] holds."""
    n, dyt, off = sysm.n_agents, sysm.dy_total, sysm.offsets
    return [(s - m - 1) * dyt + int(off[j]) + r for s in range(m + 1, k + 1) for j in range(n) if h[j, s] for r in range(sysm.dy[j])]


def _stage_optimum(win: _Windows, cost: Any, held_k: np.ndarray, k: int, window: int | None) -> float:
    """J_k* given the held sets of step k (held_k[j, s, i])."""
    m = _last_common(np.all(held_k[:, : k + 1, :], axis=(0, 2)), k, window)  # y(s) held by every agent
    key = (k, m, held_k[:, m + 1 : k + 1, :].tobytes())  # the optimum depends on the window's held sets only
    return _memo(win.stage_cache, key, lambda: _solve_stage(win, cost, held_k, k, m))


def _solve_stage(win: _Windows, cost: Any, held_k: np.ndarray, k: int, m: int) -> float:
    sysm = win.system
    n, dz = sysm.n_agents, cost.dz
    S, L = cost.S_at(k), cost.L_at(k)
    if m == k:  # everything is common: the centralized estimate, cost Tr(S L P(k|k) Lᵀ)
        C, R = sysm.C_stack(k), sysm.R_stack(k)
        P = win.Pp[k]
        Pk = P - P @ C.T @ sla.solve(C @ P @ C.T + R, C @ P, assume_a="pos") if C.size else P
        return float(np.trace(S @ L @ Pk @ L.T))
    Cyy, Cxy, Pk = win.get(m, k)
    zi, yr = [], []
    for i in range(n):
        rows = _held_rows(sysm, held_k[:, :, i], m, k)
        for c in range(dz):
            zi += [i * dz + c] * len(rows)
            yr += rows
    zi_a, yr_a = np.asarray(zi, dtype=int), np.asarray(yr, dtype=int)
    if zi_a.size > MAX_UNKNOWNS:
        raise ResourceError(
            f"window: the known-pattern bound's step {k} has {zi_a.size} unknowns (at most {MAX_UNKNOWNS}); "
            "give window = W (data older than k - W given to every agent: a looser bound) or relay = 'all'",
            argument="window",
        )
    c0 = float(np.trace(S @ L @ Pk @ L.T))
    if not zi_a.size:
        return c0
    Gam = S[np.ix_(zi_a, zi_a)] * Cyy[np.ix_(yr_a, yr_a)]
    eta = (S @ L @ Cxy)[zi_a, yr_a]
    try:
        g = sla.cho_solve(sla.cho_factor(Gam, lower=True, check_finite=False), eta, check_finite=False)
    except np.linalg.LinAlgError:  # a singular R: the least-squares solution
        g = np.linalg.lstsq(Gam, eta, rcond=None)[0]
    return c0 - float(g @ eta)


# ---------------------------------------------------------------------------
# the causal-knowledge bound: this step's arrivals known only to their receivers
# ---------------------------------------------------------------------------
def _private_configs(
    delay: np.ndarray, edges: list[tuple[int, int, int]], p: np.ndarray, n: int, k: int, relay: str, resend: int
) -> list[list[tuple[np.ndarray, float]]]:
    """Per agent i, its private configurations at step k: [(held_i[j, s] for s <= k, probability), ...].

    The events of the packets due at step k (sent at k - d_e on an in-edge e of i) are i's private bits;
    every other event of the pattern (those due before k) is given to every agent. Under the flooding or
    "all" relays what i holds at k is what it held at k - 1 and the contents of the packets arriving at k,
    so its held set depends on its own bits only."""
    pre = delay[: k + 1].copy()
    due = [(k - d, e) for e, (_, _, d) in enumerate(edges) if k - d >= 0]
    for t, e in due:
        pre[t, e] = -1
    base = held_sets(pre, edges, n, k + 1, relay, resend)[k]
    gain: dict[int, np.ndarray] = {}
    for t, e in due:
        one = pre.copy()
        one[t, e] = edges[e][2]
        gain[e] = held_sets(one, edges, n, k + 1, relay, resend)[k]
    out = []
    for i in range(n):
        mine = [e for (_, e) in due if edges[e][1] == i]
        configs = []
        for bits in product((0, 1), repeat=len(mine)):
            prob = float(np.prod([p[e] if b == 0 else 1.0 - p[e] for e, b in zip(mine, bits)]))
            if prob <= 0.0:
                continue
            h = base[:, :, i].copy()
            for e, b in zip(mine, bits):
                if b:
                    h |= gain[e][:, :, i]
            configs.append((h, prob))
        out.append(configs)
    return out


def _solve_stage_causal(win: _Windows, cost: Any, configs: list[list[tuple[np.ndarray, float]]], k: int, window: int | None) -> float:
    r"""J_k* when agent i knows the events due before k and its own arrivals at k (bits b_i, law π_i).

    The others' bits are independent of i's and of the noises, so the Radner conditions read, for every
    (i, b_i): Σ_l S_il (L_l cov(x, Y_i^{b_i}) - Σ_{b_l} π_l(b_l) G_l^{b_l} cov(Y_l^{b_l}, Y_i^{b_i})) = 0 for
    l ≠ i, with G_i^{b_i} itself for l = i: one symmetric system over the pairs (i, b_i) (each row weighted by
    π_i(b_i)), whose solution is optimal among all strategies (the cost is convex and linear strategies in
    the data for each b_i satisfy the conditions)."""
    n = win.system.n_agents
    common = np.ones(k + 1, dtype=bool)
    for i in range(n):
        for h, _ in configs[i]:
            common &= h.all(axis=0)
    m = _last_common(common, k, window)
    if m == k:
        return _solve_stage(win, cost, np.ones((n, k + 1, n), dtype=bool), k, k)
    key = (k, m, tuple((i, h[:, m + 1 :].tobytes(), prob) for i in range(n) for h, prob in configs[i]))
    return _memo(win.causal_cache, key, lambda: _solve_causal(win, cost, configs, k, m))


def _solve_causal(win: _Windows, cost: Any, configs: list[list[tuple[np.ndarray, float]]], k: int, m: int) -> float:
    sysm = win.system
    n, dz = sysm.n_agents, cost.dz
    S, L = cost.S_at(k), cost.L_at(k)
    Cyy, Cxy, Pk = win.get(m, k)
    SLC = S @ L @ Cxy
    blocks = []  # (agent, prob, z rows, y rows)
    for i in range(n):
        for h, prob in configs[i]:
            rows = _held_rows(sysm, h, m, k)
            zi = np.repeat(np.arange(i * dz, (i + 1) * dz), len(rows))
            yr = np.tile(np.asarray(rows, dtype=int), dz)
            blocks.append((i, prob, zi, yr))
    size = sum(b[2].size for b in blocks)
    if size > MAX_UNKNOWNS:
        raise ResourceError(
            f"window: the causal-knowledge bound's step {k} has {size} unknowns (at most {MAX_UNKNOWNS}); "
            "give a smaller window = W (data older than k - W given to every agent: a looser bound)",
            argument="window",
        )
    c0 = float(np.trace(S @ L @ Pk @ L.T))
    if not size:
        return c0
    Gam = np.zeros((size, size))
    eta = np.zeros(size)
    starts = np.cumsum([0] + [b[2].size for b in blocks])
    for a, (i, pa, za, ya) in enumerate(blocks):
        eta[starts[a] : starts[a + 1]] = pa * SLC[za, ya]
        for b, (j, pb, zb, yb) in enumerate(blocks):
            if j == i and a != b:
                continue  # one agent is in one configuration at a time
            w = pa if a == b else pa * pb
            Gam[starts[a] : starts[a + 1], starts[b] : starts[b + 1]] = w * S[np.ix_(za, zb)] * Cyy[np.ix_(ya, yb)]
    try:
        g = sla.cho_solve(sla.cho_factor(Gam, lower=True, check_finite=False), eta, check_finite=False)
    except np.linalg.LinAlgError:
        g = np.linalg.lstsq(Gam, eta, rcond=None)[0]
    return c0 - float(g @ eta)


def known_pattern_stats(
    system: Any,
    cost: Any,
    graph: Any,
    T: int,
    p_drop: Any,
    jitter: Any = 0,
    *,
    relay: str = "flood",
    window: int | None = None,
    n_patterns: int | None = None,
    rng: Any = None,
    exact_first: bool = False,
    resend: int = 1,
    knowledge: str = "every",
) -> KnownPatternBound:
    """The known-pattern optimum (validated arguments; :func:`teamkf.estimators.team_lossy.known_pattern_bound`).

    ``exact_first``: enumerate when the patterns are few enough even when ``n_patterns`` is given.
    """
    n = system.n_agents
    edges, p, J = _edge_params(graph, p_drop, jitter)
    win = _Windows(system, T)

    def stages_of(delay: np.ndarray) -> list[float]:
        if knowledge == "causal":
            return [_solve_stage_causal(win, cost, _private_configs(delay, edges, p, n, k, relay, resend), k, window) for k in range(T)]
        held = held_sets(delay, edges, n, T, relay, resend)
        return [_stage_optimum(win, cost, held[k], k, window) for k in range(T)]

    pats = _enumerate(edges, p, J, T) if n_patterns is None or exact_first else None
    if pats is not None:
        stages = np.zeros(T)
        for delay, prob in pats:
            stages += prob * np.array(stages_of(delay))
        return KnownPatternBound(float(stages.sum()), stages, 0.0, len(pats), True, relay, window, knowledge, resend)
    R = 200 if n_patterns is None else n_patterns
    gen = np.random.default_rng(rng)
    per = np.zeros((R, T))
    for r in range(R):
        per[r] = stages_of(_sample(edges, p, J, T, gen))
    tot = per.sum(axis=1)
    sem = float(tot.std(ddof=1) / np.sqrt(R)) if R > 1 else float("inf")
    return KnownPatternBound(float(tot.mean()), per.mean(axis=0), sem, R, False, relay, window, knowledge, resend)


def known_pattern_bound(
    system: Any,
    cost: Any,
    graph: Any,
    horizon: int,
    p_drop: Any,
    jitter: Any = 0,
    *,
    relay: str = "flood",
    window: int | None = None,
    n_patterns: int | None = None,
    rng: Any = None,
    resend: int = 1,
    knowledge: str = "every",
) -> KnownPatternBound:
    """The known-pattern optimum: the expected team cost of a team told every link event (a lower bound).

    Parameters
    ----------
    system, cost, graph : the model, the team cost and the links (delays)
    horizon : int
        T.
    p_drop, jitter : number or {(source, target): value}
        The link model (a packet is lost with probability p, else late by 0..J steps, uniformly).
    relay : "flood", "ontime" or "all"
        What packets carry: every raw measurement once, when first learned (the drop-aware design's relays
        with ``items="measurements"``; "ontime": only what arrives on time is held, as the drop-aware design
        uses it), or everything the sender holds (a bound for every protocol).
    window : int or None
        Give every agent the data older than k - window (a looser bound that bounds the work); None: exact.
    n_patterns : int or None
        Monte Carlo over this many sampled patterns; None: every pattern when there are at most
        :data:`EXACT_LIMIT`, else 200 sampled ones.
    rng : seed or Generator for the sampled patterns
    resend : int
        With relay "flood": each packet carries the sender's last ``resend`` measurements (``mtmse_lossy``'s
        ``resend = r``), each packet flooded once.
    knowledge : "every" or "causal"
        What each agent is told of the link events: every one ("every"), or only those due before the step and
        its own arrivals of the step ("causal": all that any protocol can tell it, so a tighter bound, still
        below every design; no jitter).

    Returns
    -------
    KnownPatternBound
        ``value`` (exact, or the Monte Carlo mean with ``sem`` and ``interval``), per-step ``stages``.

    Examples
    --------
    >>> from teamkf import CommGraph, LinearGaussianSystem, TeamCost
    >>> b = known_pattern_bound(LinearGaussianSystem.platoon(2), TeamCost.platoon(2, 10.0), CommGraph.line(2), 3, 0.5)
    >>> b.exact, b.n_patterns
    (True, 16)
    >>> c = known_pattern_bound(LinearGaussianSystem.platoon(2), TeamCost.platoon(2, 10.0), CommGraph.line(2), 3, 0.5, knowledge="causal")
    >>> bool(c.value > b.value)  # told less: the others' arrivals of each step are unknown
    True
    """
    from .checks import check_graph, check_model

    check_model(system, cost)
    check_graph(graph, system.n_agents)
    T = V.positive_int(horizon, "horizon")
    system.require_horizon(T)
    cost.require_horizon(T)
    relay = V.choice(relay, "relay", ("flood", "all", "ontime"))
    window = None if window is None else V.integer(window, "window", minimum=0)
    n_patterns = None if n_patterns is None else V.positive_int(n_patterns, "n_patterns")
    for name, x in (("p_drop", p_drop), ("jitter", jitter)):
        vals = x.items() if isinstance(x, dict) else [(None, x)]
        for e, v in vals:
            label = name if e is None else f"{name}[{list(e)}]"
            if isinstance(e, tuple) and e not in {(int(a), int(b)) for (a, b, _) in graph.edges}:
                raise ArgumentError(f"{label}: expected an edge of the graph, found {e!r}", argument=name)
            if name == "p_drop":
                V.probability(v, label)
            else:
                V.integer(v, label, minimum=0)
    graph.require_strongly_connected()
    resend = V.integer(resend, "resend", minimum=1)
    knowledge = check_knowledge(knowledge, jitter, "knowledge")
    return known_pattern_stats(
        system, cost, graph, T, p_drop, jitter, relay=relay, window=window, n_patterns=n_patterns, rng=rng, resend=resend, knowledge=knowledge
    )


# ---------------------------------------------------------------------------
# the bound a drop-aware design reports (known_bound, known_window, known_knowledge)
# ---------------------------------------------------------------------------
def check_knowledge(knowledge: Any, J: Any, name: str = "known_knowledge") -> str:
    """``knowledge`` (the argument ``name``), checked before any work: "every", or "causal" on links without jitter."""
    knowledge = V.choice(knowledge, name, ("every", "causal"))
    if knowledge == "causal" and any(v for v in (J.values() if isinstance(J, dict) else [J])):
        raise ArgumentError(
            f"{name}: 'causal' is for links without jitter (a late packet's fate is not one bit), found jitter = {J!r}; "
            f"give jitter = 0 or {name} = 'every'",
            argument=name,
        )
    return knowledge


def relay_of(coords: str, resend: int = 1) -> tuple[str, int]:
    """The relays of the known-pattern optimum of a design on ``coords`` items: raw measurements flooded as the design
    floods them (its own protocol), else everything held (innovations are not raw data: a bound for every protocol)."""
    return ("flood", resend) if coords == "measurements" else ("all", 1)


@dataclass(frozen=True)
class KnownRequest:
    """The known-pattern bound a drop-aware design was asked to report (``known_bound``, ``known_window``,
    ``known_knowledge``), checked before any work, with the problem it is for; :meth:`attach` computes it."""

    system: Any
    cost: Any
    graph: Any
    T: int
    p: Any
    J: Any
    n_patterns: int  # 0: not asked for
    window: int
    knowledge: str

    @classmethod
    def build(
        cls, system: Any, cost: Any, graph: Any, T: int, p: Any, J: Any, arr: Any, known_bound: Any, known_window: Any, knowledge: Any
    ) -> KnownRequest:
        """Validated options; the window defaults to the largest geodesic delay + 4."""
        nkb = V.integer(known_bound, "known_bound", minimum=0)
        W = int(arr.ell.max()) + 4 if known_window is None else V.integer(known_window, "known_window", minimum=0)
        return cls(system, cost, graph, T, p, J, nkb, W, check_knowledge(knowledge, J))

    def attach(self, d: Any, relay: str, resend: int = 1) -> Any:
        """``d`` with the known-pattern optimum of ``relay`` (and ``resend``) and its gap in ``info`` (nothing asked: ``d``)."""
        if self.n_patterns:
            kb = known_pattern_stats(
                self.system,
                self.cost,
                self.graph,
                self.T,
                self.p,
                self.J,
                relay=relay,
                window=self.window,
                n_patterns=self.n_patterns,
                rng=0,
                exact_first=True,
                resend=resend,
                knowledge=self.knowledge,
            )
            d.info["known_pattern_bound"] = kb.as_dict()
            d.info["known_pattern_gap"] = (d.total_cost - kb.value) / kb.value
        return d
