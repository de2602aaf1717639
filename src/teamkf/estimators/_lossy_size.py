r"""The drop-aware design (:mod:`teamkf.estimators.team_lossy`) sized before it allocates anything.

Its arrays are counted from the horizon :math:`T`, the arrival model's delays :math:`\ell_{ji}` and the
measurement sizes alone (no loop over :math:`T`), with the shapes the design actually allocates:

* :math:`N = T d_y` innovation items (all agents' rows :math:`d_y`): the local filters' moments
  :math:`\Sigma` (:math:`N \times N`, up to four at once in measurement coordinates) and :math:`\Theta(k)`;
* :math:`R = \sum_i \sum_j d_y^j \max(0, T - \ell_{ji})` slot rows (every (agent, item) that can arrive):
  the fills :math:`H` (:math:`R \times N`) and, without ``memory``, :math:`E[f f^\top]` with its three
  :math:`R \times R` temporaries and the :math:`(R d_z)^2` Cholesky factor of :math:`\Gamma`;
  with ``memory = m`` the same per step over the live rows only;
* the per-step fills kept by the design: :math:`\sum_k \sum_i r_i(k)\,(k + 1) d_y^i` numbers,
  :math:`r_i(k)` the rows live at agent i at step k (cubic in :math:`T` without a memory).

With ``memory = m`` the windowed form (:mod:`teamkf.estimators._lossy_window`) is counted instead: arrays of a fixed
size per step (the lifted covariance, Γ of the live rows) plus the gains, fills and items kept for every step, counted
without the steady form's reuse (an upper bound: once it is steady nothing of the size of a step is kept).

Measured peaks (platoon-6, line graph, delay 2, p = 0.2, one core): T = 40: 88 MiB, 80: 304 MiB,
120: 652 MiB, 160: 1174 MiB; :func:`estimate` gives 59, 261, 607, 1095 MiB: it counts the arrays, not the interpreter, so it
stays a little below (never a premature refusal). memory = 5 (windowed): T = 80: 2.6 MiB, 400: 7.8 MiB above the process
before the design, estimated 5.9 and 17.6 MiB. T = 300: 3.9 GiB
estimated, 4.1 GiB measured (51 s of CPU); T = 3000: 2.5 TiB estimated, refused at once. ring-6-lossy (a two-way ring,
delay-2 links, p = 0.2), T = 300: full 3.9 GiB estimated, 4.2 GiB measured (34 s of CPU); memory = 16 (windowed): 89 MiB
estimated, 134 MiB peak RSS (5 s); T = 3000, memory = 16: 653 MiB estimated, 269 MiB peak RSS (10 s).

A refused design is told what fits (:func:`suggest`): the largest ``memory`` up to 2 ℓ_max + :data:`MEMORY_SLACK` that
fits the memory and the work limit, with its estimate, else the longest horizon that fits.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .. import _budget
from ..exceptions import ArgumentError


def _sum_u(a: float, b: float, p: int) -> float:
    """:math:`\\sum_{u=a}^{b} u^p` for p = 1, 2 (0 when b < a), in floating point (no overflow for huge T)."""
    if b < a:
        return 0.0

    def s(x: float) -> float:
        return x * (x + 1) / 2 if p == 1 else x * (x + 1) * (2 * x + 1) / 6

    return s(b) - s(a - 1)


def estimate(dy: Any, ell: Any, prob: Any, T: int, memory: int | None, dx: int, dz: int, prefix: bool, kinds: int = 1) -> tuple[float, float, float]:
    """(peak bytes, floating-point operations, Python loop iterations) of the design over ``T`` steps.

    Parameters
    ----------
    dy : sequence of int
        Measurement rows of each agent.
    ell, prob : (n, n) arrays
        Delays ``ell[j, i]`` and on-time probabilities ``prob[j, i]`` of the arrival model (0: never arrives).
    T : int
        The horizon.
    memory : int or None
        The design's ``memory`` option.
    dx, dz : int
        State and estimate sizes.
    prefix : bool
        One factorization for every step (no memory and a constant cost weight S).
    kinds : int
        Item kinds designed (``items="auto"`` designs both raw measurements and innovations where cheap): their kept fills
        and their work add up.
    """
    if memory is not None:  # the windowed form (:mod:`._lossy_window`): per-step arrays of a fixed size, kept results linear in T
        from ._lossy_window import estimate as windowed

        peak, flops, loops = windowed(dy, ell, prob, T, memory, dx, dz)
        return peak * kinds, flops * kinds, loops * kinds
    dy_a = np.asarray(dy, dtype=float)
    n = dy_a.size
    dyt = float(dy_a.sum())
    Tf = float(T)
    N = Tf * dyt
    R = S = F = Rk = 0.0  # slot rows, slots, kept fill numbers, live rows at the last step
    m = float(memory) if memory is not None else None
    for i in range(n):
        for j in range(n):
            if prob[j, i] <= 0:
                continue
            l_ = float(ell[j, i])
            c = max(0.0, Tf - l_)
            R += dy_a[j] * c
            S += c
            live = min(c, m) if m is not None else c
            Rk += dy_a[j] * live
            # fills: sum over k of (items of j live at i by k) x (k + 1) own innovations, times dy_j dy_i
            if m is None:  # items s <= k - l: count k - l + 1 for k = l .. T-1
                f = _sum_u(l_ + 1, Tf, 2) - l_ * _sum_u(l_ + 1, Tf, 1)
            else:  # count min(k - l + 1, m)
                k1 = min(Tf, l_ + m)  # u = k + 1 <= l + m: count u - l
                f = _sum_u(l_ + 1, k1, 2) - l_ * _sum_u(l_ + 1, k1, 1) + m * _sum_u(k1 + 1, Tf, 1)
            F += dy_a[j] * dy_a[i] * f
    Rz = R * dz
    moments = 4 * 8 * N * N + 8 * n * dx * dyt * Tf * Tf / 2  # Σ (up to four N x N in measurement coordinates), Θ(k)
    if prefix:
        early = max(8 * (3 * R * R + S * S), 8 * R * R + 3 * 8 * Rz * Rz) + 16 * R * N
        late = 8 * Rz * Rz + 8 * R * N + 8 * F
        flops = Rz**3 / 3 + 10 * R * R + 2 * R * N * N / n
    else:
        Rkz = Rk * dz
        early = 8 * R * N
        late = 8 * R * N + 8 * F + max(8 * (3 * Rk * Rk + S / max(R, 1) * Rk * Rk), 3 * 8 * Rkz * Rkz) + 16 * Rk * N
        flops = Tf * (Rkz**3 / 3 + 10 * Rk * Rk + 2 * Rk * N * N / n)
    flops += 2 * n * dz * F + 4 * N**3  # V2 = W Hᵀ per step; the moments' products
    late += 8 * F * (kinds - 1)  # every kind's fills are kept until the cheaper one is chosen
    flops *= kinds
    loops = kinds * (Tf * _budget.DESIGN_STEP_LOOPS + 10 * S)  # per step, and per slot (its item tuple)
    return moments + max(early, late), flops, loops


#: the largest memory a refusal suggests is 2 ℓ_max + MEMORY_SLACK steps (ℓ_max the largest geodesic delay); ring-6-lossy
#: (ℓ_max = 6, T = 60, p = 0.2): memory = 8, 12, 16 cost 2.1 %, 0.64 %, 0.18 % more than the full design
MEMORY_SLACK = 4


def _fits(
    system: Any, arr: Any, T: int, memory: int | None, dz: int, prefix: bool, kinds: int, avail: int | None, limit: float
) -> tuple[bool, float, float]:
    """(fits, peak bytes, optimistic seconds) of the design, against ``avail`` bytes and ``limit`` seconds."""
    peak, flops, loops = estimate(system.dy, arr.ell, arr.prob, T, memory, system.dx, dz, prefix, kinds)
    t = flops / _budget.FLOPS + loops / _budget.LOOPS
    return (avail is None or peak <= _budget.MEMORY_FRACTION * avail) and t <= limit, peak, t


def _longest(system: Any, arr: Any, T: int, memory: int | None, dz: int, prefix: bool, kinds: Any) -> int:
    """The longest horizon below T whose design with ``memory`` fits (bisection; 0: none)."""
    avail, limit = _budget.available_memory(), _budget.work_limit_s()
    lo, hi = 0, T
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if _fits(system, arr, mid, memory, dz, prefix, kinds(memory), avail, limit)[0]:
            lo = mid
        else:
            hi = mid
    return lo


def suggest(system: Any, arr: Any, T: int, memory: int | None, dz: int, kinds: Any = lambda m: 1) -> str:
    """What makes a refused design fit: a ``memory`` (the largest up to 2 ℓ_max + :data:`MEMORY_SLACK` below the given one), else
    the longest horizon with the smallest useful memory (ℓ_max + 1: items older than the largest delay can arrive)."""
    avail, limit = _budget.available_memory(), _budget.work_limit_s()
    live = arr.prob > 0
    lmax = int(np.max(np.where(live, arr.ell, 0)))
    top = min(2 * lmax + MEMORY_SLACK, T, memory - 1 if memory is not None else T)
    for m in range(top, lmax, -1):  # m <= ℓ_max: the items of the farthest agents are never live
        ok, peak, t = _fits(system, arr, T, m, dz, False, kinds(m), avail, limit)
        if ok:
            return (
                f"set the mtmse_lossy option memory = {m} (the items of the last {m} steps: about {_budget.format_bytes(peak)} and "
                f"{_budget.format_seconds(t)} or more; its exact cost is reported, see docs/lossy-design.md), or use a shorter horizon"
            )
    m = lmax + 1 if memory is None else min(memory, lmax + 1)
    lo = _longest(system, arr, T, m, dz, False, kinds)  # what a memory keeps grows like T: counted without the steady form's reuse
    if lo < 1:
        return "use a smaller team or fewer measurement rows"
    return f"use a horizon of at most {lo:,} steps with memory = {m} (with a memory the kept gains, fills and items grow like T)"


def suggest_resend(system: Any, arr: Any, T: int, dz: int, prefix: bool, kinds: Any, resend: int) -> str:
    """What makes a refused re-sending design (which takes no ``memory``) fit: the longest horizon, or ``resend = 1`` with a memory."""
    lo = _longest(system, arr, T, None, dz, prefix, kinds)
    longest = f"use a horizon of at most {lo:,} steps (resend = {resend} takes no memory)" if lo >= 1 else "use a smaller team"
    return f"{longest}, or resend = 1 and {suggest(system, arr, T, None, dz, kinds)}"


def check(system: Any, arr: Any, T: int, memory: int | None, dz: int, prefix: bool, kinds: Any = lambda m: 1, *, resend: int = 1) -> None:
    """Refuse, before anything is allocated, a drop-aware design whose memory or time exceeds what the machine has.

    ``kinds(m)``: how many item kinds the design computes with memory m (``items="auto"`` may design both).
    The refusal names what fits (:func:`suggest`): a ``memory = m`` with its estimate, or the longest horizon; for
    ``resend`` > 1, which takes no memory, the longest horizon or ``resend = 1`` with a memory (:func:`suggest_resend`).

    Raises
    ------
    teamkf.exceptions.ResourceError
        Naming ``horizon`` (or ``memory``), with the estimate and what to change.
    """
    peak, flops, loops = estimate(system.dy, arr.ell, arr.prob, T, memory, system.dx, dz, prefix, kinds(memory))
    what = f"the mtmse_lossy design over T = {T:,} steps" + (f" (memory = {memory})" if memory is not None else "")
    if not _fits(system, arr, T, memory, dz, prefix, kinds(memory), _budget.available_memory(), _budget.work_limit_s())[0]:
        fix = suggest(system, arr, T, memory, dz, kinds) if resend == 1 else suggest_resend(system, arr, T, dz, prefix, kinds, resend)
    else:
        fix = ""
    _budget.check_memory(peak, what, argument="horizon", fix=fix)
    t = _budget.check_work(flops, what, argument="horizon", fix=fix, loops=loops)
    _budget.announce(t, what)


def _flag(v: Any, key: str) -> bool:
    if isinstance(v, (bool, np.bool_)):
        return bool(v)
    raise ArgumentError(f"{key}: expected true or false, found {v!r}", argument=key)


def check_fill(v: Any, key: str) -> Any:
    """``mtmse_lossy``'s ``fill``: true (missed items filled from the own items), false (by zero) or "held"."""
    if isinstance(v, (bool, np.bool_)) or v == "held":
        return v if v == "held" else bool(v)
    raise ArgumentError(f'{key}: expected true (filled from the own items), false (by zero) or "held" (the class containing the rule), found {v!r}')


def fill_options() -> tuple[Any, ...]:
    """``mtmse_lossy``'s registry options ``fill`` and ``patterns`` (``fill = "held"``: :mod:`teamkf.estimators._lossy_rulefill`)."""
    from .. import _validation as V
    from .registry import Option

    return (
        Option(
            name="fill",
            default=True,
            check=check_fill,
            doc='missed items: from the own items (true), zero (false), "held": the class containing the rule',
        ),
        Option(
            name="patterns",
            default=None,
            check=lambda v, k: None if v is None else V.integer(v, k, minimum=2),
            doc='fill = "held" or adaptive: link patterns sampled for the fit and the cost (none: fill = "held" all when few, else 400; adaptive 200)',
        ),
        Option(
            name="held_window",
            default=None,
            check=lambda v, k: None if v is None else V.integer(v, k, minimum=1),
            doc='fill = "held": the window W of its conditional-mean feature (none: the largest geodesic delay + 2)',
        ),
    )


def form_options() -> tuple[Any, ...]:
    """``mtmse_lossy``'s registry options of its other classes: ``keyed``, ``resend``, ``adaptive`` and ``summary``."""
    from .. import _validation as V
    from .registry import Option

    return (
        Option(
            name="keyed",
            default=0,
            check=lambda v, k: V.integer(v, k, minimum=0, maximum=1),
            doc="1: gains keyed on the current arrivals (the items due at each step; small teams, no memory); 0: pattern-independent",
        ),
        Option(
            name="resend",
            default=1,
            check=lambda v, k: V.integer(v, k, minimum=1, maximum=16),
            doc="r: each packet carries the sender's last r items (a lost item can arrive later; exact cost); 1: one item",
        ),
        Option(
            name="adaptive",
            default=False,
            check=lambda v, k: _flag(v, k),
            doc="true: gains also on each agent's exact conditional means of the recent states given what it holds "
            "(re-weighted with the realized pattern; cost sampled over patterns, paired with resend = r's exact cost)",
        ),
        Option(
            name="summary",
            default=0,
            check=lambda v, k: V.integer(v, k, minimum=0, maximum=32),
            doc="M: agents send their own filter estimate, gains keyed on its age (< M steps; exact cost); 0: items",
        ),
    )
