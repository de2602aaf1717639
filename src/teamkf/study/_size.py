"""A team scenario sized from its raw tables, before the graph or the information structure is built.

Reading a team scenario builds its communication graph (the all-pairs delays)
and its information structure (each agent's windows of the others' measurements):
work and memory that grow like :math:`n^2` in the number of agents :math:`n`, and the team
designs then grow faster. :func:`check_team_size` estimates both from the raw
tables alone (the length of ``agents``, the rows of each ``C``, the graph's kind and
delay, the horizon and the estimators), in :math:`O(n)`, and refuses with one
:class:`~teamkf.exceptions.ResourceError` naming ``agents`` when

* the memory of reading the scenario, :math:`m_{\\text{read}} = \\beta\\, n^2` bytes
  (:data:`PAIR_BYTES_BY_KIND` per agent pair, :data:`PAIR_BYTES` for an edge list), exceeds what the machine has;
* the window innovation covariance of a team design (``mtmse``, ``mmse``),
  :math:`m_{\\text{win}} = 24\\,(w\\, d_y)^2` bytes with :math:`w = \\min(c, T)` the window of
  :math:`c` (the common lag) steps and :math:`d_y` all agents' measurement rows, exceeds it;
* the work, :math:`t = n^2 \\, (\\tau_{\\text{read}} + T_{\\text{eff}}\\, s\\, \\tau_{\\text{step}})`
  seconds with :math:`s` the number of team designs (:data:`PAIR_SECONDS`,
  :data:`PAIR_STEP_SECONDS`, measured on one core and rounded down), exceeds
  :func:`teamkf._budget.work_limit_s`.

The common lag of the graph's full information structure is its weighted diameter:
:math:`(n-1)\\delta` for a line, :math:`\\lfloor n/2 \\rfloor \\delta` for a ring,
:math:`2\\delta` for a star, :math:`\\delta` for a complete graph (``delay`` :math:`= \\delta`); an explicit
``[information] common_lag`` is used as written, and an explicit edge list counts as 1 (a lower bound).
A request that passes but takes long announces its estimate on a terminal (Ctrl-C stops it).
"""

from __future__ import annotations

from typing import Any, Mapping

from .. import _budget

__all__ = ["check_team_size", "PAIR_BYTES", "PAIR_BYTES_BY_KIND", "PAIR_SECONDS", "PAIR_STEP_SECONDS", "SMALL_TEAM"]

#: bytes per agent pair while a scenario is read, at peak (graph edges, geodesic delays, windows), by graph kind; measured
#: (peak RSS of scenario_from_dict, one "local" estimator) at n = 1000 and 2000: line 273 and 255, ring 271 and 254,
#: complete 312 and 314, star 62 and 34 (at n = 300 the interpreter's baseline hid part of it: 199, 166, 226, 26);
#: an edge list counts as 24 (three 8-byte all-pairs arrays)
PAIR_BYTES_BY_KIND = {"line": 250.0, "ring": 250.0, "complete": 300.0, "star": 24.0}
#: bytes per agent pair of an edge list or an unknown kind (a lower bound)
PAIR_BYTES = 24.0
#: CPU seconds per agent pair to build and check the graph and the information structure (measured 10 to 15 us at n = 300)
PAIR_SECONDS = 5e-6
#: CPU seconds per agent pair and step of a team design (1.4 us on a complete graph to 60 us on a ring, measured)
PAIR_STEP_SECONDS = 1e-6
#: teams up to this size are not sized (they read in well under a second)
SMALL_TEAM = 200


def _rows(agent: Any) -> int:
    """Rows of an agent's C as written (1 when it cannot tell: the lower bound; the full check comes later)."""
    C = agent.get("C") if isinstance(agent, Mapping) else None
    if isinstance(C, list) and C and isinstance(C[0], list):
        return max(len(C), 1)
    return 1


def _lag(raw: Mapping[str, Any], n: int) -> int:
    """The common lag of the scenario's information structure (a lower bound where it cannot tell)."""
    info = raw.get("information")
    if isinstance(info, Mapping):
        c = info.get("common_lag")
        return c if isinstance(c, int) and not isinstance(c, bool) and c >= 1 else 1
    g = raw.get("graph")
    if not isinstance(g, Mapping) or "edges" in g:
        return 1
    d = g.get("delay", 1)
    d = d if isinstance(d, int) and not isinstance(d, bool) and d >= 1 else 1
    kind = g.get("kind")
    hops = {"line": n - 1, "ring": n // 2, "star": 2 if n > 2 else 1, "complete": 1}.get(kind if isinstance(kind, str) else "", 1)
    return max(hops * d, 1)


def check_team_size(raw: Mapping[str, Any], horizon: int | None, families: Mapping[str, Any]) -> None:
    """Refuse, from the raw tables and before anything of size :math:`n^2` is built, a team scenario too large for the machine.

    Parameters
    ----------
    raw : mapping
        The scenario's tables as read (``agents`` a list; everything else may still be wrong: it is checked later).
    horizon : int or None
        The checked horizon (None: steady state, counted as one window of steps).
    families : mapping
        The registered families (their ``uses`` tells the team designs, which build window covariances).

    Raises
    ------
    teamkf.exceptions.ResourceError
        Naming ``agents``, with the estimate and what to change.
    """
    agents = raw.get("agents")
    if not isinstance(agents, list) or not agents:
        return
    n = len(agents)
    pairs = float(n) * float(n)
    fix = (
        "use fewer agents (reading a team grows like n^2 and its team designs faster), a reduced [information] table, "
        "or a [population] scenario for very large teams"
    )
    big = n > SMALL_TEAM
    if big:
        g = raw.get("graph")
        kind = g.get("kind") if isinstance(g, Mapping) and "edges" not in g else None
        per_pair = PAIR_BYTES_BY_KIND.get(kind, PAIR_BYTES) if isinstance(kind, str) else PAIR_BYTES
        _budget.check_memory(
            pairs * per_pair,
            f"reading a team of {n:,} agents ({per_pair:.0f} bytes for each of its n^2 = {pairs:.3g} agent pairs: edges, delays, windows)",
            argument="agents",
            fix=fix,
        )
    names = raw.get("estimators")
    names = [e for e in names if isinstance(e, str)] if isinstance(names, list) else []
    teams = [e for e in names if getattr(families.get(e), "uses", None) == "structure"]
    c = _lag(raw, n)
    T = horizon if horizon is not None else c
    if teams:
        dy = sum(_rows(a) for a in agents)
        w = min(c, T)
        argument = "agents" if big else ("information.common_lag" if isinstance(raw.get("information"), Mapping) else "graph.delay")
        fix = fix if big else f"use a smaller {argument} (the window of a team design is the common lag: {c:,} steps here) or a finite horizon"
        _budget.check_memory(
            24.0 * float(w * dy) ** 2,
            f"the {teams[0]} design of a team of {n:,} agents (its window of {w:,} steps x {dy:,} measurements: a {w * dy:,} x {w * dy:,} "
            "innovation covariance and its solve)",
            argument=argument,
            fix=fix,
        )
    if not big:
        return
    seconds = pairs * (PAIR_SECONDS + T * len(teams) * PAIR_STEP_SECONDS)
    what = f"reading a team of {n:,} agents ({pairs:.3g} agent pairs)" + (f" and {len(teams)} team design(s) over {T:,} steps" if teams else "")
    _budget.check_work(0.0, what, argument="agents", fix=fix, loops=seconds * _budget.LOOPS)
    _budget.announce(seconds, what)
