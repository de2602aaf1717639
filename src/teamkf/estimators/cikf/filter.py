r"""The designed CIKF: :class:`CIKFDesign` (covariances, costs, the vectorized filter) and its online agents.

Agent n runs Algorithm 1 with the designed gains (eqs. 21-24):
ŷ^n_{k|k} = ŷ^n_{k|k-1} + Σ_l B^{nl}_k (ŷ^l_{k|k-1} - ŷ^n_{k|k-1}) + B^{nn}_k (z̃^n_k - H̃_n ŷ^n_{k|k-1}),
x̂^n_{k|k} = x̂^n_{k|k-1} + K^n_k (ŷ^n_{k|k} - G x̂^n_{k|k-1}), then ŷ^n_{k+1|k} = Ã ŷ^n_{k|k} + Ǎ x̂^n_{k|k},
x̂^n_{k+1|k} = A x̂^n_{k|k}. :class:`CIKFAgent` is one agent for :func:`teamkf.run_graph` (one exchange per step,
unit delay); :meth:`CIKFDesign.simulate` and :meth:`CIKFDesign.errors` run all agents over all runs at once.
:func:`tracking_bound` is Theorem 3's bound for the design's own gains.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal, Sequence

import numpy as np

from ... import _validation as V
from ..._blas import blas_threads
from ..._validation import FloatArray
from ...exceptions import InformationStructureError, ShapeError
from ...network.graph import CommGraph
from ..base import Design, check_measurements, check_paths
from .gains import DEFAULT_RCOND
from .kernels import Form, _agent_groups, _worker_pool
from .model import PseudoStateModel

__all__ = ["CIKFDesign", "CIKFAgent", "tracking_bound"]


@dataclass(frozen=True, eq=False, kw_only=True)
class CIKFDesign(Design):
    r"""Gains (Algorithm 2, Theorem 4) and error covariances (corrected eqs. 41-47) of the CIKF.

    Built by :func:`~teamkf.design_cikf`.

    Parameters
    ----------
    estimator, horizon, system, cost, stage_costs, average_cost, info
        As in :class:`~teamkf.Design`: the family name, T (None for the steady state), the
        model, the team cost, the exact E[c(x(k), ẑ(k))] per step and the plain-data facts.
    graph : CommGraph
        The communication graph: agent i hears agent j over edge (j, i) after its integer delay τ_ji.
    model : PseudoStateModel
        The pseudo-state model of Section III (each agent's reduced coordinates).
    form : "filter" or "predictor"
        ẑ_n(k) = L_n x̂^n_{k|k} (filter) or L_n x̂^n_{k|k-1} (predictor).
    rcond : float
        The pseudo-inverse cut-off of Theorem 4.
    neighbors : tuple
        Ω_n, in the order of the consensus gain blocks.
    B_cons : tuple over steps of tuples over agents of (r, d_n r) arrays
        [B_r^{n l_1}, ..., B_r^{n l_d}] in reduced coordinates.
    B_innov : tuple over steps of tuples over agents of (r, M_n) arrays
        The innovation gains B_u^n.
    K : (T, N, M, r) array
        The state gains K_r^n.
    Sigma_pred, Sigma_filt : (T, N, M, M) arrays
        Agent n's Σ^{nn}_{k|k-1} and Σ^{nn}_{k|k}.
    P_pred_trace : (T, N) array
        tr P^{nn}_{k|k-1} (pseudo-state MSE, reduced = full coordinates).

    See Also
    --------
    design_cikf

    Examples
    --------
    >>> from teamkf import design_cikf
    >>> from teamkf.study.random_field import random_field
    >>> system, graph = random_field(15, 6, rng=1)
    >>> d = design_cikf(system, None, graph, horizon=5)
    >>> d.K.shape[:2], len(d.neighbors)
    ((5, 6), 6)
    """

    graph: CommGraph
    model: PseudoStateModel
    form: Form = "filter"
    rcond: float = DEFAULT_RCOND
    neighbors: tuple[tuple[int, ...], ...]
    B_cons: tuple[tuple[FloatArray, ...], ...]
    B_innov: tuple[tuple[FloatArray, ...], ...]
    K: FloatArray
    Sigma_pred: FloatArray
    Sigma_filt: FloatArray
    P_pred_trace: FloatArray

    @property
    def n_agents(self) -> int:
        return int(self.system.n_agents)

    # --- analytic MSE -------------------------------------------------------
    def mse(self, form: Form | None = None, *, per_agent: bool = False) -> FloatArray:
        """tr Σ^{nn} per step: (T, N) with ``per_agent``, else the average over agents (T,).

        ``form="predictor"``: Σ_{k|k-1} (the paper's Fig. 4 plots tr Σ_{i+1|i}, i.e. entries 1..T-1);
        ``form="filter"``: Σ_{k|k}.
        """
        f = self.form if form is None else form
        if f not in ("filter", "predictor"):
            raise ShapeError(f"form: expected 'filter' or 'predictor', found {f!r}")
        S = self.Sigma_filt if f == "filter" else self.Sigma_pred
        t = np.trace(S, axis1=2, axis2=3)
        return t if per_agent else t.mean(axis=1)  # type: ignore[no-any-return]

    # --- gains --------------------------------------------------------------
    def gains(self, k: int) -> dict[str, Any]:
        """Reduced-coordinate gains at step k: ``B_cons`` (per agent (r, d_n r)), ``B_innov`` (per agent (r, M_n)), ``K`` (N, M, r)."""
        k = self._step(k)
        return {"B_cons": self.B_cons[k], "B_innov": self.B_innov[k], "K": self.K[k]}

    def _step(self, k: int) -> int:
        if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or not 0 <= k < self.horizon:  # type: ignore[operator]
            raise ShapeError(f"k: expected a step in 0..{self.horizon - 1} (horizon = {self.horizon}), found {k!r}")  # type: ignore[operator]
        return int(k)

    def m_rows(self, k: int) -> list[FloatArray]:
        """Block rows of M_k = I - B^C - B^I D̃_H in reduced coordinates over each closed neighbourhood [n, l_1, ..., l_d]."""
        k = self._step(k)
        r = self.model.rank
        rows = []
        for n in range(self.n_agents):
            Bc, Bu = self.B_cons[k][n], self.B_innov[k][n]
            d = len(self.neighbors[n])
            row = np.empty((r, (d + 1) * r))
            row[:, :r] = np.eye(r) - Bu @ self.model.C_tilde[n] - Bc.reshape(r, d, r).sum(axis=1)
            row[:, r:] = Bc
            rows.append(row)
        return rows

    def paper_gains(self, k: int) -> dict[str, FloatArray]:
        """B^C, B^I and K of eqs. (60)-(63) in the paper's full coordinates, as dense NM x NM matrices (small problems).

        B^{nl} = U B_r^{nl} U', B^{nn} = U B_u^n (H_n' R_n^-1)†, K^n = K_r^n U'. They act on the
        paper's M-dimensional pseudo-state and pseudo-observations; the estimate they give is the
        reduced-coordinate filter's (module docstring).
        """
        k = self._step(k)
        m, N, M = self.model, self.n_agents, self.system.dx
        U = m.U
        BC = np.zeros((N * M, N * M))
        BI = np.zeros((N * M, N * M))
        K = np.zeros((N * M, N * M))
        r = m.rank
        for n in range(N):
            sl = slice(n * M, (n + 1) * M)
            Bc = self.B_cons[k][n]
            for q, l in enumerate(self.neighbors[n]):
                Bnl = U @ Bc[:, q * r : (q + 1) * r] @ U.T
                BC[sl, l * M : (l + 1) * M] = -Bnl
                BC[sl, sl] += Bnl
            BI[sl, sl] = U @ self.B_innov[k][n] @ np.linalg.pinv(m.innov_map[n])
            K[sl, sl] = self.K[k, n] @ U.T
        return {"B_C": BC, "B_I": BI, "K": K}

    # --- online: graph agents -------------------------------------------------
    def graph_agents(self) -> list["CIKFAgent"]:
        """Algorithm 1: one message-passing agent per node for :func:`teamkf.simulation.runtime.run_graph`."""
        return [CIKFAgent(self, n) for n in range(self.n_agents)]

    def agents(self) -> list[Any]:
        raise self._unsupported(
            "agents()",
            "CIKF agents exchange pseudo-state predictions, not measurement packets: run them with "
            "run_graph(design.graph_agents(), design.graph, y), or use design.filter(y) / design.errors(paths)",
        )

    def _filter(self, ys: list[FloatArray]) -> FloatArray:
        return self.simulate(ys)

    def details(self) -> dict[str, Any]:
        return {"form": self.form, "rank": self.model.rank, "local_dims": None, "gain_shapes": {"K_n": list(self.K.shape[-2:])}}

    def arrays(self) -> dict[str, np.ndarray]:
        """Costs, the state gains ``K`` (T, N, M, r), the consensus gains ``B_cons_{n}`` (T, r, d_n r) and the
        innovation gains ``B_innov_{n}`` (T, r, M_n) of each agent, and the error covariances."""
        out = {**super().arrays(), "K": np.asarray(self.K), "Sigma_pred": np.asarray(self.Sigma_pred), "Sigma_filt": np.asarray(self.Sigma_filt)}
        for n in range(self.n_agents):
            out[f"B_cons_{n}"] = np.stack([np.asarray(step[n]) for step in self.B_cons])
            out[f"B_innov_{n}"] = np.stack([np.asarray(step[n]) for step in self.B_innov])
            out[f"neighbors_{n}"] = np.asarray(self.neighbors[n], dtype=np.int64)
        return out

    # --- vectorized Monte Carlo ---------------------------------------------------
    def _check_y(self, y: Any) -> tuple[list[FloatArray], int, int]:
        ys, n_runs, T, _ = check_measurements(y, self.system, self.horizon)
        return ys, n_runs, T

    def _recursion(self, ys: Sequence[FloatArray] | None, x0: FloatArray | None, w: FloatArray | None, n_runs: int, T: int, form: str) -> FloatArray:
        threads = self.info.get("threads", 1)
        with blas_threads(None if threads is None else 1):
            return self._recursion_impl(ys, x0, w, n_runs, T, form)

    def _recursion_impl(
        self, ys: Sequence[FloatArray] | None, x0: FloatArray | None, w: FloatArray | None, n_runs: int, T: int, form: str
    ) -> FloatArray:
        r"""Algorithm 1 on data (``ys``) or its error recursion (30)-(33) on the primitive noises (x0, w, ys = v).

        Runs-last layout. The pseudo-state parts live in ``Y`` (N, r, n_runs); ``X`` (N, r + M, n_runs) holds,
        per agent, [ŷ^n_{k|k}; x̂^n_{k|k-1}] (errors: [e^n_{k|k}; ε^n_{k|k-1}]). One step is

            X[n, :r] = [M_k]_{n, hood(n)} Y[hood(n)] ± B_u^n y_n(k)       (21) / (30): one GEMM per agent on
                                                                          its gathered neighbourhood
            [Y[n]; X[n, r:]] <- Φ^n_k X[n] (+ [G_r; I] w(k))              (22)-(24) / (31)-(33) fused

        with Φ^n = [[Ã + Ǎ K^n, Ǎ F^n], [A K^n, A F^n]], F^n = I - K^n G_r (x̂_{k|k} = K ŷ_{k|k} + F x̂_{k|k-1}):
        one (r + M) x (r + M) GEMM per agent instead of five products and their passes over memory.
        The filter form's output x̂^n_{k|k} = [K^n F^n] X[n] costs one more GEMM per agent.
        """
        m, sys, cost = self.model, self.system, self.cost
        N, M, r = self.n_agents, sys.dx, m.rank
        q = r + M
        A = sys.A_at(0)
        Gr, At, Ac = m.G_r, m.A_tilde_r, m.A_check_r
        errors = x0 is not None
        R_ = n_runs
        Y = np.empty((N, r, R_))
        X = np.empty((N, q, R_))
        if errors:
            Y[:] = (Gr @ x0.T)[None]  # type: ignore[union-attr]  # e^n_{0|-1} = G_r (x0 - x̄0)
            X[:, r:] = x0.T[None]  # type: ignore[union-attr]  # ε^n_{0|-1}
        else:
            Y[:] = 0.0  # ŷ^n_{0|-1} = G_r x̄_0 = 0
            X[:, r:] = 0.0
        dz = cost.dz
        identity_L = dz == M and all(
            np.array_equal(cost.L_block(n, k), np.eye(M)) for n in range(N) for k in range(min(T, 1 if not cost.is_time_varying else T))
        )
        threads = self.info.get("threads", 1) or 1
        groups = _agent_groups(self.neighbors, [c.shape[0] for c in m.C_tilde], parts=threads)
        hoods = [np.asarray([n, *nb], dtype=np.intp) for n, nb in enumerate(self.neighbors)]
        offs = np.concatenate([[0], np.cumsum([c.shape[0] for c in m.C_tilde])])
        ystack = np.concatenate([np.asarray(y, dtype=float) for y in ys], axis=2)  # type: ignore[union-attr]  # (R, T, sum M_n)
        # zero-filled, not np.empty: the strided first writes below would otherwise fault the fresh pages in
        # one by one (measured: 1.6 s of CPU for the 640 MB of 1000 runs x 32 steps at M = N = 50, against 0.2 s)
        out = np.zeros((n_runs, T, N * dz))
        Lb = None if identity_L else [np.stack([cost.L_block(n, k) for n in range(N)]) for k in range(T)]
        cuts = np.linspace(0, N, min(threads, N) + 1).round().astype(int)
        sign = -1.0 if errors else 1.0  # - B_u^n v_n (errors) | + B_u^n y_n (data)
        with _worker_pool(threads if threads > 1 else None) as pool:

            def run(tasks: Sequence[Any]) -> None:
                if pool is None:
                    for f in tasks:
                        f()
                else:
                    for fut in [pool.submit(f) for f in tasks]:
                        fut.result()

            for k in range(T):
                Bu_k = self.B_innov[k]
                rows_k = self.m_rows(k)
                Kk = self.K[k]
                F = np.eye(M) - Kk @ Gr
                KF = np.concatenate([Kk, F], axis=2)  # x̂_{k|k} = [K F] [ŷ_{k|k}; x̂_{k|k-1}], (N, M, q)
                Phi = None
                if k + 1 < T:
                    Phi = np.empty((N, q, q))
                    Phi[:, :r, :r] = At + Ac @ Kk
                    Phi[:, :r, r:] = Ac @ F
                    Phi[:, r:, :r] = A @ Kk
                    Phi[:, r:, r:] = A @ F
                yk = np.ascontiguousarray(ystack[:, k].T)  # (sum M_n, R)
                wk = np.ascontiguousarray(w[:, k].T) if errors and k + 1 < T else None  # type: ignore[index]  # (M, R)
                Gw = None if wk is None else Gr @ wk

                def consensus(part: Sequence[tuple[np.ndarray, np.ndarray]], rows_k: Any = rows_k, Bu_k: Any = Bu_k, yk: FloatArray = yk) -> None:
                    for agents, _ in part:
                        for n in agents:  # M_k's block row times the neighbourhood's (d + 1) r x n_runs rows
                            np.matmul(rows_k[n], Y[hoods[n]].reshape(-1, R_), out=X[n, :r])
                        mn = offs[agents[0] + 1] - offs[agents[0]]
                        if mn:
                            Bu = np.stack([Bu_k[n] for n in agents])
                            Yv = np.stack([yk[offs[n] : offs[n] + mn] for n in agents])
                            X[agents, :r] += sign * np.matmul(Bu, Yv)

                def update(
                    lo: int,
                    hi: int,
                    k: int = k,
                    KF: FloatArray = KF,
                    Phi: FloatArray | None = Phi,
                    wk: FloatArray | None = wk,
                    Gw: FloatArray | None = Gw,
                ) -> None:
                    src = np.matmul(KF[lo:hi], X[lo:hi]) if form == "filter" else X[lo:hi, r:]  # (hi - lo, M, R)
                    if Lb is not None:
                        src = np.matmul(Lb[k][lo:hi], src)
                    o = out[:, k, lo * dz : hi * dz].reshape(R_, hi - lo, dz)
                    for i in range(0, R_, 64):  # transposed into the run-major output, 64 runs at a time
                        o[i : i + 64] = src[:, :, i : i + 64].transpose(2, 0, 1)
                    if Phi is None:  # the last step: no prediction
                        return
                    tmp = np.empty((q, R_))
                    for n in range(lo, hi):
                        np.matmul(Phi[n], X[n], out=tmp)  # [ŷ_{k+1|k}; x̂_{k+1|k}] = Φ^n [ŷ_{k|k}; x̂_{k|k-1}]
                        Y[n] = tmp[:r]
                        X[n, r:] = tmp[r:]
                        if wk is not None and Gw is not None:  # + [G_r; I] w(k)
                            Y[n] += Gw
                            X[n, r:] += wk

                run([lambda p=p: consensus(p) for p in groups])
                run([lambda a=a, b=b: update(a, b) for a, b in zip(cuts[:-1], cuts[1:]) if b > a])
        return out

    def simulate(self, y: Any, *, form: Form | None = None) -> FloatArray:
        """Algorithm 1 for every agent at once, batched over runs: ẑ (n_runs, T', N d_z), agent-major.

        Parameters
        ----------
        y : list over agents of (n_runs, T', d_y^n) arrays (T' <= horizon), or a ``Paths``
        form : override the design's form ("filter" or "predictor")

        Equals ``run_graph(design.graph_agents(), design.graph, y)`` (tested).
        """
        ys, n_runs, T = self._check_y(y)
        f = self.form if form is None else form
        if f not in ("filter", "predictor"):
            raise ShapeError(f"form: expected 'filter' or 'predictor', found {f!r}")
        return self._recursion(ys, None, None, n_runs, T, f)

    def errors(self, paths: Any, *, form: Form | None = None) -> FloatArray:
        r"""Team errors L x(k) - ẑ(k), (n_runs, T', N d_z), from the primitive noises (no cancellation).

        The error recursion of Lemma 2 with Ȟ_n = 0, in reduced coordinates:

            e^n_{k|k} = e^n - Σ_l B^{nl}(e^n - e^l) - B_u^n (C̃_n e^n + v_n(k))       (30)
            ε^n_{k|k} = ε^n - K^n (G_r ε^n - e^n_{k|k})                              (31)
            e^n_{k+1|k} = Ã_r e^n_{k|k} + Ǎ_r ε^n_{k|k} + G_r w(k)                   (32)
            ε^n_{k+1|k} = A ε^n_{k|k} + w(k)                                         (33)

        from ε^n_{0|-1} = x(0), e^n_{0|-1} = G_r x(0). Only x(0), w and v enter, so
        nothing large is subtracted when A is unstable; the result is what the online
        agents produce (``L x - simulate(y)``) up to round-off.
        """
        check_paths(paths, self.system)
        x = V.as_float_array(paths.x, "paths.x")
        sys, N = self.system, self.n_agents
        if x.ndim != 3 or x.shape[2] != sys.dx:
            raise ShapeError(f"paths.x: expected shape (n_runs, n_steps, {sys.dx}), found {x.shape}")
        n_runs, T = x.shape[:2]
        if T > self.horizon:  # type: ignore[operator]
            raise ShapeError(f"paths: expected at most horizon = {self.horizon} steps, found {T}")
        w = np.asarray(paths.w, dtype=float)
        v = [np.asarray(vi, dtype=float) for vi in paths.v]
        if w.shape != (n_runs, max(T - 1, 0), sys.dx) or len(v) != N or any(vi.shape != (n_runs, T, sys.dy[i]) for i, vi in enumerate(v)):
            raise ShapeError(
                f"paths: expected w of shape {(n_runs, max(T - 1, 0), sys.dx)} and {N} noise arrays v[i] of shape "
                f"(n_runs, {T}, d_y^i), found w {w.shape} and {[vi.shape for vi in v]}"
            )
        f = self.form if form is None else form
        if f not in ("filter", "predictor"):
            raise ShapeError(f"form: expected 'filter' or 'predictor', found {f!r}")
        return self._recursion(v, x[:, 0], w, n_runs, T, f)

    def costs(self, paths: Any) -> FloatArray:
        """Team cost c(x(k), ẑ(k)) per run and step, (n_runs, T'), from :meth:`errors`."""
        e = self.errors(paths)
        return np.stack([np.einsum("ra,ab,rb->r", e[:, k], self.cost.S_at(k), e[:, k]) for k in range(e.shape[1])], axis=1)

    # --- tracking capacity ---------------------------------------------------
    def tracking_bound(self, k: int | None = None, *, subspace: Literal["range", "full"] = "range") -> float:
        """Theorem 3's bound λ_1 / (λ_m ||I - B^C - B^I D̃_H||_2) with this design's gains at step k (default: the last)."""
        return tracking_bound(self, self.horizon - 1 if k is None else k, subspace=subspace)  # type: ignore[operator]


class CIKFAgent:
    """Agent n of Algorithm 1 on the message-passing runtime.

    Its state is (ŷ^n_{k|k-1} in reduced coordinates, x̂^n_{k|k-1}). At step k it
    receives its own measurement y_n(k) (its pseudo-observation z̃^n = H_n' R_n^-1 y_n(k)
    enters only through B^{nn}(z̃^n - H̃_n ŷ^n) = B_u^n (y_n(k) - C̃_n ŷ_r^n), which is
    what is computed) and the payloads its neighbours sent at
    k - 1: their pseudo-state predictions ŷ^l_{k|k-1} in the paper's coordinates
    (M-dimensional, ŷ = U ŷ_r). At k = 0 nothing has arrived and every
    neighbour's prediction is the common prior G x̄_0 = 0 (Assumption 3), so
    the differences are zero (and so are the step-0 consensus gains). It
    returns L_n x̂^n_{k|k} (or L_n x̂^n_{k|k-1}) and sends ŷ^n_{k+1|k}.
    """

    def __init__(self, design: CIKFDesign, index: int, *, tolerant: bool = False):
        self.design = design
        self.index = index
        #: on unreliable links (teamkf.simulation.links): the consensus term uses the neighbours whose
        #: step-(k-1) prediction arrived; a missing neighbour's difference ŷ^l - ŷ^n is taken as zero
        #: (its block of B^{nl} is dropped, the others are not renormalized)
        self.tolerant = tolerant

    def init_state(self, n_runs: int) -> dict[str, FloatArray]:
        d = self.design
        return {"y": np.zeros((n_runs, d.model.rank)), "x": np.zeros((n_runs, d.system.dx))}

    def step(
        self, state: dict[str, FloatArray], k: int, own: FloatArray, inbox: Sequence[Any]
    ) -> tuple[dict[str, FloatArray], FloatArray, FloatArray]:
        d, n = self.design, self.index
        if k >= d.horizon:  # type: ignore[operator]
            raise ShapeError(f"k: the CIKF was designed for horizon = {d.horizon} steps, found step {k}; design a longer horizon")
        m = d.model
        yh, xh = state["y"], state["x"]
        nb = d.neighbors[n]
        got = {j: p for (j, s, p) in inbox if s == k - 1}
        if k > 0 and sorted(got) != list(nb) and not self.tolerant:
            raise InformationStructureError(
                f"CIKF agent {n} at step {k}: expected the step-{k - 1} predictions of its neighbours {list(nb)}, "
                f"found messages from {sorted(got)}; run it on the graph it was designed for (unit delays)"
            )
        u = np.asarray(own, dtype=float) - yh @ m.C_tilde[n].T
        yf = yh + u @ d.B_innov[k][n].T
        if nb and k > 0:
            diff = np.concatenate([np.asarray(got[l], dtype=float) @ m.U - yh if l in got else np.zeros_like(yh) for l in nb], axis=1)
            yf = yf + diff @ d.B_cons[k][n].T
        xf = xh + (yf - xh @ m.G_r.T) @ d.K[k, n].T
        z = (xf if d.form == "filter" else xh) @ d.cost.L_block(n, k).T
        yn = yf @ m.A_tilde_r.T + xf @ m.A_check_r.T
        xn = xf @ d.system.A_at(0).T
        return {"y": yn, "x": xn}, z, yn @ m.U.T


def _m_norm(rows: Sequence[FloatArray], hoods: Sequence[np.ndarray], r: int) -> float:
    """||M||_2 of the block-sparse M (dense SVD when small, ARPACK otherwise)."""
    N = len(rows)
    n_tot = N * r
    if n_tot <= 600:
        Mf = np.zeros((n_tot, n_tot))
        for n, row in enumerate(rows):
            Mf[n * r : (n + 1) * r, np.concatenate([np.arange(l * r, (l + 1) * r) for l in hoods[n]])] = row
        return float(np.linalg.norm(Mf, 2))
    import scipy.sparse as sp
    from scipy.sparse.linalg import svds

    ii, jj, vv = [], [], []
    for n, row in enumerate(rows):
        cols = np.concatenate([np.arange(l * r, (l + 1) * r) for l in hoods[n]])
        I, J = np.meshgrid(np.arange(n * r, (n + 1) * r), cols, indexing="ij")
        ii.append(I.ravel())
        jj.append(J.ravel())
        vv.append(row.ravel())
    Ms = sp.csr_matrix((np.concatenate(vv), (np.concatenate(ii), np.concatenate(jj))), shape=(n_tot, n_tot))
    s = svds(Ms, k=1, return_singular_vectors=False, tol=1e-10, random_state=0)
    return float(s[0])


def tracking_bound(design: CIKFDesign, k: int, *, subspace: Literal["range", "full"] = "range") -> float:
    r"""Theorem 3 with given gains: λ_1 / (λ_m ||I - B^C_k - B^I_k D̃_H||_2).

    ``subspace="range"`` (default) takes the norm on range(G)^N, where every
    pseudo-state error lives (the reduced M_k); ``"full"`` as printed, on all of
    R^{NM}: there M_k acts as the identity on null(G)^N, so the norm is >= 1 and
    the bound <= λ_1/λ_m whenever G is singular. ``inf`` when the norm is 0.
    """
    if not isinstance(design, CIKFDesign):
        raise ShapeError(f"design: expected a CIKFDesign, found {type(design).__name__}")
    if subspace not in ("range", "full"):
        raise ShapeError(f"subspace: expected 'range' or 'full', found {subspace!r}")
    rows = design.m_rows(k)
    hoods = [np.array([n, *design.neighbors[n]]) for n in range(design.n_agents)]
    nrm = _m_norm(rows, hoods, design.model.rank)
    if subspace == "full" and not design.model.invertible:
        nrm = max(nrm, 1.0)
    m = design.model
    return float("inf") if nrm <= 1e-12 else m.lambda_1 / (m.lambda_m * nrm)
