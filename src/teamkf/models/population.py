"""A population of interference-coupled scalar agents (Abedinpour Fallah et al., 2017).

``N`` agents with independent scalar dynamics are coupled only through their
measurements, each of which contains the population mean (eqs. 1-2); every
agent is stabilized by certainty-equivalent feedback on its own estimate
(eq. 4)::

    x_{k+1,i} = a x_{k,i} + b u_{k,i} + w_{k,i}                       (1)
    y_{k,i}   = c x_{k,i} + h m_k + v_{k,i},   m_k = (1/N) sum_j x_{k,j} (2)
    u_{k,i}   = -f xhat_{k,i}                                          (4)

Notation
--------
==============  ==================================================================
symbol          meaning
==============  ==================================================================
``n_agents``    N, the number of agents (any positive integer, 10**9 included:
                the statistics are computed exactly without simulating agents)
``a, b``        scalar dynamics (eq. 1); the paper takes b > 0
``c, h``        own-state and mean-state gains of the measurement (eq. 2)
``f``           feedback gain u = -f xhat (eq. 4); ``a_f = a - b f``
``sigma_w``     std of the process noise w_{k,i}
``sigma_v``     std of the measurement noise v_{k,i} (> 0)
``sigma_0``     std of the initial state x_{0,i} ~ N(x0_mean, sigma_0**2)
``x0_mean``     mean of the initial states (the paper's x-bar_0)
``memory``      0: exact growing-memory ("bulk") filter; n > 0: the finite-memory
                filter of Theorem 2 that keeps the last n measurements
``r``           control weight of the LQ cost (eq. 3); not in the paper's
                numerical section, which never states it -- we take r = 1
==============  ==================================================================

Time convention: states x_0 .. x_T, measurements y_1 .. y_T (the paper's filter
starts at K_1, a 1 x 1 gain on y_1), and xhat_0 = x0_mean, so u_0 = -f x0_mean.

Examples
--------
>>> m = PopulationModel(n_agents=1000, a=2.5, f=2.0)
>>> m.a_f
0.5
>>> cdma = cdma_population(100, a=2.0, alpha=0.5, beta=2.0, h_prime=10.0, f=1.5)
>>> round(cdma.c, 6), round(cdma.h, 6)
(0.9, 10.0)
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from .._validation import positive_int
from ..exceptions import ArgumentError, ShapeError

__all__ = [
    "PopulationModel",
    "cdma_population",
]


def _real(x: Any, name: str) -> float:
    if isinstance(x, (bool, np.bool_)) or not isinstance(x, (int, float, np.integer, np.floating)):
        raise ArgumentError(f"{name}: expected a real number, found {x!r}")
    v = float(x)
    if not math.isfinite(v):
        raise ArgumentError(f"{name}: expected a finite number, found {v!r}")
    return v


def _positive(x: Any, name: str, *, strict: bool = True, hint: str = "") -> float:
    v = _real(x, name)
    if (strict and v <= 0) or (not strict and v < 0):
        want = "> 0" if strict else ">= 0"
        raise ArgumentError(f"{name}: expected a number {want}, found {v!r}{'; ' + hint if hint else ''}")
    return v


@dataclass(frozen=True)
class PopulationModel:
    """N interference-coupled scalar agents under feedback u = -f xhat (eqs. 1, 2, 4).

    Parameters
    ----------
    n_agents : int
        N >= 1 (10**9 is fine: nothing is simulated per agent by the filters).
    a, f : float
        Dynamics and feedback gain; ``a_f = a - b f`` is the closed-loop pole of
        the certainty-equivalent controller under perfect observation.
    b, c : float, > 0
    h : float, >= 0
        Interference gain (h = 0 decouples the agents).
    sigma_w, sigma_0 : float, >= 0
    sigma_v : float, > 0
        Needed so that every innovation variance is >= sigma_v**2 > 0.
    x0_mean : float
    memory : int, >= 0
        0 for the exact growing-memory filter, n for the memory-n filter (Thm. 2).
    r : float, > 0
        Control weight in the LQ cost (3) (default 1; the paper does not state it).

    Raises
    ------
    teamkf.exceptions.ShapeError
        Naming the argument, with the value found and what was expected.
    """

    n_agents: int
    a: float
    f: float
    b: float = 1.0
    c: float = 1.0
    h: float = 1.0
    sigma_w: float = 1.0
    sigma_v: float = 1.0
    sigma_0: float = 1.0
    x0_mean: float = 0.0
    memory: int = 0
    r: float = 1.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "n_agents", positive_int(self.n_agents, "n_agents"))
        object.__setattr__(self, "a", _real(self.a, "a"))
        object.__setattr__(self, "f", _real(self.f, "f"))
        object.__setattr__(self, "b", _positive(self.b, "b", hint="the paper's b > 0; flip the sign of f instead"))
        object.__setattr__(self, "c", _positive(self.c, "c", hint="the own-state gain of eq. (2) must be positive"))
        object.__setattr__(self, "h", _positive(self.h, "h", strict=False, hint="use h = 0 for agents without interference"))
        object.__setattr__(self, "sigma_w", _positive(self.sigma_w, "sigma_w", strict=False))
        object.__setattr__(
            self,
            "sigma_v",
            _positive(self.sigma_v, "sigma_v", hint="the measurement noise must be strictly positive (innovation variances are >= sigma_v**2)"),
        )
        object.__setattr__(self, "sigma_0", _positive(self.sigma_0, "sigma_0", strict=False))
        object.__setattr__(self, "x0_mean", _real(self.x0_mean, "x0_mean"))
        object.__setattr__(self, "memory", positive_int(self.memory, "memory", minimum=0))
        object.__setattr__(self, "r", _positive(self.r, "r"))

    @property
    def a_f(self) -> float:
        """Closed-loop pole under perfect observation, a - b f."""
        return self.a - self.b * self.f

    @property
    def q(self) -> float:
        """Process-noise variance sigma_w**2."""
        return self.sigma_w**2

    @property
    def r_v(self) -> float:
        """Measurement-noise variance sigma_v**2."""
        return self.sigma_v**2

    @property
    def p0(self) -> float:
        """Initial-state variance sigma_0**2."""
        return self.sigma_0**2

    def with_(self, **changes: Any) -> "PopulationModel":
        """A copy with some parameters changed (``a_f=`` sets f = (a - a_f)/b)."""
        if "a_f" in changes:
            af = _real(changes.pop("a_f"), "a_f")
            a = changes.get("a", self.a)
            b = changes.get("b", self.b)
            changes["f"] = (a - af) / b
        return replace(self, **changes)

    @classmethod
    def from_af(cls, n_agents: int, a: float, a_f: float, **kw: Any) -> "PopulationModel":
        """Build from the closed-loop pole a_f instead of f (f = (a - a_f)/b)."""
        b = _real(kw.get("b", 1.0), "b")
        return cls(n_agents=n_agents, a=a, f=(_real(a, "a") - _real(a_f, "a_f")) / b, **kw)


def cdma_population(
    n_agents: int,
    a: float,
    alpha: float,
    beta: float,
    h_prime: float,
    *,
    f: float,
    **kw: Any,
) -> PopulationModel:
    """The CDMA power-control population of Section 5 (eqs. 63-64).

    User i sends power p = beta x_{k,i}; the uplink gain is alpha; the despread
    signal of user i carries the others' received power with processing gain
    h'/N. With y = z - sigma_th**2 this is model (2) with::

        c = alpha beta (1 - h'/N),   h = alpha beta h'                    (64)

    Parameters
    ----------
    n_agents : int
        N users.
    a : float
        State gain of each user's dynamics.
    alpha, beta : float, > 0
        Mean-squared uplink channel gain and power-per-state factor.
    h_prime : float, 0 <= h' < N
        Processing-gain numerator (c > 0 needs h' < N).
    f : float
        Feedback gain.
    **kw
        Other :class:`PopulationModel` fields (b, sigma_w, sigma_v, ...).

    Examples
    --------
    >>> m = cdma_population(1000, a=1.0, alpha=1.0, beta=1.0, h_prime=1.0, f=0.5)
    >>> m.c, m.h
    (0.999, 1.0)
    """
    N = positive_int(n_agents, "n_agents")
    al = _positive(alpha, "alpha")
    be = _positive(beta, "beta")
    hp = _positive(h_prime, "h_prime", strict=False)
    if hp >= N:
        raise ShapeError(f"h_prime: expected 0 <= h_prime < n_agents = {N} (so that c = alpha beta (1 - h'/N) > 0), found {hp!r}")
    return PopulationModel(n_agents=N, a=a, f=f, c=al * be * (1.0 - hp / N), h=al * be * hp, **kw)
