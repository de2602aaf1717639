r"""The lossy runtime batched over runs: link events as arrays, relays and packet agents vectorized.

:func:`teamkf.simulation.links.pass_messages_lossy` runs here. Its three stages:

1. **Link events, all runs at once** (:func:`draw_link_events`). Run r draws, from its own stream
   (:func:`~teamkf.simulation.links.link_streams`), one uniform u_e(k) (drop) and one uniform
   j_e(k) (jitter) per edge e and step k, whatever happens — the same numbers, in the same order,
   as the one-run-at-a-time loop of teamkf 0.2, so a seed gives the same drops as before. From them
   (:func:`link_outcomes`) the packet sent on e = (a → b, τ_e) at step k

   .. math::  \text{is lost} \iff k \in \text{an outage of } e \ \lor\ u_e(k) < p_e,
              \qquad \text{else arrives at } k + τ_e + \lfloor j_e(k) (J_e + 1) \rfloor,

   and nothing is sent by an agent from its failure step on. Per-edge counts are sums of these
   arrays.

2. **Relays** (packet agents behind :class:`~teamkf.estimators.base.MeasurementRelay`: MTMSE,
   MMSE, the own-window designs). A relay forwards, at the step it first learns them, the
   measurements it had never seen, so what reaches agent i depends only on the link events: the
   first time t_i(j, s) at which agent i holds y_j(s) obeys

   .. math::  t_i(i, s) = s, \qquad t_i(j, s) = \min_{m \to i \text{ delivers at } t_m(j, s)}
              \big(t_m(j, s) + τ_{mi} + \text{extra}_{mi}(t_m(j, s))\big),

   computed for every run as integer arrays (:func:`relay_arrivals`), step by step (an arrival is
   always later than its sending step, τ >= 1). A packet crosses each node at most once, so
   t_i(j, s) - s <= (n - 1)(τ_max + J_max) when it is finite: only that many steps are scanned.

3. **The missed-packet rule, for all runs at once** (:class:`_TeamStep`). The MTMSE/MMSE agent
   i holds at step k the window measurements H = {(j, s) : a <= s <= k, t_i(j, s) <= k}. A needed
   measurement y_m that is not in H is replaced by its conditional expectation

   .. math::  E[y_m \mid \hat x(a), y_H] = C_m Φ \hat x(a) + Σ_W[m, H] Σ_W[H, H]^{-1} \tilde y_H

   (:meth:`~teamkf.estimators.team.TeamAgent.expected_measurements`, Σ_W under the nominal
   predictor covariance). The agent's whole step — folding y(a0), a0 = k - c, into the common
   predictor with the rule, then its local estimate with the rule — is therefore linear in
   u = [x̂(a0); y(a0 : k) restricted to H]:

   .. math::  [\hat x(a0 + 1);\ z_i(k)] = M_{i,k}(H)\, u .

   The map depends on the run only through (i, H), so the rows (agent, run) are sorted by
   (agent, pattern) at each step, M is built once per pattern (all new patterns of a step and agent
   together: batched solves on the held coordinates, single products with the pattern-independent
   factors; then cached on the design: patterns repeat across blocks), and all rows are
   stepped by one batched matrix product. The estimates are those of the agents' own online step
   to round-off (checked in ``tests/unit/test_lossy_mc.py``), with the same miss counts.

Other families step every run of the block at once too, with each run's own arrivals: KCF, diffusion
(published combination), local, CI, ICF and HCMCI through their algorithm's ``agent_step_runs``
(:mod:`teamkf.estimators._runs`: per-run covariances stacked as (R, d, d), a packet's terms added to
the runs that received it, in the one-run order), CIKF and the drop-aware team filter
(``mtmse_lossy``, whose flooding is stage 2's) here. Their estimates are those of the agents' own
one-run ``step`` bit for bit (``tests/unit/test_lossy_stacked.py``): a stacked product is one BLAS
call per run with the one-run core shapes. Any other tolerant agent (a plug-in, the other
combination rules) runs its own ``step`` one run at a time on the same precomputed link events
(:func:`_run_grouped`). An omniscient design (the
centralized bound) receives every y_j(k) at step k whatever the links do, so it runs as on reliable
links, vectorized.

Each block of runs is computed alone, so the result of a run depends on its block (``batch``) and
not on how blocks are grouped into chunks or on the worker.
"""

from __future__ import annotations

import hashlib
import weakref
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from .._progress import progress
from .._validation import FloatArray
from ..exceptions import TeamkfError
from ..network.graph import CommGraph

__all__ = ["LinkOutcomes", "draw_link_events", "link_outcomes", "relay_arrivals", "count_links", "run_lossy"]


@dataclass(frozen=True)
class LinkOutcomes:
    """What happens to the packet each edge carries at each step, for every run of a block.

    Attributes
    ----------
    edges : list of (source, target, delay), sorted (the order of the link-event draws)
    sent : (T, E) bool       the source sends at that step (not failed, not omniscient)
    lost : (R, T, E) bool    the packet is lost (drop or outage); meaningful where ``sent``
    extra : (R, T, E) int    extra jitter steps of a delivered packet
    arrive : (R, T, E) int   arrival step k + τ_e + extra (>= T: after the horizon)
    """

    edges: list[tuple[int, int, int]]
    sent: np.ndarray
    lost: np.ndarray
    extra: np.ndarray
    arrive: np.ndarray

    @property
    def delivered(self) -> np.ndarray:
        """(R, T, E) bool: sent, not lost and arriving within the horizon."""
        T = self.sent.shape[0]
        return self.sent[None] & ~self.lost & (self.arrive < T)  # type: ignore[no-any-return]


def draw_link_events(streams: Sequence[np.random.SeedSequence], T: int, n_edges: int) -> tuple[FloatArray, FloatArray]:
    """(u, j): the drop and jitter uniforms, each (R, T, E), of every run from its own stream.

    Run r's generator is ``default_rng(streams[r])``; per step it draws E drop uniforms then E
    jitter uniforms (the order of the one-run loop, so the numbers are the same).
    """
    R = len(streams)
    draws = np.empty((R, T, 2, n_edges))
    for r, s in enumerate(streams):
        np.random.default_rng(s).random(out=draws[r].reshape(-1))
    return draws[:, :, 0], draws[:, :, 1]


def link_outcomes(links: Any, edges: Sequence[tuple[int, int, int]], u: FloatArray, jit: FloatArray, omniscient: Sequence[bool]) -> LinkOutcomes:
    """Drops, outages, failures and jitter of every (run, step, edge) (module docstring, stage 1)."""
    R, T, E = u.shape
    steps = np.arange(T)
    sent = np.ones((T, E), dtype=bool)
    down = np.zeros((T, E), dtype=bool)
    p = np.empty(E)
    J = np.empty(E, dtype=np.int64)
    d = np.empty(E, dtype=np.int64)
    for q, (a, b, delay) in enumerate(edges):
        if omniscient[a]:
            sent[:, q] = False
        if a in links.failures:
            sent[steps >= links.failures[a], q] = False
        for a2, b2, f, last in links.outages:
            if (a2, b2) == (a, b):
                down[f : last + 1, q] = True
        p[q], J[q], d[q] = links.p_of((a, b)), links.jitter_of((a, b)), delay
    lost = down[None] | (u < p)
    extra = np.where(J > 0, (jit * (J + 1)).astype(np.int64), 0)
    arrive = steps[None, :, None] + d + extra
    return LinkOutcomes(list(edges), sent, lost, extra, arrive)


def count_links(out: LinkOutcomes, stats: Any) -> None:
    """Add the per-edge counts (sent, delivered on time, late, dropped) of every run to ``stats``."""
    R = out.lost.shape[0]
    for q, (a, b, _) in enumerate(out.edges):
        s = out.sent[:, q]
        n_sent = int(s.sum()) * R
        if not n_sent:
            continue
        lost = out.lost[:, s, q]
        late = (~lost) & (out.extra[:, s, q] > 0)
        n_lost, n_late = int(lost.sum()), int(late.sum())
        stats.add((a, b), "sent", n_sent)
        stats.add((a, b), "dropped", n_lost)
        stats.add((a, b), "late", n_late)
        stats.add((a, b), "delivered", n_sent - n_lost - n_late)


def relay_arrivals(out: LinkOutcomes, n: int, T: int, max_jitter: int) -> np.ndarray:
    """t[r, i, j, s]: the step at which agent i first holds y_j(s) in run r (T: never), stage 2.

    Step by step (every arrival is later than its sending step, so what is learnt at k is final when
    step k is processed); at step k every agent forwards at once what it learnt at k, on all its edges:
    one candidate array per step for all edges, reduced per target edge group by a minimum.
    """
    R = out.lost.shape[0]
    t = np.full((T, n, n, R), T, dtype=np.int32)  # t[s, i, j, r] while computing: a step's window is one slice, runs innermost
    for i in range(n):
        t[:, i, i, :] = np.arange(T)[:, None]
    if out.edges:
        horizon = (n - 1) * (max(d for (_, _, d) in out.edges) + max_jitter)  # a packet's latency when it arrives
        ok = out.delivered.transpose(1, 2, 0)  # (T, E, R)
        arrive = np.ascontiguousarray(np.where(ok, out.arrive.transpose(1, 2, 0), T), dtype=np.int32)  # T: not delivered
        any_ok = np.asarray(ok.any(axis=2))  # (T, E)
        for k in range(T):
            qs = np.flatnonzero(any_ok[k]).tolist()
            if not qs:
                continue
            win = t[max(0, k - horizon) : k + 1]  # (w, n, n, R)
            new = win == k  # what each agent learns at k, and forwards at k on all its edges
            for q in qs:
                a, b, _ = out.edges[q]
                dst = win[:, b]
                np.minimum(dst, arrive[k, q], out=dst, where=new[:, a])
    return t.transpose(3, 1, 2, 0)  # type: ignore[no-any-return]


# ---------------------------------------------------------------------------
# MTMSE / MMSE agents with the missed-packet rule, all runs at once
# ---------------------------------------------------------------------------
_FINGERPRINTS: "weakref.WeakKeyDictionary[Any, bytes]" = weakref.WeakKeyDictionary()
_CACHES: dict[bytes, dict] = {}
_CACHE_MAX = 50_000  # fill gains kept per model (each (targets x window) doubles)
_STEP_SLAB = 8  # rows per slab of a step's batched product (most patterns hold few runs)


def _fingerprint(design: Any) -> bytes:
    """What the fill gains depend on: the model, the predictor covariances and the information structure.

    MTMSE and MMSE designs of one scenario share it (the same Kalman predictor), so they share gains.
    """
    try:
        fp = _FINGERPRINTS.get(design)
    except TypeError:  # pragma: no cover - not weakly referenceable
        fp = None
    if fp is None:
        sys, st = design.system, design.structure
        h = hashlib.sha256()
        for arr in (sys.A, sys.Q, sys.Sigma_x, *sys.C, *sys.R, design.P_pred):
            a = np.ascontiguousarray(arr, dtype=float)
            h.update(repr(a.shape).encode())
            h.update(a.tobytes())
        h.update(repr((design.horizon, st.common_lag, [list(map(tuple, loc)) for loc in st.local])).encode())
        fp = h.digest()
        try:
            _FINGERPRINTS[design] = fp
        except TypeError:  # pragma: no cover
            pass
    return fp


def _design_cache(design: Any) -> dict:
    fp = _fingerprint(design)
    c = _CACHES.get(fp)
    if c is None:
        if len(_CACHES) >= 8:  # a few models at a time (a sweep moves on)
            _CACHES.pop(next(iter(_CACHES)))
        c = _CACHES[fp] = {"sigma": {}, "fill": {}, "sel": {}, "rule": {}}
    if c.get("n_fill", 0) > _CACHE_MAX:  # bounded: patterns of lossy runs repeat, but need not
        c["fill"].clear()
        c["n_fill"] = 0
    return c


def _fill_gains(design: Any, cache: dict, a: int, k: int, mask: np.ndarray, targets: list[tuple[int, int]], ui: np.ndarray) -> FloatArray:
    """G(H) = Σ_W[targets, H] Σ_W[H, H]^-1 with zero columns outside H, for each row of ``mask`` (P, w d_y).

    Σ_W is the covariance of the window innovations y(a : k) - C Φ x̂(a) under the nominal predictor
    covariance P(a) (:func:`~teamkf.estimators.team.window_covariances`), as in
    :meth:`~teamkf.estimators.team.TeamAgent.expected_measurements`. Solved on H only, Σ_W[H, H] X =
    Σ_W[H, targets], one batched solve per group of patterns holding the same number of coordinates.
    """
    sys = design.system
    dyt, off, dy = sys.dy_total, np.asarray(sys.offsets, dtype=int), [int(v) for v in sys.dy]
    Sigma_W = cache["sigma"].get((a, k))
    if Sigma_W is None:
        from ..estimators.team import window_covariances

        P_a = sys.Sigma_x if a == 0 else (design.P_pred if design.horizon is None else design.P_pred[a])
        Sigma_W = cache["sigma"][(a, k)] = window_covariances(sys, k, a, P_a)[0]
    tpos = np.concatenate([(s - a) * dyt + off[j] + np.arange(dy[j]) for (j, s) in targets]).astype(int)
    # ui: the coordinates that can be held at all (a fixed set, so a pattern's gain does not depend on the
    # other patterns solved with it); the others are identity rows
    mk = mask[:, ui]
    out = np.zeros((mask.shape[0], tpos.size, mask.shape[1]))
    # patterns grouped by how many coordinates they hold: each group one batched solve on its held coordinates
    # only (Σ_W[H, H] X = Σ_W[H, targets]; the same numbers as with identity rows outside H, at a fraction of the work)
    cnt = mk.sum(axis=1)
    order = np.argsort(cnt, kind="stable")
    bounds = np.flatnonzero(np.diff(cnt[order])) + 1
    Su = Sigma_W[np.ix_(ui, ui)]
    St = Sigma_W[np.ix_(ui, tpos)]
    for grp in np.split(order, bounds):
        m = int(cnt[grp[0]])
        if m == 0:
            continue
        idx = np.nonzero(mk[grp])[1].reshape(grp.size, m)  # held positions (in ui) of each pattern, ascending
        Xg = np.linalg.solve(Su[idx[:, :, None], idx[:, None, :]], St[idx])  # (P_g, m, Σ d_target)
        out[grp[:, None], :, ui[idx]] = Xg  # advanced indices first: (P_g, m, Σ d_target)
    return out


_MAPS: "weakref.WeakKeyDictionary[Any, dict]" = weakref.WeakKeyDictionary()
#: parts of step maps built by one design, waiting for the next design of the same model (popped when used)
_PRE: dict[tuple, tuple] = {}
_PRE_BYTES = [0]
_PRE_MAX_BYTES = 128 * 2**20


def _append_maps(store: dict, new: FloatArray) -> None:
    """Append maps to a step's store (capacity doubled when full, so a block adding a few patterns copies nothing)."""
    size = store.get("size", 0)
    buf = store.get("buf")
    if buf is None or size + len(new) > len(buf):
        grown = np.empty((max(2 * (size + len(new)), 16), *new.shape[1:]))
        if size and buf is not None:
            grown[:size] = buf[:size]
        buf = store["buf"] = grown
    buf[size : size + len(new)] = new
    store["size"] = size + len(new)
    store["maps"] = buf[: size + len(new)]


def _step_maps(design: Any) -> dict:
    """The cache of a design's step maps M_{i,k}(H) (they hold its own gains: not shared between designs)."""
    try:
        m = _MAPS.get(design)
        if m is None or len(m) > _CACHE_MAX:
            m = _MAPS[design] = {}
        return m
    except TypeError:  # pragma: no cover - not weakly referenceable
        return {}


class _TeamStep:
    r"""Every agent of an MTMSE/MMSE design over a block of runs, one linear map per step and arrival pattern.

    With H the window measurements agent i holds at step k, its whole step (fold of y(a0) with the rule,
    then the local estimate with the rule) is linear in u = [x̂(a0); y(a0 : k) on H]:

    .. math::  [\hat x(a'); z_i(k)] = M_{i,k}(H)\, u,

    M built once per (i, k, H) from the rule's gains (cached on the design), so a step of all agents and
    runs is one gather of u, one sort by (agent, pattern) and one batched product: a few numpy calls per
    step whatever the number of runs, agents and patterns. The agents' own arithmetic
    (:class:`~teamkf.estimators.team.TeamAgent`) in another order: equal to round-off.
    """

    def __init__(self, design: Any, ys: Sequence[FloatArray], t: np.ndarray, ell: list[list[int]]):
        self.d, self.sys = design, design.system
        self.n, self.c = self.sys.n_agents, design.structure.common_lag
        self.Y = np.concatenate(ys, axis=2)  # (R, T, Σ d_y)
        self.t = t  # (R, n, n, T)
        self.tt = np.ascontiguousarray(t.transpose(1, 0, 3, 2))  # (i, r, s, j): a step's window is one slice
        self.R, self.T = ys[0].shape[:2]
        self.x = np.zeros((self.n * self.R, self.sys.dx))  # row i R + r: agent i, run r
        self.agent = np.repeat(np.arange(self.n, dtype=np.int64), self.R)
        self.cache = _design_cache(design)
        self.mats = _step_maps(design)
        self.ell = ell  # ell[j][i]: y_j(s) reaches agent i at s + ell[j][i] at the earliest
        self.ell_key = tuple(tuple(int(v) for v in row) for row in ell)
        self.dy = [int(v) for v in self.sys.dy]
        self.off = np.asarray(self.sys.offsets, dtype=int)

    def step(self, k: int) -> FloatArray:
        """z(k) of every agent: (R, n d_z)."""
        n, R, dyt = self.n, self.R, self.sys.dy_total
        a0 = max(0, k - self.c)
        w = k - a0 + 1
        bits = (self.tt[:, :, a0 : k + 1] <= k).reshape(n * R, w * n)  # row (i, r); window order: step, then agent
        agent = self.agent
        if w * n <= 55:
            codes = (bits @ (np.int64(1) << np.arange(w * n, dtype=np.int64))) + (agent << 56)
        else:  # long windows: patterns as bytes (sorted through their rank in this block)
            packed = np.concatenate([agent[:, None].astype(np.uint8), np.packbits(bits, axis=1)], axis=1)
            codes = np.unique(packed, axis=0, return_inverse=True)[1].ravel()
        order = np.argsort(codes, kind="stable")  # rows grouped by (agent, pattern)
        cs = codes[order]
        first = np.empty(cs.size, dtype=bool)
        first[0] = True
        np.not_equal(cs[1:], cs[:-1], out=first[1:])
        starts = np.flatnonzero(first)
        gid = np.cumsum(first) - 1
        lead = order[starts]  # a row of each pattern
        keys = codes[lead].tolist() if w * n <= 55 else [bytes(packed[r]) for r in lead.tolist()]
        store = self.mats.get(k)
        if store is None:
            store = self.mats[k] = {"index": {}, "maps": None}
        index = store["index"]
        todo = [g for g, key in enumerate(keys) if key not in index]
        if todo:
            dyw = np.tile(self.dy, w)
            by_agent: dict[int, list[int]] = {}
            for g in todo:
                by_agent.setdefault(int(agent[lead[g]]), []).append(g)
            for i, gs in by_agent.items():
                m = self._maps_shared(i, k, a0, [keys[g] for g in gs], np.repeat(bits[lead[gs]], dyw, axis=1))
                _append_maps(store, m.transpose(0, 2, 1))  # stored as (d_x + w d_y, d_x + d_z): the product's right factor
                for g in gs:
                    index[keys[g]] = len(index)
        which = np.array([index[key] for key in keys])
        # rows sorted by pattern, in slabs of _STEP_SLAB rows of one pattern (zero rows pad a pattern's last slab)
        sizes = np.diff(np.append(starts, n * R))
        nslab = -(-sizes // _STEP_SLAB)
        pos = np.arange(n * R) - starts[gid]
        padrow = ((np.cumsum(nslab) - nslab)[gid] + pos // _STEP_SLAB) * _STEP_SLAB + pos % _STEP_SLAB
        dx = self.sys.dx
        pad = np.zeros((int(nslab.sum()) * _STEP_SLAB, dx + w * dyt))
        pad[padrow, :dx] = self.x[order]
        # y(a0 : k) whole: a map's columns of the measurements outside its pattern H are exact zeros, so
        # 0 * y adds nothing (y is finite); masking them would cost a pass over every row
        pad[padrow, dx:] = self.Y[order % R, a0 : k + 1].reshape(n * R, w * dyt)
        Ms = store["maps"][np.repeat(which, nslab)]
        res = np.matmul(pad.reshape(-1, _STEP_SLAB, pad.shape[1]), Ms).reshape(pad.shape[0], -1)
        out = np.empty((n * R, Ms.shape[2]))
        out[order] = res[padrow]
        self.x = out[:, :dx]
        return out[:, dx:].reshape(n, R, -1).transpose(1, 0, 2).reshape(R, -1)  # type: ignore[no-any-return]

    def misses(self) -> np.ndarray:
        """Per agent, the measurements the rule replaced at least once, summed over runs: (n,).

        y_j(s) is replaced when it is folded at s + c without having arrived, or when it is first needed in
        agent i's window, at s + (its smallest local lag), without having arrived (later needs are implied).
        """
        n, T, c = self.n, self.T, self.c
        s = np.arange(T)
        big = 2 * T + c + 1
        lag = np.full((n, n), big)
        for i in range(n):
            for j, l in self.d.structure.local_lags(i):
                lag[i, j] = min(lag[i, j], l)
        fold = (self.t > (s + c)) & (s + c <= T - 1)
        need = s[None, None, :] + lag[:, :, None]  # (i, j, s)
        loc = (self.t > need[None]) & (need[None] <= T - 1)
        return (fold | loc).sum(axis=(0, 2, 3))  # type: ignore[no-any-return]

    def _maps_shared(self, i: int, k: int, a0: int, keys: list, mask: np.ndarray) -> FloatArray:
        """:meth:`_maps`, reusing the parts [x̂(a'); ĩ] that another design of the same model (MTMSE and MMSE share
        the predictor and the rule) built for the same patterns; they are handed over once and dropped."""
        fp = (_fingerprint(self.d), hashlib.sha256(np.ascontiguousarray(self.d.K, dtype=float).tobytes()).digest())
        got: list[Any] = [_PRE.pop((fp, k, key), None) for key in keys]
        miss = [q for q, g in enumerate(got) if g is None]
        if miss:
            X, innov, a = self._pre(i, k, a0, mask[miss])
            nbytes = X[0].nbytes + (0 if innov is None else innov[0].nbytes)
            if _PRE_BYTES[0] + nbytes * len(miss) > _PRE_MAX_BYTES:
                _PRE.clear()
                _PRE_BYTES[0] = 0
            for q_, q in enumerate(miss):
                got[q] = (X[q_], None if innov is None else innov[q_], a)
                _PRE[(fp, k, keys[q])] = got[q]
            _PRE_BYTES[0] += nbytes * len(miss)
        X = np.stack([g[0] for g in got])
        innov = None if got[0][1] is None else np.stack([g[1] for g in got])
        return self._finish(i, k, X, innov, got[0][2])

    def _maps(self, i: int, k: int, a0: int, mask: np.ndarray) -> FloatArray:
        """M_{i,k}(H) for each row of ``mask`` (P, w d_y): (P, d_x + d_z, d_x + w d_y)."""
        X, innov, a = self._pre(i, k, a0, mask)
        return self._finish(i, k, X, innov, a)

    def _finish(self, i: int, k: int, X: FloatArray, innov: FloatArray | None, a: int) -> FloatArray:
        """[x̂(a'); z_i = L_i Φ(k, a') x̂(a') + F_i(k) ĩ] as maps of u."""
        d = self.d
        Z = np.matmul(d.cost.L_block(i, k) @ self.sys.transition(k, a), X)
        if innov is not None:
            Z = Z + np.matmul(d.gain_at(k)[i], innov)
        return np.concatenate([X, Z], axis=1)

    def _pre(self, i: int, k: int, a0: int, mask: np.ndarray) -> tuple[FloatArray, FloatArray | None, int]:
        """x̂(a') and the local innovation with the rule applied, as maps of u, for each pattern (row of ``mask``).

        ỹ(s) = y(s) - C(s) Φ(s, a) x̂(a) is Sel(a) - CΦ(a) X with Sel, CΦ the same for every pattern and X the map
        of x̂(a): before the fold X = [I 0] (no pattern), after it X = A X₀ + A K E(H). So the products with the
        pattern-independent factors are single matrix products over all patterns (``_lmul``), and only the fill
        G(H) ỹ of the local part is a batched product (with its small inner dimension d_x through CΦ).
        """
        sys, d, n = self.sys, self.d, self.n
        dx, dyt = sys.dx, sys.dy_total
        w = k - a0 + 1
        P, D = mask.shape[0], dx + w * dyt
        X0 = np.zeros((dx, D))
        X0[:, :dx] = np.eye(dx)

        def sel_cphi(a: int) -> tuple[FloatArray, FloatArray]:  # Sel (w' d_y, D) and CΦ (w' d_y, d_x), s = a..k
            got = self.cache["sel"].get((a0, a, k))
            if got is not None:
                return got  # type: ignore[no-any-return]
            m = (k - a + 1) * dyt
            sel = np.zeros((m, D))
            sel[:, dx + (a - a0) * dyt :] = np.eye(m)
            rows, Phi = [], np.eye(dx)
            for s in range(a, k + 1):
                rows.append(self._C(s) @ Phi)
                Phi = sys.A_at(s) @ Phi
            got = self.cache["sel"][(a0, a, k)] = (sel, np.concatenate(rows, axis=0))
            return got  # type: ignore[no-any-return]

        a = a0
        X: FloatArray = np.broadcast_to(X0, (P, dx, D))
        if k >= self.c:  # fold y(a0) with the rule
            sel, cphi = sel_cphi(a0)
            Yt0 = sel - cphi @ X0  # the same for every pattern
            targets = [(j, a0) for j in range(n)]
            E = np.broadcast_to(Yt0[:dyt], (P, dyt, D))
            G = self._rule_gains(mask, targets, a0, k, i)
            if G is not None:
                lost, Gm = G
                fill = (Gm.reshape(-1, Gm.shape[2]) @ Yt0).reshape(P, -1, D)
                E = np.where(lost[:, :, None], fill, E)
            A = sys.A_at(a0)
            X = _lmul(A @ d.K_at(a0), E) + (A @ X0)[None]
            a = a0 + 1
        pairs = d.structure.local_pairs(i, k)
        if not pairs:
            return np.ascontiguousarray(X), None, a
        sel, cphi = sel_cphi(a)
        cols = np.concatenate([(s - a) * dyt + self.off[j] + np.arange(self.dy[j]) for (j, s) in pairs])
        innov = sel[cols][None] - _lmul(cphi[cols], X)
        G = self._rule_gains(mask[:, (a - a0) * dyt :], pairs, a, k, i)
        if G is not None:
            lost, Gm = G
            fill = np.zeros((P, Gm.shape[1], D))
            fill[:, :, dx + (a - a0) * dyt :] = Gm  # G Sel
            fill -= np.matmul(_lmul(cphi.T, Gm.transpose(0, 2, 1)).transpose(0, 2, 1), X)  # - (G CΦ) X
            innov = np.where(lost[:, :, None], fill, innov)
        return np.ascontiguousarray(X), innov, a

    def _rule_gains(self, mask: np.ndarray, targets: list[tuple[int, int]], a: int, k: int, i: int) -> tuple[np.ndarray, FloatArray] | None:
        """(lost (P, Σ d_target), G(H) (P, Σ d_target, w' d_y)) for the rule's fill of the lost targets, or None when none is lost.

        The fill of a lost target is its conditional expectation G(H) ỹ_H (G is zero outside H: only held
        measurements enter)."""
        dyt = self.sys.dy_total
        key = (i, a, k, len(targets), self.ell_key)
        got = self.cache["rule"].get(key)
        if got is None:
            tpos = np.concatenate([(s - a) * dyt + self.off[j] + np.arange(self.dy[j]) for (j, s) in targets]).astype(int)
            reach = [(s - a) * dyt + self.off[j] + np.arange(self.dy[j]) for s in range(a, k + 1) for j in range(self.n) if s + self.ell[j][i] <= k]
            ui = np.concatenate(reach).astype(int) if reach else np.zeros(0, dtype=int)
            got = self.cache["rule"][key] = (tpos, ui)
        tpos, ui = got
        lost = ~mask[:, tpos]  # (P, Σ d_target)
        if not lost.any():
            return None
        return lost, _fill_gains(self.d, self.cache, a, k, mask, targets, ui)

    def _C(self, s: int) -> FloatArray:
        return self.sys.C_stack(s)


def _lmul(M: FloatArray, X: FloatArray) -> FloatArray:
    """M @ X[p] for every p, (P, m, D), as one matrix product (M: (m, d), X: (P, d, D))."""
    P, d, D = X.shape
    return (M @ X.transpose(1, 0, 2).reshape(d, P * D)).reshape(M.shape[0], P, D).transpose(1, 0, 2)  # type: ignore[no-any-return]


def _is_team_relay(ag: Any) -> bool:
    from ..estimators.base import MeasurementRelay
    from ..estimators.team import TeamAgent

    return type(ag) is MeasurementRelay and type(ag.inner) is TeamAgent and not ag.omniscient and ag.inner.index == ag.index


#: the link events of the last block (its designs share them: same streams, graph and links)
_LAST: list[Any] = []
#: the uniforms of the last block's link events (shared by designs whose outcomes differ, e.g. an omniscient bound)
_DRAWS: list[Any] = []


def _events(streams: Sequence[Any], T: int, edges: list, links: Any, omni: tuple, n: int, relays: bool) -> tuple[LinkOutcomes, np.ndarray | None]:
    """Outcomes (and relay arrivals) of a block, reused by the next design run on the same streams and links."""
    if _LAST and _LAST[0] is streams and _LAST[1] == (T, tuple(edges), omni) and _LAST[2] is links:
        out, t = _LAST[3], _LAST[4]
        if relays and t is None:
            t = _LAST[4] = relay_arrivals(out, n, T, links.max_jitter)
        return out, t
    if _DRAWS and _DRAWS[0] is streams and _DRAWS[1] == (T, len(edges)):  # another design kind on the same runs
        u, jit = _DRAWS[2], _DRAWS[3]
    else:
        u, jit = draw_link_events(streams, T, len(edges))
        _DRAWS[:] = [streams, (T, len(edges)), u, jit]
    out = link_outcomes(links, edges, u, jit, omni)
    t = relay_arrivals(out, n, T, links.max_jitter) if relays else None
    _LAST[:] = [streams, (T, tuple(edges), omni), links, out, t]  # holds ``streams``: its id cannot be reused meanwhile
    return out, t


def run_lossy(
    agents: Sequence[Any], graph: CommGraph, ys: Sequence[FloatArray], links: Any, streams: Sequence[Any], stats: Any, *, design: Any = None
) -> FloatArray:
    """The lossy message-passing loop for a block of runs (see :func:`teamkf.simulation.links.pass_messages_lossy`).

    Runs on one BLAS thread, as the Monte Carlo's chunks do: the step maps and fill gains it caches per design
    are then the same bits whoever computed them first (a caller on two BLAS threads could cache results
    one ulp apart from a Dask worker's, and the serial and distributed Monte Carlo would differ).
    """
    from .._blas import single_thread_blas

    with single_thread_blas():
        return _run_lossy(agents, graph, ys, links, streams, stats, design=design)


def _run_lossy(
    agents: Sequence[Any], graph: CommGraph, ys: Sequence[FloatArray], links: Any, streams: Sequence[Any], stats: Any, *, design: Any = None
) -> FloatArray:
    from ..estimators.base import pass_messages

    n = graph.n_agents
    R, T = ys[0].shape[:2]
    edges = sorted(graph.edges)
    omni = tuple(bool(getattr(ag, "omniscient", False)) for ag in agents)
    relays = not any(omni) and all(
        _is_team_relay(ag) and ag.inner.index == i and ag.inner.design is agents[0].inner.design for i, ag in enumerate(agents)
    )
    flood = not any(omni) and _is_lossy_team(agents)
    held = not any(omni) and _is_rulefill(agents)
    out, t = _events(streams, T, edges, links, omni, n, relays or flood or held)
    count_links(out, stats)
    if all(omni):  # the centralized bound: every y_j(k) at step k, whatever the links
        return pass_messages(agents, graph, ys, design=design)
    if relays:
        assert t is not None
        return _run_team(agents, graph, ys, t, streams, stats)
    if flood:
        assert t is not None
        return _run_lossy_team(agents, ys, t)
    if held:
        assert t is not None
        return _run_rulefill(agents, graph, ys, t, stats)
    if _is_cikf(agents):
        return _run_cikf(agents, ys, out)
    if _is_summary(agents):  # mtmse_lossy with summary = M: its own batched step (teamkf.estimators._lossy_summary)
        return agents[0].run_batched(agents, ys, out)
    if _is_adaptive(agents):  # mtmse_lossy with adaptive = true: its own batched step (teamkf.estimators._lossy_adaptive)
        return agents[0].run_batched(agents, ys, out)
    if _stackable(agents, graph):
        return _run_stacked(agents, graph, ys, out)
    return _run_grouped(agents, graph, ys, out, stats, design)


def _run_team(agents: Sequence[Any], graph: CommGraph, ys: Sequence[FloatArray], t: np.ndarray, streams: Any, stats: Any) -> FloatArray:
    """MTMSE/MMSE relays: every agent and run stepped together, one linear map per (agent, step, pattern)."""
    del streams
    n = len(agents)
    try:  # y_j(s) cannot reach agent i before s + ℓ_ji (geodesic delay), whatever the links do
        ell = np.asarray(graph.geodesic_delays()).T.tolist()  # ell[j][i] = ℓ_ji
    except TeamkfError:  # not strongly connected: no bound used
        ell = [[0] * n for _ in range(n)]
    ts = _TeamStep(agents[0].inner.design, ys, t, ell)
    T = ys[0].shape[1]
    z = np.stack([ts.step(k) for k in progress(range(T), desc="lossy runtime", total=T, unit="step")], axis=1)
    for i, m in enumerate(ts.misses().tolist()):
        if m:
            stats.missed[i] = stats.missed.get(i, 0) + int(m)
    return z


# ---------------------------------------------------------------------------
# the drop-aware team filter (mtmse_lossy): every run at once
# ---------------------------------------------------------------------------
def _is_lossy_team(agents: Sequence[Any]) -> bool:
    from ..estimators.team_lossy import LossyTeamAgent

    return bool(agents) and all(type(ag) is LossyTeamAgent and ag.index == i and ag.design is agents[0].design for i, ag in enumerate(agents))


def _run_lossy_team(agents: Sequence[Any], ys: Sequence[FloatArray], t: np.ndarray) -> FloatArray:
    """:class:`~teamkf.estimators.team_lossy.LossyTeamAgent` for every run at once, the same numbers run by run.

    Its agents flood every item they learn for the first time, as the relays of stage 2 do, so agent i first
    holds item (j, s) at t[r, i, j, s] (:func:`relay_arrivals`); the item enters (1) when that is s + ℓ_ji (on
    time), else its prediction from the agent's own items does. Rows are stacked as (R, 1, d): each product has
    the core shapes of the one-run step's."""
    d = agents[0].design
    sysm, n = d.system, len(agents)
    R, T = ys[0].shape[:2]
    ell = np.asarray(d.arrivals.ell, dtype=int)
    mine: list[list[Any]] = [[None] * T for _ in range(n)]
    xh: list[Any] = [np.zeros((R, 1, sysm.dx)) for _ in range(n)]
    zs: list[list[FloatArray]] = [[] for _ in range(n)]
    for k in progress(range(T), desc="lossy runtime (all runs)", total=T, unit="step"):
        for i in range(n):
            xhat = xh[i] if k == 0 else xh[i] @ sysm.A_at(k - 1).T
            y = ys[i][:, k, None, :]
            nu = y - xhat @ sysm.C_at(i, k).T
            xh[i] = xhat = xhat + nu @ d.K_local[k][i].T
            mine[i][k] = y if d.coordinates == "measurements" else nu
        for i in range(n):
            z = xh[i] @ d.cost.L_block(i, k).T
            its = d.items[k][i]
            if its:
                w = d.fills[k][i].shape[1] // sysm.dy[i] if sysm.dy[i] else k + 1  # the fills act on the last w own items
                fill = np.concatenate([mine[i][s] for s in range(k + 1 - w, k + 1)], axis=-1) @ d.fills[k][i].T
                parts, col = [], 0
                for j, s in its:
                    dj = int(sysm.dy[j])
                    due = s + int(ell[j, i])
                    on = t[:, i, j, s] == due if due <= k else np.zeros(R, dtype=bool)
                    parts.append(np.where(on[:, None, None], mine[j][s], fill[:, :, col : col + dj]))
                    col += dj
                z = z + np.concatenate(parts, axis=-1) @ d.gains[k][i].T
            zs[i].append(z[:, 0, :])
    return np.concatenate([np.stack(zi, axis=1) for zi in zs], axis=2)  # type: ignore[no-any-return]


def _is_summary(agents: Sequence[Any]) -> bool:
    from ..estimators._lossy_summary import SummaryAgent

    return bool(agents) and all(type(ag) is SummaryAgent and ag.index == i and ag.design is agents[0].design for i, ag in enumerate(agents))


def _is_adaptive(agents: Sequence[Any]) -> bool:
    from ..estimators._lossy_adaptive import adaptive_agent_class

    cls = adaptive_agent_class()
    if not agents or type(agents[0]) is not cls or not hasattr(agents[0].design, "estimates"):  # a slice's view steps run by run
        return False
    return all(type(ag) is cls and ag.index == i and ag.design is agents[0].design for i, ag in enumerate(agents))


def _is_rulefill(agents: Sequence[Any]) -> bool:
    from ..estimators._lossy_rulefill import RuleFillAgent

    return bool(agents) and all(type(ag) is RuleFillAgent and ag.index == i and ag.design is agents[0].design for i, ag in enumerate(agents))


def _run_rulefill(agents: Sequence[Any], graph: CommGraph, ys: Sequence[FloatArray], t: np.ndarray, stats: Any) -> FloatArray:
    """``mtmse_lossy`` with ``fill = "held"`` (:mod:`teamkf.estimators._lossy_rulefill`) for every run at once: its agents
    relay as the MTMSE relays, so the rule's feature is :class:`_TeamStep` on the same arrivals, the others its ``features``."""
    d = agents[0].design
    ell = np.asarray(graph.geodesic_delays()).T.tolist()
    ts = _TeamStep(d.nominal, ys, t, ell)
    R, T = ys[0].shape[:2]
    Y = np.concatenate(ys, axis=2).reshape(R, -1)
    n = len(agents)
    z = np.empty((R, T, n * d.cost.dz))
    for k in progress(range(T), desc="lossy runtime (all runs)", total=T, unit="step"):
        rule = ts.step(k).reshape(R, n, -1)
        z[:, k] = d.combine(k, d.features(k, Y, t, rule))
    for i, m in enumerate(ts.misses().tolist()):
        if m:
            stats.missed[i] = stats.missed.get(i, 0) + int(m)
    return z


def _is_cikf(agents: Sequence[Any]) -> bool:
    from ..estimators.cikf.filter import CIKFAgent

    return bool(agents) and all(
        type(ag) is CIKFAgent and ag.tolerant and ag.index == i and ag.design is agents[0].design for i, ag in enumerate(agents)
    )


def _run_cikf(agents: Sequence[Any], ys: Sequence[FloatArray], out: LinkOutcomes) -> FloatArray:
    """:class:`~teamkf.estimators.cikf.filter.CIKFAgent` (tolerant) for every run at once, the same numbers run by run.

    A neighbour's step-(k-1) prediction enters where it arrived at k; elsewhere its difference is an exact zero,
    as in the one-run step. Rows are stacked as (R, 1, d): each product has the core shapes of the one-run step's."""
    from ..exceptions import ShapeError

    d = agents[0].design
    m, n = d.model, len(agents)
    R, T = ys[0].shape[:2]
    if T > d.horizon:
        raise ShapeError(f"k: the CIKF was designed for horizon = {d.horizon} steps, found step {d.horizon}; design a longer horizon")
    arr = np.where(out.delivered, out.arrive, -1)
    edge = {(a, b): q for q, (a, b, _) in enumerate(out.edges)}
    yh: list[Any] = [np.zeros((R, 1, m.rank)) for _ in range(n)]
    xh: list[Any] = [np.zeros((R, 1, d.system.dx)) for _ in range(n)]
    sent: list[Any] = [None] * n
    zs: list[list[FloatArray]] = [[] for _ in range(n)]
    for k in progress(range(T), desc="lossy runtime (all runs)", total=T, unit="step"):
        now = []
        for i in range(n):
            u = ys[i][:, k, None, :] - yh[i] @ m.C_tilde[i].T
            yf = yh[i] + u @ d.B_innov[k][i].T
            nb = d.neighbors[i]
            if nb and k > 0:
                parts = []
                for lnode in nb:
                    q = edge.get((lnode, i))
                    on = arr[:, k - 1, q] == k if q is not None else np.zeros(R, dtype=bool)
                    parts.append(np.where(on[:, None, None], sent[lnode] @ m.U - yh[i], 0.0))
                yf = yf + np.concatenate(parts, axis=-1) @ d.B_cons[k][i].T
            xf = xh[i] + (yf - xh[i] @ m.G_r.T) @ d.K[k, i].T
            zs[i].append(((xf if d.form == "filter" else xh[i]) @ d.cost.L_block(i, k).T)[:, 0, :])
            yh[i] = yf @ m.A_tilde_r.T + xf @ m.A_check_r.T
            xh[i] = xf @ d.system.A_at(0).T
            now.append(yh[i] @ m.U.T)
        sent = now
    return np.concatenate([np.stack(zi, axis=1) for zi in zs], axis=2)  # type: ignore[no-any-return]


# ---------------------------------------------------------------------------
# families with a stacked tolerant step: all runs at once
# ---------------------------------------------------------------------------
def _stackable(agents: Sequence[Any], graph: CommGraph) -> bool:
    """The agents are one linear design's loss-tolerant agents and its algorithm steps all runs at once (``agent_step_runs``)."""
    from ..estimators.linear_team import LinearAgent

    if not agents or any(type(ag) is not LinearAgent or not ag.tolerant or ag.index != i for i, ag in enumerate(agents)):
        return False
    d = agents[0].design
    if any(ag.design is not d for ag in agents) or not getattr(d.algorithm, "stacks_runs", True):
        return False
    # the class whose tolerant step the agents run must be the one that stacks it (a subclass may change the step)
    owner = next((c for c in type(d.algorithm).__mro__ if "agent_step_tolerant" in c.__dict__), None)
    if owner is None or "agent_step_runs" not in owner.__dict__:
        return False
    pairs = [(a, b) for (a, b, _) in graph.edges]
    return len(pairs) == len(set(pairs))


def _run_stacked(agents: Sequence[Any], graph: CommGraph, ys: Sequence[FloatArray], out: LinkOutcomes) -> FloatArray:
    """Every run of the block at once through the family's ``agent_step_runs`` (:mod:`teamkf.estimators._runs`).

    The same estimates as :func:`_run_grouped` bit for bit: each run's packets enter in the order
    :func:`~teamkf.estimators.linear_team.delivered` gives them, and the stacked step repeats the one-run arithmetic.
    """
    from ..exceptions import ShapeError

    d = agents[0].design
    alg = d.algorithm
    n = graph.n_agents
    R, T = ys[0].shape[:2]
    if T > len(d.steps):
        raise ShapeError(f"k: the design has horizon = {len(d.steps)} steps, found step {len(d.steps)}; design a longer horizon")
    # arrival step of each (run, sent step, edge) packet, -1 when it is not delivered
    arr = np.where(out.delivered, out.arrive, -1)
    late = out.extra.max(axis=(0, 1)) if out.extra.size else np.zeros(len(out.edges), dtype=np.int64)
    ins: list[list[tuple[int, int, int, int]]] = []  # per target: (position, source, edge, delay), in position order
    info = alg.runs_graph if hasattr(alg, "runs_graph") else alg.graph  # the graph whose packets the step uses (``delivered``)
    for i in range(n):
        pos = {j: a for a, j in enumerate(info.in_neighbors(i))} if info is not None else {}
        ins.append(sorted((pos[a], a, q, dl) for q, (a, b, dl) in enumerate(out.edges) if b == i and a in pos))
    keep = max((dl + int(late[q]) for q, (_, _, dl) in enumerate(out.edges)), default=0)  # the oldest packet still in flight
    pay: dict[int, list[dict]] = {}
    states: list[Any] = [None] * n
    z = np.empty((R, T, sum(int(d.cost.L_block(i, 0).shape[0]) for i in range(n))))
    for k in progress(range(T), desc="lossy runtime (all runs)", total=T, unit="step"):
        now, col = [], 0
        for i in range(n):
            slots = []
            for _, a, q, dl in ins[i]:
                for s in range(max(0, k - dl - int(late[q])), k - dl + 1):
                    m = arr[:, s, q] == k
                    if m.any():
                        slots.append((a, s, m, pay[s][a]))
            y_i = ys[i][:, k, :, None]
            states[i], payload = alg.agent_step_runs(i, k, states[i], y_i, slots)
            zi = (d.cost.L_block(i, k) @ states[i][alg.output])[:, :, 0]
            z[:, k, col : col + zi.shape[1]] = zi
            col += zi.shape[1]
            now.append(payload)
        pay[k] = now
        pay.pop(k - keep - 1, None)
    return z


# ---------------------------------------------------------------------------
# any tolerant family: runs grouped by what arrived
# ---------------------------------------------------------------------------
def _run_grouped(agents: Sequence[Any], graph: CommGraph, ys: Sequence[FloatArray], out: LinkOutcomes, stats: Any, design: Any = None) -> FloatArray:
    """Step the agents' own ``step`` on the runs one at a time (their states need not stack), on the block's link events."""
    from ..estimators.base import checked_step, step_context

    dz, who = step_context(design)

    n = graph.n_agents
    R, T = ys[0].shape[:2]
    ok = out.delivered
    omni = [bool(getattr(ag, "omniscient", False)) for ag in agents]
    ends = [(a, b) for (a, b, _) in out.edges]
    results = []
    for r in progress(range(R), desc="lossy runtime (run by run)", total=R, unit="run"):
        states = [ag.init_state(1) for ag in agents]
        inbox: dict[int, list[list[Any]]] = {}
        # run r's deliveries, by sending step: (edge, arrival step), edges in order
        ks, qs = np.nonzero(ok[r])
        sends: dict[int, list[tuple[int, int]]] = {}
        for k_, q_, t_ in zip(ks.tolist(), qs.tolist(), out.arrive[r, ks, qs].tolist()):
            sends.setdefault(k_, []).append((q_, t_))
        yr = [y[r : r + 1] for y in ys]
        zr = []
        for k in range(T):
            box = inbox.pop(k, None) or [[] for _ in range(n)]
            zs, payloads = [], []
            for i, ag in enumerate(agents):
                if omni[i]:
                    own: Any = [(j, k, yr[j][:, k]) for j in range(n)]
                    msgs: list[Any] = []
                else:
                    own, msgs = yr[i][:, k], box[i]
                states[i], z, payload = checked_step(ag, i, states[i], k, own, msgs, 1, dz, who)
                zs.append(z)
                payloads.append(payload)
            for q, t_arr in sends.get(k, ()):
                a, b = ends[q]
                inbox.setdefault(t_arr, [[] for _ in range(n)])[b].append((a, k, payloads[a]))
            zr.append(np.concatenate(zs, axis=1))
        results.append(np.stack(zr, axis=1))
        for i in range(n):
            m = _missed(states[i])
            if m:
                stats.missed[i] = stats.missed.get(i, 0) + m
    return np.concatenate(results, axis=0)


def _missed(state: Any) -> int:
    """Deadline misses an agent's state recorded (measurements replaced by their expectation)."""
    if isinstance(state, dict):
        if "missed" in state:
            return int(state["missed"])
        inner = state.get("inner")
        if isinstance(inner, dict):
            return int(inner.get("missed", 0))
    return 0
