"""The steady-state filters as linear time-invariant systems (for streaming long logs).

After its warm-up, a steady-state design of the centralized filter, MTMSE or
per-agent MMSE is one linear time-invariant map from the measurements to the
estimates: a common one-step predictor

    x̂(a+1) = M x̂(a) + N y(a),     M = A (I - K̄ C),  N = A K̄,   x̂(0) = 0      (eq. 20)

and a finite window of the c most recent measurements,

    z(k) = G x̂(k - c + 1) + Σ_{l=0}^{c-1} H_l y(k - l)        (k >= start),

where c is the common lag (1 for the centralized filter). The steps k < start
use the exact warm-up gains of the design (run them with its online agents).
"""

from __future__ import annotations

from dataclasses import dataclass

from .._validation import FloatArray

__all__ = ["SteadyForm"]


@dataclass(frozen=True, eq=False)
class SteadyForm:
    """z(k) = G x̂(k-c+1) + Σ_l H[l] y(k-l) for k >= start, x̂(a+1) = M x̂(a) + N y(a), x̂(0) = 0.

    Attributes
    ----------
    M : (d_x, d_x)
    N : (d_x, d_y)          d_y = Σ_i d_y^i (the stacked measurement)
    G : (n d_z, d_x)
    H : (c, n d_z, d_y)
    start : int             first step the form holds (the steps before use the warm-up gains)
    """

    M: FloatArray
    N: FloatArray
    G: FloatArray
    H: FloatArray
    start: int

    @property
    def lag(self) -> int:
        """c: z(k) uses x̂(k - c + 1) and y(k - c + 1 .. k)."""
        return int(self.H.shape[0])
