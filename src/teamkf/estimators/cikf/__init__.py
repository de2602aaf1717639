r"""Consensus+Innovations Kalman filter (CIKF) with optimized gains (Das & Moura, IEEE TSP 2016).

Every agent n keeps an estimate of the *pseudo-state* y = G x and of the
state x. At step k it combines its own pseudo-observation with its
neighbours' previous pseudo-state predictions (one exchange per step, unit
delay), then updates its state estimate from its pseudo-state estimate:

.. math::

    \hat y^n_{k|k} &= \hat y^n_{k|k-1} + \sum_{l \in \Omega_n} B^{nl}_k (\hat y^l_{k|k-1} - \hat y^n_{k|k-1})
                      + B^{nn}_k (\tilde z^n_k - \tilde H_n \hat y^n_{k|k-1} - \check H_n \hat x^n_{k|k-1})   \quad (21) \\
    \hat x^n_{k|k} &= \hat x^n_{k|k-1} + K^n_k (\hat y^n_{k|k} - G \hat x^n_{k|k-1})                        \quad (22) \\
    \hat y^n_{k+1|k} &= \tilde A \hat y^n_{k|k} + \check A \hat x^n_{k|k}, \qquad
    \hat x^n_{k+1|k} = A \hat x^n_{k|k}                                                                   \quad (23, 24)

Notation (paper -> teamkf; steps 0-based, the paper's i is our k)
-----------------------------------------------------------------
================================  ==============================================================
paper                             here
================================  ==============================================================
M, N                              ``system.dx``, ``system.n_agents``
A, V, Sigma_0                     ``system.A``, ``system.Q``, ``system.Sigma_x`` (x̄_0 = 0)
H_n, R_n, z^n_i                   ``system.C[n]``, ``system.R[n]``, y_n(k)
H̄_n = H_n' R_n^-1 H_n             ``model.H_bar[n]``                                   (5)
G = sum_n H̄_n                     ``model.G``                                          (7)
G†, Ĩ = I - G† G                  ``model.G_pinv``, ``model.I_tilde``                  (15)
Ã = G A G†, Ǎ = G A Ĩ             ``model.A_tilde``, ``model.A_check``                 (11, 13)
H̃_n = H̄_n G†, Ȟ_n = H̄_n Ĩ         ``model.H_tilde[n]``, ``model.H_check[n]``           (12, 14)
λ_1, λ_m                          smallest / largest non-zero eigenvalue of G (Theorem 3)
Ω_n                               ``graph.in_neighbors(n)`` (every edge must have delay 1)
B^{nl}, B^{nn}, K^n               :meth:`CIKFDesign.paper_gains` (full coordinates)
P, Σ, Π, Γ                        pseudo-state, state and cross error covariances (34)-(40)
================================  ==============================================================

Reduced coordinates (how G need not be invertible)
--------------------------------------------------
Let G = U Λ U' with U (M x r) an orthonormal basis of range(G) (eigenvalues
below ``G_RTOL`` times the largest count as zero). Every pseudo-state error
lies in range(G) (e_{0|-1} = G(x_0 - x̄_0), and (32) maps into range(G)),
and so does every gain's output, so the filter runs on y_r = U' y in R^r:

* G_r = Λ U' (r x M), Ã_r = U' Ã U = Λ U' A U Λ^-1, Ǎ_r = U' Ǎ = Λ U' A Ĩ;
* Ȟ_n = 0 identically: null(G) is the intersection of the null spaces of
  the PSD H̄_n, so H̄_n Ĩ = 0 and H_n Ĩ = 0 — the Ȟ terms of (21), (30),
  (41)-(42) and Theorem 4 drop out (checked literally in the tests);
* the M-dimensional innovation z̃^n - H̃_n ŷ^n = H_n' R_n^-1 u^n is a
  full-column-rank image of the M_n-dimensional u^n = z^n - C̃_n ŷ_r^n with
  C̃_n = H_n U Λ^-1, so the Theorem-4 gain on it is B_u^n = B^{nn} H_n' R_n^-1
  (r x M_n) and the estimate is the same; :meth:`CIKFDesign.paper_gains`
  maps back to B^{nn} = U B_u^n (H_n' R_n^-1)†, B^{nl} = U B_r^{nl} U',
  K^n = K_r^n U'.

In these coordinates Σ_ν̃ has size d_n r + M_n instead of (d_n + 1) M and
its innovation block C̃ P C̃' + R_n is positive definite.

The corrected covariance iterations (Algorithm 2)
-------------------------------------------------
Derived from Lemma 2, eqs. (30)-(33), and the definitions (34)-(40); with
M_k = I - B^C - B^I D̃_H (block-sparse, the graph's pattern), F_k = I - K (I ⊗ G)
(block-diagonal):

.. math::

    \Gamma &= \Pi_{k|k-1} M_k^\top                                                   && (41) \\
    P_{k|k} &= M_k P_{k|k-1} M_k^\top + B^I \bar D_H B^{I\top}                         && (42) \\
    \Sigma_{k|k} &= F \Sigma_{k|k-1} F^\top + F \Gamma K^\top + K \Gamma^\top F^\top + K P_{k|k} K^\top  && (43)^* \\
    \Pi_{k|k} &= F \Gamma + K P_{k|k}                                                 && (44) \\
    P_{k+1|k} &= \tilde A P \tilde A^\top + \check A \Sigma \check A^\top + \tilde A \Pi^\top \check A^\top
                 + \check A \Pi \tilde A^\top + (1 1^\top) \otimes (G V G)              && (45)^* \\
    \Sigma_{k+1|k} &= A \Sigma A^\top + (1 1^\top) \otimes V                          && (46) \\
    \Pi_{k+1|k} &= A \Pi \tilde A^\top + A \Sigma \check A^\top + (1 1^\top) \otimes (V G)   && (47)

(all Ã, Ǎ, A act blockwise, I_N ⊗ ·; the filter-step covariances on the
right of (45)-(47)). Corrections to the extracted text (*): in (43) the cross
terms need Γ_k, not Π_{k|k-1} (ε_{k|k} = F ε_{k|k-1} + K e_{k|k} and
E[ε_{k|k-1} e_{k|k}'] = Γ_k, eq. 40); in (45) the Σ and cross terms need Ǎ,
not Ã (e_{k+1|k} = Ã e_{k|k} + Ǎ ε_{k|k} + G v_k, eq. 32); the initial
conditions are (1 1') ⊗ Σ_0, (1 1') ⊗ (G Σ_0 G), (1 1') ⊗ (Σ_0 G) (the
printed J ⊗ Σ_0 with J = (1 1') ⊗ I has the wrong size). These forms hold
for *any* gains (Joseph-like), so the iteration gives the true covariance of
the filter that is run, whatever the pseudo-inverse cut-off.

Theorem 4 (the gains), in reduced coordinates, with ν̃^n = [e^n - e^{l_1}; ...;
e^n - e^{l_d}; u^n], u^n = C̃_n e^n + r^n and ν^n = G_r ε^n_{k|k-1} - e^n_{k|k}:

.. math::

    \hat B^n = \Sigma_{e\tilde\nu} \Sigma_{\tilde\nu}^{+}, \quad
    \Sigma_{e\tilde\nu} = [P^{nn} - P^{nl_1}, \dots, P^{nn} - P^{nl_d}, P^{nn} \tilde C_n^\top], \\
    [\Sigma_{\tilde\nu}]_{qs} = P^{nn} - P^{nl_s} - P^{l_q n} + P^{l_q l_s}, \quad
    [\Sigma_{\tilde\nu}]_{q,u} = (P^{nn} - P^{l_q n}) \tilde C_n^\top, \quad
    [\Sigma_{\tilde\nu}]_{u,u} = \tilde C_n P^{nn} \tilde C_n^\top + R_n, \\
    K^n = (\Sigma^{nn} G_r^\top - \Gamma^{nn}) \Sigma_\nu^{+}, \quad
    \Sigma_\nu = G_r \Sigma^{nn} G_r^\top - G_r \Gamma^{nn} - \Gamma^{nn\top} G_r^\top + P^{nn}_{k|k}.

The paper writes Σ_{yν̃} = E[(y - ȳ) ν̃'] and drops E[(ŷ^n - ȳ) ν̃'] — the
MSE-minimizing gain is E[e^n ν̃'] Σ_ν̃^+, which is what its block formulas
(and ours) compute.

The pseudo-inverse cut-off
--------------------------
Σ_ν̃ is singular at k = 0 (all agents start from the same prior, so every
difference e^n - e^l is exactly 0) and, later, its difference blocks are
formed by cancellation (P^{nn} - P^{nl} - P^{ln} + P^{ll} of nearly equal
blocks), so their smallest eigenvalues carry absolute errors of order
eps ||P||. ``_psd_solve`` (``pinv="cholesky"``, default) runs a pivoted
Cholesky that stops when the largest remaining conditional variance is
below ``rcond`` times the largest variance: innovation components that are
(numerically) predictable from the kept ones get zero gain, which is exact
for the consistent systems of Theorem 4 when Σ_ν̃ is exactly singular.
``pinv="eigh"`` truncates the eigen-decomposition at ``rcond * lambda_max``.
The default ``rcond = 1e-9`` stays three orders of magnitude above the
round-off level of the differences; at M = N = 50 it costs 5e-4 dB against
1e-12, and neither drifts (``docs/cikf.md``, tested).

Cost (M = N = 50: NM = 2500)
----------------------------
M_k has N + 2|E| non-zero M x M blocks and K, F, I ⊗ Ã, I ⊗ Ǎ are
block-diagonal, so every product is done block-wise: one GEMM per agent over
its closed neighbourhood for M_k, batched GEMMs for the block-diagonal
factors. No NM x NM matrix is ever multiplied by another as a dense matrix
(``method="dense"`` does exactly that, as the benchmark's baseline).

``method="joint"`` (the default for the corrected equations) runs the same
equations as one recursion on the joint covariance J = cov([e; ε])
(N(r + M) square, agent-major): the update (41)-(42) is M_k on the e-rows
of J, and (43)-(47) collapse into one (r + M) x (r + M) map per agent,
Φ^n = [[Ã + Ǎ K^n, Ǎ F^n], [A K^n, A F^n]], applied on both sides; both
two-sided products are computed on the upper block triangle only, in place
(``_iterate_joint``). At M = N = 50 that is 12.2 GFLOP per step against 14.4
for the block-operator form, in fewer and larger GEMMs, and J (plus
(M_k P)' when small) is all the memory. Theorem 4's per-agent pivoted
Cholesky factorizations run on the worker threads with the GIL released
(``teamkf._lapack``). ``method="structured"`` keeps the block-operator
arithmetic that ``tests/unit/test_cikf_reference.py`` pins entry by entry.
The two differ only in the rounding: Σ, P, the stage costs and the errors
agree to ~1e-12, but Theorem 4's consensus gains only to ~1e-8, because
Σ_ν̃ is formed by cancellation (the structured method itself moves that much
when P is scaled by 1 + 2^-52, see ``tests/unit/test_cikf_joint.py``), so
gains are compared by what they produce.

Modules
-------
=========================================  ====================================================================
:mod:`~teamkf.estimators.cikf.model`       Proposition 1: the pseudo-state model (G, Ã, Ǎ, H̃_n in reduced coordinates)
:mod:`~teamkf.estimators.cikf.gains`       Theorem 4: the gains of one step, the pseudo-inverse cut-off
:mod:`~teamkf.estimators.cikf.kernels`     the block products of Algorithm 2 and the worker pool
:mod:`~teamkf.estimators.cikf.recursion`   Algorithm 2, block-operator form (``method="structured"``, ``"dense"``)
:mod:`~teamkf.estimators.cikf.joint`       Algorithm 2 on cov([e; ε]) (``method="joint"``, the default)
:mod:`~teamkf.estimators.cikf.filter`      :class:`CIKFDesign`, the online agents :class:`CIKFAgent`, :func:`tracking_bound`
:mod:`~teamkf.estimators.cikf.capacity`    Theorem 3: :func:`tracking_capacity`, :func:`tracking_capacity_upper_bound`
:mod:`~teamkf.estimators.cikf.design`      the entry point :func:`design_cikf` and the ``cikf`` family record
=========================================  ====================================================================

References
----------
.. [1] S. Das and J. M. F. Moura, "Consensus+Innovations Distributed Kalman
   Filter with Optimized Gains", IEEE Trans. Signal Processing, 2016 (eqs.
   cited above; Algorithms 1-2; Theorems 3-4).
"""

# the private names are re-exported for the tests and benchmarks that import them from here
from .capacity import TrackingCapacity, tracking_capacity, tracking_capacity_upper_bound
from .design import _mse_cost, design_cikf  # noqa: F401
from .filter import CIKFAgent, CIKFDesign, tracking_bound
from .gains import DEFAULT_RCOND, _psd_solve  # noqa: F401
from .model import G_RTOL, PseudoStateModel, _neighbors, pseudo_state_model  # noqa: F401

__all__ = [
    "PseudoStateModel",
    "pseudo_state_model",
    "CIKFDesign",
    "CIKFAgent",
    "design_cikf",
    "TrackingCapacity",
    "tracking_bound",
    "tracking_capacity",
    "tracking_capacity_upper_bound",
    "G_RTOL",
    "DEFAULT_RCOND",
]
