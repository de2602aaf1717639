"""Relative-closeness assertions for the CIKF comparisons (max |got - want| / max |want|)."""

from __future__ import annotations

import numpy as np

RTOL = 1e-10


def close(got, want, what, rtol=RTOL):
    got, want = np.asarray(got, dtype=float), np.asarray(want, dtype=float)
    assert got.shape == want.shape, what
    scale = max(float(np.abs(want).max()), 1e-300)
    err = float(np.abs(got - want).max()) / scale
    assert err <= rtol, f"{what}: max relative difference {err:.2e} > {rtol:.0e}"


def compare_to_reference(d, ref, *, gains=True):
    """A CIKF design against ``cikf_reference.reference_iterate``'s output: covariances, traces, stage costs, and
    (``gains``) the consensus, innovation and state gains entry by entry."""
    if gains:
        for k in range(d.horizon):
            for n in range(d.n_agents):
                close(d.B_cons[k][n], ref["B_cons"][k][n], f"B_cons[{k}][{n}]")
                close(d.B_innov[k][n], ref["B_innov"][k][n], f"B_innov[{k}][{n}]")
        close(d.K, ref["K"], "K")
    close(d.Sigma_pred, ref["Sigma_pred"], "Sigma_pred")
    close(d.Sigma_filt, ref["Sigma_filt"], "Sigma_filt")
    close(d.P_pred_trace, ref["P_pred_trace"], "P_pred_trace")
    close(d.stage_costs, ref["stage"], "stage_costs")
