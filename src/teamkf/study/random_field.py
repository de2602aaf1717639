r"""The random field of Section VII-A of Das & Moura (2016), as a seeded scenario builder.

M sites x(k) in R^M evolve as x(k+1) = A x(k) + w(k); N agents each observe
``sites_per_agent`` (2) sites through 0-1 rows, y_n(k) = H_n x(k) + v_n(k);
the agents talk over a connected Erdős–Rényi graph (about 138 edges for
N = 50) with unit delay per hop.

==================  ===========================================================
paper (Sec. VII-A)  here
==================  ===========================================================
A: lattice of       sites split into ``n_clusters`` groups (default M // 10, at
degree 4, entries   least 3); each group is a ring lattice in which a site is
in (0, 1),          coupled to itself and its 2 nearest neighbours on each side
``||A||_2 = 1.05``  (degree 4), with symmetric weights drawn from U(0, 1). Each
                    group's block is scaled to a spectral norm drawn from
                    U(1.01, 1.05), the largest set to exactly 1.05, so
                    ``||A||_2 = 1.05`` and *every* group has an unstable mode.
H_n: 0-1 rows       ``sites_per_agent`` distinct sites per agent, uniformly at
                    random (some sites may stay unobserved: G can be singular)
V, R_n, Sigma_0     random SPD (Wishart with twice the dimension as degrees of
                    freedom, so moderately conditioned), scaled to spectral
                    norms 4, 8, 16
graph               connected G(N, m) with m = round(p C(N, 2)),
                    p = 138 / C(50, 2) (so m = 138 for N = 50), every edge both
                    directions with delay 1
x̄_0                 0 (teamkf's systems start at mean 0; the errors of a linear
                    unbiased filter do not depend on the mean)
==================  ===========================================================

Why groups. The paper states that (A, H) is detectable while no (A, H_n) is.
A single connected lattice with positive weights has a positive Perron
eigenvector, so *any* single site detects its dominant unstable mode and, for
generic weights, the other modes too: then every agent alone detects the
field. To have no agent detect the field on its own, the unstable modes must
be invisible from some sites: with at least ``sites_per_agent + 1`` groups
that each carry an unstable mode, an agent's two sites touch at most two
groups, so no (A, H_n) is detectable, while the union of all agents' sites
touches every group and (A, H) is. Both properties are checked with
:func:`teamkf.estimators.riccati.is_detectable`; the observation pattern is
redrawn until (A, H) is detectable.

The instance is not tuned to any published number: everything is drawn from
the seeded generator, once.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from .. import _validation as V
from ..exceptions import DetectabilityError, ShapeError
from ..models.system import LinearGaussianSystem

__all__ = ["random_field", "random_field_instance", "RandomFieldInstance", "PAPER_EDGE_PROBABILITY"]

#: edge probability of the paper's graph: 138 edges among C(50, 2) = 1225 pairs
PAPER_EDGE_PROBABILITY = 138 / 1225


@dataclass(frozen=True, eq=False)
class RandomFieldInstance:
    """A drawn Section VII-A instance and what was checked about it.

    Attributes
    ----------
    system : LinearGaussianSystem
    graph : CommGraph            undirected (both directions), delay 1
    sites : (N, sites_per_agent) int array   the sites each agent observes
    clusters : tuple of int arrays           the site groups of A
    unobserved : int array                   sites no agent observes (G singular iff non-empty)
    rho_A : float                            spectral radius of A
    n_unstable : int                         eigenvalues of A with modulus >= 1
    globally_detectable : bool               (A, H) detectable
    locally_detectable : tuple of bool       (A, H_n) detectable, per agent
    """

    system: LinearGaussianSystem
    graph: Any
    sites: np.ndarray
    clusters: tuple
    unobserved: np.ndarray
    rho_A: float
    n_unstable: int
    globally_detectable: bool
    locally_detectable: tuple

    @property
    def n_edges(self) -> int:
        """Undirected edges of the graph."""
        return int(self.graph.n_edges // 2)


def _generator(rng: Any) -> np.random.Generator:
    if isinstance(rng, np.random.Generator):
        return rng
    if isinstance(rng, (int, np.integer)) and not isinstance(rng, bool):
        return np.random.default_rng(int(rng))
    if isinstance(rng, np.random.SeedSequence):
        return np.random.default_rng(rng)
    raise ShapeError(f"rng: expected a numpy Generator, a SeedSequence or an int seed, found {rng!r}; pass rng=0")


def _positive(x: Any, name: str) -> float:
    try:
        v = float(x)
    except (TypeError, ValueError):
        raise ShapeError(f"{name}: expected a positive number, found {x!r}") from None
    if not np.isfinite(v) or v <= 0:
        raise ShapeError(f"{name}: expected a positive number, found {v}")
    return v


def _random_spd(gen: np.random.Generator, d: int, norm: float) -> np.ndarray:
    """Wishart(2d dof) draw scaled to spectral norm ``norm``."""
    B = gen.standard_normal((d, 2 * d))
    S = B @ B.T
    S = 0.5 * (S + S.T)
    return S * (norm / float(np.linalg.eigvalsh(S)[-1]))


def _lattice_dynamics(gen: np.random.Generator, M: int, n_clusters: int, a_norm: float) -> tuple[np.ndarray, tuple]:
    sizes = np.full(n_clusters, M // n_clusters)
    sizes[: M % n_clusters] += 1
    targets = gen.uniform(1.01, 1.05, n_clusters) * (a_norm / 1.05)
    targets[int(np.argmax(targets))] = a_norm
    A = np.zeros((M, M))
    clusters = []
    start = 0
    for c, s in enumerate(sizes):
        idx = np.arange(start, start + s)
        start += s
        nei = min(2, (int(s) - 1) // 2)
        B = np.zeros((s, s))
        for a in range(s):
            B[a, a] = gen.uniform(0.0, 1.0)
            for d in range(1, nei + 1):
                b = (a + d) % s
                w = gen.uniform(0.0, 1.0)
                B[a, b] = B[b, a] = w
        B *= targets[c] / float(np.linalg.norm(B, 2))
        A[np.ix_(idx, idx)] = B
        clusters.append(idx)
    return A, tuple(clusters)


def random_field_instance(
    M: int = 50,
    N: int = 50,
    *,
    rng: Any,
    sites_per_agent: int = 2,
    n_clusters: int | None = None,
    a_norm: float = 1.05,
    v_norm: float = 4.0,
    r_norm: float = 8.0,
    sigma0_norm: float = 16.0,
    edge_probability: float = PAPER_EDGE_PROBABILITY,
    require_local_undetectable: bool = True,
    max_tries: int = 200,
) -> RandomFieldInstance:
    """Draw a Section VII-A instance (see the module docstring) and check its properties.

    Parameters
    ----------
    M, N : int
        Sites and agents (the paper: 50 and 50).
    rng : Generator, SeedSequence or int (keyword, required)
    sites_per_agent : int
        Sites observed by each agent (the paper: 2).
    n_clusters : int, optional
        Groups of sites in A; default ``max(sites_per_agent + 1, M // 10)``.
    a_norm, v_norm, r_norm, sigma0_norm : float
        Spectral norms of A, V (= Q), R_n and Sigma_0 (the paper: 1.05, 4, 8, 16).
    edge_probability : float
        Edge density of the graph (default: the paper's 138 / 1225).
    require_local_undetectable : bool
        Raise unless no single agent detects (A, H_n) (needs ``a_norm > 1``
        and more groups than ``sites_per_agent``).
    max_tries : int
        Redraws of the observation pattern (until (A, H) is detectable) and of
        the graph (until connected).

    Raises
    ------
    ShapeError
        On bad sizes (``M < 3``, ``sites_per_agent > M``, too many groups).
    DetectabilityError
        If no detectable observation pattern is found, or a single agent
        detects the field while ``require_local_undetectable``.
    """
    import networkx as nx

    from .._linalg import is_detectable
    from ..network.graph import CommGraph

    M = V.positive_int(M, "M", minimum=3)
    N = V.positive_int(N, "N", minimum=2)
    spa = V.positive_int(sites_per_agent, "sites_per_agent")
    if spa > M:
        raise ShapeError(f"sites_per_agent: expected at most M = {M} sites per agent, found {spa}")
    nc = max(spa + 1, M // 10) if n_clusters is None else V.positive_int(n_clusters, "n_clusters")
    if nc > M // 3 and n_clusters is not None:
        raise ShapeError(f"n_clusters: expected at most M // 3 = {M // 3} groups (each needs 3 sites), found {nc}")
    nc = min(nc, M // 3) if n_clusters is None else nc
    a_norm = _positive(a_norm, "a_norm")
    v_norm, r_norm, s0_norm = _positive(v_norm, "v_norm"), _positive(r_norm, "r_norm"), _positive(sigma0_norm, "sigma0_norm")
    p = float(edge_probability)
    if not 0 < p <= 1:
        raise ShapeError(f"edge_probability: expected a probability in (0, 1], found {edge_probability!r}")
    tries = V.positive_int(max_tries, "max_tries")
    gen = _generator(rng)

    A, clusters = _lattice_dynamics(gen, M, nc, a_norm)
    Q = _random_spd(gen, M, v_norm)
    Sigma0 = _random_spd(gen, M, s0_norm)
    R = [_random_spd(gen, spa, r_norm) for _ in range(N)]
    eye = np.eye(M)
    for _ in range(tries):
        sites = np.stack([np.sort(gen.choice(M, size=spa, replace=False)) for _ in range(N)])
        H = eye[sites.reshape(-1)]
        if is_detectable(A, H):
            break
    else:
        raise DetectabilityError(
            f"random_field: expected a detectable (A, H), found none in max_tries={tries} observation "
            f"patterns with {N} agents x {spa} sites over {M} sites; raise N or sites_per_agent"
        )
    C = [eye[s] for s in sites]
    local = tuple(bool(is_detectable(A, c)) for c in C)
    if require_local_undetectable and any(local):
        raise DetectabilityError(
            f"random_field: expected no agent to detect the field alone, found agents {[i for i, d in enumerate(local) if d][:5]} "
            f"that do (n_clusters={nc}, sites_per_agent={spa}, a_norm={a_norm}); use more groups than sites per agent and a_norm > 1, "
            "or pass require_local_undetectable=False"
        )
    m_edges = max(N - 1, int(round(p * N * (N - 1) / 2)))
    for _ in range(tries):
        Gnx = nx.gnm_random_graph(N, m_edges, seed=int(gen.integers(2**31 - 1)))
        if nx.is_connected(Gnx):
            break
    else:
        raise ShapeError(
            f"edge_probability: expected a density that gives a connected graph of {N} agents, found none in "
            f"max_tries={tries} draws with {m_edges} edges; raise edge_probability"
        )
    graph = CommGraph.from_networkx(Gnx, default_delay=1)
    system = LinearGaussianSystem(A=A, Q=Q, Sigma_x=Sigma0, C=C, R=R)
    observed = np.unique(sites)
    unobserved = np.setdiff1d(np.arange(M), observed)
    lam = np.abs(np.linalg.eigvals(A))
    return RandomFieldInstance(system, graph, sites, clusters, unobserved, float(lam.max()), int(np.sum(lam >= 1.0)), True, local)


def random_field(M: int = 50, N: int = 50, *, rng: Any, **kwargs: Any) -> tuple[LinearGaussianSystem, Any]:
    """The Section VII-A random field: ``(system, graph)`` (see :func:`random_field_instance` for the options).

    Examples
    --------
    >>> from teamkf.study.random_field import random_field
    >>> system, graph = random_field(15, 8, rng=0)
    >>> system.dx, system.n_agents, system.dy[0]
    (15, 8, 2)
    >>> graph.n_agents, all(graph.delay(i, j) == 1 for i, j, _ in graph.edges)
    (8, True)
    """
    inst = random_field_instance(M, N, rng=rng, **kwargs)
    return inst.system, inst.graph
