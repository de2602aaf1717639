"""Information structures: exactly which measurements each agent holds.

Notation (team-MMSE paper, Section III; code steps are 0-based):

=================  ==========================================================
symbol             meaning
=================  ==========================================================
I_i(k)             measurements y_j(s) agent i holds at step k       (eq. 14)
ell_ji             geodesic delay from j to i: i holds y_j(s), s <= k - ell_ji
c (common_lag)     common part y(0 : k - c), held by every agent (c >= tau*)
window (j, a, b)   agent i also holds y_j(k - b .. k - a), 0 <= a <= b < c
I_i^loc(k)         the local part: the windows, restricted to s >= 0   (27)
=================  ==========================================================

On a graph, :meth:`InformationStructure.from_graph` gives every agent the
common part y(0:k-c) with c = tau* (the weighted diameter) and, for every
source j with ell_ji < c, the window (j, ell_ji, c-1): together exactly the
information of eq. (14). A *reduced* ("shed") structure keeps the same common
part and smaller windows (the paper's IS1, IS2 of Section V-C); it is
realizable on a graph when every window respects the geodesic delays.

The common part need not be the whole intersection of the agents'
information (on a line graph the intersection is larger than y(0:k-tau*));
the MTMSE optimum does not depend on that choice as long as common and local
parts together are the agents' information.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from .. import _validation as V
from ..exceptions import InformationStructureError

__all__ = ["InformationStructure"]

Window = tuple[int, int, int]


@dataclass(frozen=True, eq=True)
class InformationStructure:
    """Common lag plus per-agent windows of recent measurements.

    Parameters
    ----------
    n_agents : int
        The number of agents n.
    common_lag : int
        c >= 1: every agent holds y(0 : k - c) at step k.
    local : sequence (one per agent) of (j, newest, oldest) triples
        Agent i also holds y_j(k - oldest .. k - newest), with
        0 <= newest <= oldest <= c - 1. Windows of one agent for the same
        source must not overlap.

    Examples
    --------
    The paper's IS2 for the 4-vehicle platoon (each agent keeps its own last
    three readings):

    >>> from teamkf import InformationStructure
    >>> IS2 = InformationStructure(4, 3, [[(i, 0, 2)] for i in range(4)])
    >>> IS2.local_dims((4, 4, 4, 4))
    (12, 12, 12, 12)
    """

    n_agents: int
    common_lag: int
    local: Any

    def __post_init__(self) -> None:
        n = V.positive_int(self.n_agents, "n_agents")
        _check_agents(n)
        c = _int(self.common_lag, "common_lag", minimum=1)
        if self.local is None or len(self.local) != n:
            found = "None" if self.local is None else f"{len(self.local)} lists"
            raise InformationStructureError(f"local: expected one list of windows per agent ({n}), found {found}")
        canon: list[tuple[Window, ...]] = []
        for i, wins in enumerate(self.local):
            rows: list[Window] = []
            for w_idx, w in enumerate(wins):
                name = f"local[{i}][{w_idx}]"
                try:
                    j, newest, oldest = (x for x in w)
                except (TypeError, ValueError):
                    raise InformationStructureError(f"{name}: expected a [source, newest, oldest] triple, found {w!r}") from None
                j = _int(j, f"{name} source", minimum=0)
                newest = _int(newest, f"{name} newest", minimum=0)
                oldest = _int(oldest, f"{name} oldest", minimum=0)
                if j >= n:
                    raise InformationStructureError(f"{name}: source agent {j} is out of range 0..{n - 1}")
                if newest > oldest:
                    raise InformationStructureError(
                        f"{name}: expected newest <= oldest (lags counted back from k), found newest={newest} > oldest={oldest}; swap them"
                    )
                if oldest >= c:
                    raise InformationStructureError(
                        f"{name}: expected oldest <= common_lag - 1 = {c - 1}, found {oldest}; y_{j}(k - {oldest}) is already in the common part y(0:k-{c}) — shorten the window"
                    )
                rows.append((j, newest, oldest))
            rows.sort()
            for a, b in zip(rows, rows[1:]):
                if a[0] == b[0] and b[1] <= a[2]:
                    raise InformationStructureError(
                        f"local[{i}]: windows {list(a)} and {list(b)} of source {a[0]} overlap; merge them into one window"
                    )
            canon.append(tuple(rows))
        object.__setattr__(self, "n_agents", n)
        object.__setattr__(self, "common_lag", c)
        object.__setattr__(self, "local", tuple(canon))

    # --- builders ----------------------------------------------------------
    @classmethod
    def from_graph(cls, graph: Any, common_lag: int | None = None) -> "InformationStructure":
        """The full information of eq. (14) on a strongly connected delay graph.

        ``common_lag`` defaults to max(tau*, 1); a larger value moves
        measurements from the common part to the local windows without
        changing what any agent holds.
        """
        from .graph import CommGraph

        V.instance(graph, "graph", CommGraph, "a CommGraph", "build one with CommGraph.line/ring/complete or CommGraph(n, edges)")
        graph.require_strongly_connected()
        ell = np.asarray(graph.geodesic_delays())  # ell[j, i]: from j to i
        tau = int(ell.max()) if ell.size else 0
        c = max(tau, 1) if common_lag is None else _int(common_lag, "common_lag", minimum=1)
        if c < tau:
            j, i = np.unravel_index(int(np.argmax(ell)), ell.shape)
            raise InformationStructureError(
                f"common_lag: expected >= the weighted diameter tau* = {tau}, found {c}; y_{j}(k - {c}) reaches agent {i} only after {tau} steps"
            )
        n = graph.n_agents
        local = [[(j, int(ell[j, i]), c - 1) for j in range(n) if ell[j, i] <= c - 1] for i in range(n)]
        return cls(n, c, local)

    @classmethod
    def delayed_sharing(cls, n_agents: int, delay: int) -> "InformationStructure":
        """The tau-step delayed sharing structure (Example 1): I_i(k) = {y(0:k-tau), y_i(k-tau+1:k)}."""
        d = _int(delay, "delay", minimum=1)
        return cls(n_agents, d, [[(i, 0, d - 1)] for i in range(n_agents)])

    @classmethod
    def own_window(cls, n_agents: int, common_lag: int, length: int | None = None) -> "InformationStructure":
        """Each agent keeps only its own last ``length`` readings (default: common_lag), like IS2."""
        n = _int(n_agents, "n_agents", minimum=1)
        _check_agents(n)
        c = _int(common_lag, "common_lag", minimum=1)
        m = c if length is None else _int(length, "length", minimum=1)
        if m > c:
            raise InformationStructureError(f"length: expected <= common_lag = {c}, found {m}")
        return cls(n, c, [[(i, 0, m - 1)] for i in range(n)])

    # --- queries ------------------------------------------------------------
    def local_lags(self, i: int) -> list[tuple[int, int]]:
        """(source j, lag) pairs of agent i's local part in steady state, lag = k - s."""
        return [(j, lag) for (j, a, b) in self.local[i] for lag in range(a, b + 1)]

    def local_pairs(self, i: int, k: int) -> list[tuple[int, int]]:
        """Agent i's local measurements at step k as (source j, step s), s >= 0.

        Ordered by step, then source: the order of agent i's local vector
        I_i^loc(k) and of the columns of its gain F_i(k).
        """
        pairs = [(k - lag, j) for (j, a, b) in self.local[i] for lag in range(a, min(b, k) + 1)]  # s = k - lag >= 0: O(held), not O(window)
        pairs.sort()
        return [(j, s) for (s, j) in pairs]

    def holds(self, i: int, k: int) -> set[tuple[int, int]]:
        """Every (j, s) agent i holds at step k: the common part and its windows."""
        common = {(j, s) for s in range(0, k - self.common_lag + 1) for j in range(self.n_agents)}
        return common | set(self.local_pairs(i, k))

    def local_dims(self, dy: Sequence[int]) -> tuple[int, ...]:
        """Steady-state dimension of each agent's local vector I_i^loc."""
        return tuple(int(sum(dy[j] * (b - a + 1) for j, a, b in self.local[i])) for i in range(self.n_agents))  # closed form: no loop over the lags

    def arrival_lag(self, i: int, j: int) -> int:
        """Smallest lag at which agent i uses y_j(s): it must have it by step s + lag."""
        lags = [a for (jj, a, _) in self.local[i] if jj == j]
        return min(lags + [self.common_lag])

    def validate_on(self, graph: Any) -> None:
        """Check that the structure is realizable on ``graph``.

        Every agent must receive y_j(s) before it uses it: the common part
        needs c >= ell_ji for every pair, and a window (j, newest, oldest) of
        agent i needs newest >= ell_ji.
        """
        if graph.n_agents != self.n_agents:
            raise InformationStructureError(f"graph: expected {self.n_agents} agents (as the information structure), found {graph.n_agents}")
        graph.require_strongly_connected()
        ell = np.asarray(graph.geodesic_delays())
        c = self.common_lag
        if ell.size and ell.max() > c:
            j, i = (int(v) for v in np.unravel_index(int(np.argmax(ell)), ell.shape))
            raise InformationStructureError(
                f"common_lag: {c} is not realizable on this graph: y_{j}(s) reaches agent {i} only {int(ell[j, i])} steps later "
                f"(weighted diameter tau* = {int(ell.max())}); use common_lag >= {int(ell.max())}"
            )
        for i, wins in enumerate(self.local):
            for j, a, b in wins:
                if a < ell[j, i]:
                    raise InformationStructureError(
                        f"local[{i}]: window [{j}, {a}, {b}] uses y_{j}(k - {a}), but y_{j} reaches agent {i} only after {int(ell[j, i])} steps; "
                        f"use newest >= {int(ell[j, i])}"
                    )

    def is_sub_structure_of(self, other: "InformationStructure") -> bool:
        """True when every agent holds at most what it holds in ``other`` (same common lag or larger)."""
        if other.n_agents != self.n_agents or self.common_lag < other.common_lag:
            return False
        for i in range(self.n_agents):
            mine = set(self.local_lags(i))
            theirs = set(other.local_lags(i)) | {(j, lag) for j in range(self.n_agents) for lag in range(other.common_lag, self.common_lag)}
            if not mine <= theirs:
                return False
        return True

    def plot(self, ax: Any = None, **kwargs: Any) -> Any:
        """Draw, for each agent, which y_j(s) it holds as a lag × source grid (matplotlib); returns the axes.

        Keywords go to :func:`teamkf.plotting.network.plot_information`
        (``agents``, ``max_lag``, ``title``).
        """
        from ..plotting.network import plot_information

        return plot_information(self, ax, **kwargs)

    def to_dict(self) -> dict[str, Any]:
        return {"common_lag": self.common_lag, "local": [[list(w) for w in wins] for wins in self.local]}

    @classmethod
    def from_dict(cls, n_agents: int, d: dict[str, Any]) -> "InformationStructure":
        return cls(n_agents, d["common_lag"], d["local"])


#: the largest team an information structure is built for (one window list per agent, held in Python)
MAX_AGENTS = 10**6


def _check_agents(n: int) -> None:
    from .._budget import check_size

    check_size(n, "n_agents", maximum=MAX_AGENTS, what="a team of", fix="use fewer agents (a population scenario handles huge N)")


def _int(x: Any, name: str, *, minimum: int) -> int:
    if isinstance(x, bool) or not isinstance(x, (int, np.integer, float)) or (isinstance(x, float) and not x.is_integer()):
        raise InformationStructureError(f"{name}: expected an integer >= {minimum}, found {x!r}")
    if int(x) < minimum:
        raise InformationStructureError(f"{name}: expected an integer >= {minimum}, found {int(x)}")
    return int(x)
