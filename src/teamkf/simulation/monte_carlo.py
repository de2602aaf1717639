"""Monte Carlo of estimators: team cost per step and in total, with 95 % confidence intervals, streamed.

All estimators are evaluated on the same sampled paths (common random
numbers), vectorized over runs. Two ways to get each estimator's errors:

* ``path="errors"`` (default): ``design.errors(paths)`` propagates the
  estimator's error recursion from the primitive noises, e = L x - z without
  ever subtracting two large numbers. It stays accurate when A is unstable
  (the UAV formation with n = 10 has spectral radius 1.55: x(100) ~ 1e19).
* ``path="runtime"``: the agents run in the message-passing runtime on the
  sampled measurements and e = L x - z is formed from the simulated state —
  the honest check of the information discipline, accurate for stable
  systems only.

Streaming
---------
Runs are processed in *blocks* of ``batch`` runs (block j holds runs
j·batch .. (j+1)·batch - 1) and blocks are grouped into *chunks* (one task
each, serially or on Dask workers). Nothing per run is kept: run r's random
numbers come from a counter-based stream built on demand from (seed, r)
(:class:`~teamkf.simulation.sampling.RunStreams`), a block's costs are reduced
at once to its per-step sums Σ c and Σ c² and the sums Σ C and Σ C² of the
run totals C = Σ_k c(k), and these block sums are added *exactly* (as
integers, in units of 2^-1126, :class:`ExactSums`), so the merged sums are
the exact sums of the block sums whatever the order. A block is always
computed alone with the same array shapes and one BLAS thread, so its sums do
not depend on the chunk it is in or the worker that runs it: the result for a
seed and a ``batch`` is bit-for-bit the same for every ``chunk`` and
scheduler (serial, a local Dask cluster, a remote one). Peak memory is that
of one block per worker, whatever ``n_runs``.

From the exact sums S1 = Σ c, S2 = Σ c², the mean is S1/n and the sample
variance (n S2 - S1²) / (n (n - 1)), evaluated exactly and rounded once.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Iterator, Literal, Mapping, Sequence

import numpy as np

from .. import _validation as V
from .._validation import FloatArray
from ..exceptions import ArgumentError, ShapeError
from .mc_result import MonteCarloResults
from .online import run_online
from .sampling import RunStreams, sample_paths

__all__ = ["MonteCarloResult", "monte_carlo", "runtime_estimates", "Z95", "ExactSums", "DEFAULT_BATCH"]

Z95 = 1.959963984540054
#: default runs per computation block (memory: one block's paths and errors per worker)
DEFAULT_BATCH = 1024
#: most blocks per chunk by default (one chunk = one task)
DEFAULT_BLOCKS_PER_CHUNK = 16
_SHIFT = 1126  # 2^-1126 is below the smallest subnormal times 2^-52: every double is an integer multiple of it
_MAX_RUNS = 2**63  # run indices are Philox counter words (uint64)


class ExactSums:
    r"""Exact, order-independent sums of float vectors (Python integers in units of 2^-1126).

    Every finite double is m 2^e with an integer m (``|m| < 2^53``) and e >= -1126 + 53 (``np.frexp``), so
    it is the integer m 2^(e + 1126) in units of 2^-1126; sums of such integers are exact, so the result
    does not depend on the order of the additions or on how they were split. ``value()`` rounds once.

    Examples
    --------
    >>> a, b = ExactSums(1), ExactSums(1)
    >>> for x in (1e16, 1.0, -1e16): a.add(np.array([x]))
    >>> for x in (-1e16, 1e16, 1.0): b.add(np.array([x]))
    >>> float(a.value()[0]), a.acc == b.acc
    (1.0, True)
    """

    def __init__(self, n: int, acc: Sequence[int | float] | None = None):
        self.acc: list[int | float] = list(acc) if acc is not None else [0] * int(n)  # float: inf (diverged)

    def add(self, x: FloatArray) -> None:
        x = np.asarray(x, dtype=float).ravel()
        if x.size != len(self.acc):
            raise ShapeError(f"x: expected {len(self.acc)} values, found {x.size}")
        bad = ~np.isfinite(x)
        if bad.any():  # a diverging estimator: those entries are infinite for good (reported, flagged, never an error)
            for i in np.flatnonzero(bad).tolist():
                self.acc[i] = math.inf
            x = np.where(bad, 0.0, x)
        m, e = np.frexp(x)
        mi = (m * 9007199254740992.0).astype(np.int64)  # m 2^53: exact (53 significant bits)
        sh = e.astype(np.int64) + (_SHIFT - 53)
        acc = self.acc
        for i, (a, b) in enumerate(zip(mi.tolist(), sh.tolist())):
            if a:
                acc[i] += a << b if b >= 0 else a >> -b  # b < 0 only below 2^-1126: never for doubles
        return None

    def merge(self, other: "ExactSums") -> None:
        self.acc = [a + b for a, b in zip(self.acc, other.acc)]

    def value(self) -> FloatArray:
        """The sums, each rounded once to the nearest double."""
        return np.array([a if isinstance(a, float) else a / (1 << _SHIFT) for a in self.acc])


def _mean_sem(s1: int | float, s2: int | float, n: int) -> tuple[float, float]:
    """Mean and standard error of the mean from exact sums (units 2^-1126 and 2^-2252), rounded once each."""
    from fractions import Fraction

    if isinstance(s1, float) or isinstance(s2, float):  # infinite (a diverging estimator)
        return math.inf, math.inf
    mean = Fraction(s1, 1 << _SHIFT) / n
    var = (Fraction(n * s2, 1 << _SHIFT) - Fraction(s1 * s1, 1 << (2 * _SHIFT))) / (n * (n - 1))
    var = max(var, Fraction(0))
    return float(mean), math.sqrt(float(var / n))


@dataclass(frozen=True, eq=False)
class MonteCarloResult:
    """Sample team costs of one estimator, with their standard errors.

    One value of :func:`~teamkf.monte_carlo`'s result: the mean over runs of
    c(x(k), ẑ(k)) per step and of J_T = Σ_k c(x(k), ẑ(k)), with the standard
    error s / √n_runs of each (``ci95`` is mean ± 1.96 standard errors).

    Parameters
    ----------
    estimator : str
        The design's name in the mapping given to :func:`~teamkf.monte_carlo`.
    n_runs : int
        The number of runs.
    stage_mean, stage_sem : (T,) arrays
        The mean of c(x(k), ẑ(k)) over runs, and its standard error.
    total_mean, total_sem : float
        The mean and standard error of Σ_k c(x(k), ẑ(k)).
    path : "errors" or "runtime"
        How the errors were computed: the cancellation-free error recursions, or agents run on measurements.
    seed : dict or None
        ``{"entropy": ..., "spawn_key": [...]}``: ``SeedSequence(entropy, spawn_key=spawn_key)``
        reproduces the run streams (recorded also when ``rng=None`` drew fresh entropy).
    batch, chunk : int or None
        Runs per computation block and per task (see :func:`~teamkf.monte_carlo`).
    links : LinkStats or None
        Per-edge packet counts on unreliable links, or None.

    Examples
    --------
    >>> from teamkf import LinearGaussianSystem, TeamCost, design_centralized, monte_carlo
    >>> kf = design_centralized(LinearGaussianSystem.platoon(3), TeamCost.platoon(3, 1.0), horizon=5)
    >>> r = monte_carlo({"kf": kf}, 5, 400, rng=1)["kf"]
    >>> lo, hi = r.ci95
    >>> bool(lo <= kf.total_cost <= hi), r.stage_mean.shape
    (True, (5,))
    """

    estimator: str
    n_runs: int
    stage_mean: FloatArray
    stage_sem: FloatArray
    total_mean: float
    total_sem: float
    path: str = "errors"
    seed: Any = None
    batch: int | None = None
    chunk: int | None = None
    #: per-edge packet counts on unreliable links (:class:`~teamkf.simulation.links.LinkStats`), or None
    links: Any = None

    @property
    def diverged(self) -> bool:
        """True when the simulated cost is not finite (the estimator diverges on this system)."""
        return not bool(np.isfinite(self.total_mean))

    @property
    def ci95(self) -> tuple[float, float]:
        return (self.total_mean - Z95 * self.total_sem, self.total_mean + Z95 * self.total_sem)

    @property
    def stage_ci95(self) -> tuple[FloatArray, FloatArray]:
        return (self.stage_mean - Z95 * self.stage_sem, self.stage_mean + Z95 * self.stage_sem)

    def summary(self) -> dict[str, Any]:
        """JSON-ready and strict (non-finite values are null, with ``"diverged": true``); records what repeats the run."""
        from .._version import __version__
        from ..estimators.base import json_float

        lo, hi = self.ci95
        out: dict[str, Any] = {
            "method": "monte-carlo",
            "runs": self.n_runs,
            "total_cost": json_float(self.total_mean),
            "ci95": [json_float(lo), json_float(hi)],
            "stage_costs": [json_float(c) for c in self.stage_mean],
            "seed": self.seed,
            "batch": self.batch,
            "chunk": self.chunk,
            "teamkf_version": __version__,
        }
        if self.diverged:
            out["diverged"] = True
        return out

    def _repr_html_(self) -> str:
        from .._repr import html_table

        lo, hi = self.ci95
        rows = [
            {
                "estimator": self.estimator,
                "runs": self.n_runs,
                "steps": len(self.stage_mean),
                "J_T (mean)": self.total_mean,
                "95 % low": lo,
                "95 % high": hi,
                "path": self.path,
            }
        ]
        return html_table(list(rows[0]), rows, caption="teamkf Monte Carlo result")

    def to_pandas(self) -> Any:
        pd = V.require("pandas", "dask")
        lo, hi = self.stage_ci95
        return pd.DataFrame(
            {"estimator": self.estimator, "step": np.arange(len(self.stage_mean)), "stage_cost": self.stage_mean, "ci95_low": lo, "ci95_high": hi}
        )

    def plot(self, ax: Any = None, **kwargs: Any) -> Any:
        """Stage cost against the step with its 95 % band (matplotlib, lazy)."""
        from ..plotting import _pyplot, family_style, legend_outside

        plt = _pyplot()
        if ax is None:
            _, ax = plt.subplots(figsize=(6, 4))
        t = np.arange(1, len(self.stage_mean) + 1)
        lo, hi = self.stage_ci95
        style = {**family_style(self.estimator), **kwargs}  # its family's colour, as in every other plot
        (line,) = ax.plot(t, self.stage_mean, label=f"{self.estimator} (MC, {self.n_runs} runs)", **style)
        ax.fill_between(t, lo, hi, alpha=0.2, color=line.get_color())
        ax.set_xlabel("t")
        ax.set_ylabel("E[c(x(t), z(t))]")
        legend_outside(ax)
        return ax


def runtime_estimates(design: Any, y: Any, graph: Any = None, *, links: Any = None, streams: Any = None, stats: Any = None) -> FloatArray:
    """Every agent's estimate from the online agents: message passing over ``graph`` (default: the
    design's own graph), or delivery by the information structure. ``y``: list over agents of
    (n_runs, T, d_y^i). What ``path="runtime"`` and ``teamkf filter`` run. ``links``/``streams``/``stats``:
    unreliable links (:func:`teamkf.simulation.runtime.run_graph`)."""
    graph = graph if graph is not None else getattr(design, "graph", None)
    if graph is not None:
        from .runtime import graph_agents, run_graph

        return run_graph(graph_agents(design), graph, y, links=links, streams=streams, stats=stats, design=design)
    if links is not None and not links.trivial:
        raise ArgumentError(
            f"links: the {design.estimator!r} design has no graph of its own; pass graph= (the network the links belong to)", argument="links"
        )
    return run_online(design.agents(), y)


def _team_errors(design: Any, paths: Any, path: str, graph: Any, links: Any = None, streams: Any = None, stats: Any = None) -> FloatArray:
    if path == "errors":
        return design.errors(paths)  # type: ignore[no-any-return]
    z = runtime_estimates(design, paths.y, graph, links=links, streams=streams, stats=stats)
    cost = design.cost
    return np.stack([paths.x[:, k] @ cost.L_at(k).T - z[:, k] for k in range(paths.n_steps)], axis=1)


def _cost_kind(S: FloatArray) -> str:
    if np.array_equal(S, np.eye(S.shape[0])):
        return "identity"
    if np.array_equal(S, np.diag(np.diag(S))):
        return "diagonal"
    return "dense"


def _block_costs(design: Any, paths: Any, path: str, graph: Any, links: Any = None, streams: Any = None, stats: Any = None) -> FloatArray:
    """(n, T) team costs c(x(k), ẑ(k)) = e' S_k e of one block of runs."""
    return team_stage_costs(design.cost, _team_errors(design, paths, path, graph, links, streams, stats))


def team_stage_costs(cost: Any, e: FloatArray) -> FloatArray:
    """c(k) = e(k)' S(k) e(k) for team errors e = L x - ẑ of shape (n_runs, T, n d_z): (n_runs, T).

    The one evaluation of the quadratic form that the Monte Carlo and ``teamkf filter --truth`` share
    (so a recorded run's realized costs are bit for bit the Monte Carlo's for the same run); it uses
    S's structure (identity, diagonal, dense).
    """
    n, T, d = e.shape
    out = np.empty((n, T))
    steps = range(T) if cost.is_time_varying else (None,)
    for k in steps:
        S = cost.S_at(0 if k is None else k)
        ek = e if k is None else e[:, k : k + 1]
        kind = _cost_kind(S)
        if kind == "identity":
            c = np.einsum("rka,rka->rk", ek, ek)
        elif kind == "diagonal":
            c = (ek * ek) @ np.diag(S)
        else:
            c = np.einsum("rka,rka->rk", ek.reshape(-1, d).dot(S).reshape(ek.shape), ek)
        if k is None:
            out[:] = c
        else:
            out[:, k] = c[:, 0]
    return out


@dataclass(frozen=True)
class _Spec:
    """What a chunk task needs (shipped once to each worker)."""

    designs: dict
    system: Any
    n_steps: int
    n_runs: int
    streams: RunStreams
    batch: int
    path: str
    graph: Any
    links: Any = None


def _limit_blas() -> Any:
    from .._blas import _load_blas

    _load_blas()  # every BLAS loaded before the limit, in this process as in a fresh Dask worker
    try:
        from threadpoolctl import threadpool_limits

        return threadpool_limits(1)
    except Exception:  # pragma: no cover - threadpoolctl missing: BLAS as configured
        import contextlib

        return contextlib.nullcontext()


def _run_chunk(spec: _Spec, first_block: int, last_block: int) -> dict[str, Any]:
    """Exact sums of blocks first_block .. last_block - 1: per design [Σc (T), Σc² (T), [ΣC, ΣC²]] (+ link counts)."""
    T = spec.n_steps
    acc = {name: (ExactSums(T), ExactSums(T), ExactSums(2)) for name in spec.designs}
    lstats: dict[str, Any] = {}
    if spec.links is not None:
        from .links import LinkStats

        lstats = {name: LinkStats() for name in spec.designs}
    with _limit_blas(), np.errstate(over="ignore", invalid="ignore"):  # a diverging estimator: inf, flagged later
        for j in range(first_block, last_block):
            a, b = j * spec.batch, min((j + 1) * spec.batch, spec.n_runs)
            paths = sample_paths(spec.system, T, b - a, rng=None, streams=spec.streams, first_run=a)
            lstreams = None
            if spec.links is not None:  # run r's link events: its own stream (the block does not matter)
                from .links import link_streams

                seq = np.random.SeedSequence(spec.streams.entropy, spawn_key=spec.streams.spawn_key)
                lstreams = link_streams(seq, b, first_run=a)
            for name, d in spec.designs.items():
                c = _block_costs(d, paths, spec.path, spec.graph, spec.links, lstreams, lstats.get(name))
                tot = c.sum(axis=1)
                s1, s2, st = acc[name]
                s1.add(c.sum(axis=0))
                s2.add((c * c).sum(axis=0))
                st.add(np.array([tot.sum(), (tot * tot).sum()]))
                del c, tot
            del paths  # one block alive at a time (else the next block is drawn while this one is held)
    out: dict[str, Any] = {name: [s1.acc, s2.acc, st.acc] for name, (s1, s2, st) in acc.items()}
    if lstats:
        out["__links__"] = lstats
    return out


def _chunks(n_blocks: int, per_chunk: int) -> list[tuple[int, int]]:
    return [(a, min(a + per_chunk, n_blocks)) for a in range(0, n_blocks, per_chunk)]


def _progress(total: int, enabled: bool | None) -> Any:
    """The package's progress bar over runs (:mod:`teamkf._progress`: silent off a terminal, quiet or TEAMKF_PROGRESS=0)."""
    from .._progress import bar

    return bar(total, desc="Monte Carlo", unit="run", unit_scale=True, enabled=enabled)


def _serial(spec: _Spec, chunks: list[tuple[int, int]], bar: Any) -> Iterator[dict[str, Any]]:
    for a, b in chunks:
        part = _run_chunk(spec, a, b)
        if bar is not None:
            bar.update(min(b * spec.batch, spec.n_runs) - a * spec.batch)
        yield part


def _dask(spec: _Spec, chunks: list[tuple[int, int]], bar: Any, scheduler: Any) -> Iterator[dict[str, Any]]:
    from .parallel import _open_client, with_plugins  # the Dask clients (LocalCluster tuned: one BLAS thread per worker)

    distributed = V.require("distributed", "dask")
    client, owned = _open_client(scheduler, None)
    try:
        [fspec] = client.scatter([spec], broadcast=True)
        task = with_plugins(_run_chunk, client)  # a worker holding another version of a plug-in refuses
        futs = {client.submit(task, fspec, a, b, pure=False, retries=3): (a, b) for a, b in chunks}
        for fut in distributed.as_completed(futs):
            a, b = futs[fut]
            part = fut.result()
            if bar is not None:
                bar.update(min(b * spec.batch, spec.n_runs) - a * spec.batch)
            yield part
    finally:
        for obj in owned:
            obj.close()


def _same_system(a: Any, b: Any) -> bool:
    """Equal models: same sizes and equal matrices (designs built separately for one system agree)."""
    if a.dx != b.dx or list(a.dy) != list(b.dy):
        return False
    pairs = [(a.A, b.A), (a.Q, b.Q), (a.Sigma_x, b.Sigma_x), *zip(a.C, b.C), *zip(a.R, b.R)]
    return all(np.shape(x) == np.shape(y) and np.array_equal(x, y) for x, y in pairs)


#: bytes per run held for the whole Monte Carlo: its SeedSequence (measured: ~380) and a margin
_BYTES_PER_STREAM = 512


def _check_memory(designs: Mapping[str, Any], system: Any, T: int, R_: int, batch: int) -> None:
    """Refuse up front (with the estimate) a Monte Carlo whose memory exceeds what the machine has."""
    from .._resources import check_memory

    b = min(batch, R_)
    per_batch = (
        8.0 * b * T * (3 * system.dx + 3 * sum(system.dy) + 2 * len(designs) * max(getattr(d.cost, "dz", system.dx) for d in designs.values()))
    )
    estimate = R_ * (_BYTES_PER_STREAM + 8.0 * T * len(designs)) + per_batch
    check_memory(
        estimate,
        f"a Monte Carlo of {R_:,} runs x {T} steps x {len(designs)} estimators (one seed stream and {T} stage costs per run and estimator)",
        argument="n_runs",
        fix="use fewer runs (the 95 % interval only shrinks like 1/sqrt(runs)), or a shorter horizon",
    )


def _check_work(designs: Mapping[str, Any], system: Any, T: int, R_: int, blocks: int = 0) -> None:
    """Refuse up front (with the estimate) a Monte Carlo whose run time exceeds the limit (:func:`teamkf._budget.check_work`).

    Per run and step: sampling (:math:`d_x^2 + d_x d_y`), each design's online step
    (:math:`d_z (d_x + d_y)` with :math:`d_z` its team estimate size) and a fixed overhead of
    50 operations, at :data:`teamkf._budget.BATCHED_OPS` operations per second. ``blocks`` > 0 (``path="runtime"``,
    unreliable links under ``--p-drop``): each agent's online step also runs in Python once per block of runs and step
    (:data:`teamkf._budget.STEP_LOOPS` each).
    """
    from .. import _budget

    dx, dy = system.dx, sum(system.dy)
    per = 50.0 + dx * dx + dx * dy + sum(float(getattr(d.cost, "dz", dx) or dx) * system.n_agents * (dx + dy) for d in designs.values())
    _budget.check_work(
        float(R_) * T * per,
        f"a Monte Carlo of {R_:,} runs x {T} steps x {len(designs)} estimators",
        argument="n_runs",
        fix="use fewer runs (the 95 % interval only shrinks like 1/sqrt(runs)) or a shorter horizon",
        rate=_budget.BATCHED_OPS,
        loops=float(blocks) * T * system.n_agents * len(designs) * _budget.STEP_LOOPS,
    )


def monte_carlo(
    designs: Mapping[str, Any],
    n_steps: int,
    n_runs: int,
    *,
    rng: int | np.random.SeedSequence | np.random.Generator | None,
    batch: int = DEFAULT_BATCH,
    path: Literal["errors", "runtime"] = "errors",
    graph: Any = None,
    chunk: int | None = None,
    scheduler: Any = None,
    progress: bool | None = None,
    links: Any = None,
) -> MonteCarloResults:
    """Evaluate every design on the same ``n_runs`` sampled paths, streamed in blocks (module docstring).

    Parameters
    ----------
    designs : mapping of str to Design
        Name -> design (with ``.system``, ``.cost`` and ``.errors`` / ``.agents``); every design
        sees the same sampled paths.
    n_steps : int
        The horizon simulated.
    n_runs : int
        The number of independent runs (>= 2; any number: memory does not grow with it).
    rng : int, SeedSequence, Generator or None
        The seed (None: fresh entropy, recorded in the result); run r uses the counter-based
        stream ``RunStreams(rng).generator(r)``.
    batch : int
        Runs per computation block (memory per worker ~ one block's paths and errors). Results for a
        seed agree to rounding whatever the batch, and bit for bit for a given batch.
    path : "errors" or "runtime"
        "errors": the cancellation-free error recursions; "runtime": the agents run on measurements.
    graph : CommGraph or None
        With path="runtime", run the agents over this graph (message passing)
        instead of the structure-driven delivery.
    chunk : int or None
        Runs per task (rounded up to a multiple of ``batch``; default: at most 16 blocks, and about 32
        tasks when there are enough blocks, so that workers stay busy). The result does not depend on it,
        bit for bit.
    scheduler : None, "serial", "local", str, Client or cluster
        None or "serial": this process; "local": an embedded Dask LocalCluster, one
        single-threaded worker per core; a Dask scheduler address, a ``distributed.Client`` or a cluster.
        One chunk per task, retried (3 times) when a worker is lost; bit-for-bit the serial result.
    progress : bool or None
        A progress bar on stderr (None: only when stderr is a terminal).
    links : LinkModel or None
        Unreliable links (:class:`~teamkf.simulation.links.LinkModel`; needs path="runtime").
        Run r's link events come from its own stream (seeded by ``rng``), so
        the numbers do not depend on the batch, the chunk or the worker; the
        per-edge packet counts are in each result's ``links`` field.

    Returns
    -------
    MonteCarloResults
        A read-only mapping: one result per design, under the design's name (``.to_frame()`` for a table): the mean cost per step and in total,
        with standard errors and 95 % intervals (``result["mtmse"].ci95``).

    Examples
    --------
    >>> from teamkf import LinearGaussianSystem, TeamCost, design_centralized, monte_carlo
    >>> sys_ = LinearGaussianSystem.platoon(3)
    >>> d = design_centralized(sys_, TeamCost.platoon(3, 1.0), horizon=5)
    >>> a = monte_carlo({"kf": d}, 5, 300, rng=1, batch=100, chunk=100)["kf"]
    >>> b = monte_carlo({"kf": d}, 5, 300, rng=1, batch=100, chunk=300)["kf"]
    >>> a.total_mean == b.total_mean and a.total_sem == b.total_sem
    True
    """
    T = V.positive_int(n_steps, "n_steps")
    R_ = V.positive_int(n_runs, "n_runs", minimum=2)
    if R_ > _MAX_RUNS:
        raise ArgumentError(
            f"n_runs: expected at most 2^63 runs (run indices are 64-bit Philox counter words), found {R_}; split the study over seeds"
        )
    B = V.positive_int(batch, "batch")
    V.instance(designs, "designs", Mapping, "a mapping name -> design (e.g. {'mtmse': design_mtmse(...)})")
    if not designs:
        raise ArgumentError("designs: expected at least one design", argument="designs")
    for name, d in designs.items():
        if not (hasattr(d, "system") and hasattr(d, "agents")):
            raise ArgumentError(
                f"designs[{name!r}]: expected a design (from a design_* function), found {V.describe(d)}", argument=f"designs[{name!r}]"
            )
    V.choice(path, "path", ("errors", "runtime"))
    first_name, first = next(iter(designs.items()))
    system = first.system
    for name, d in designs.items():
        if d.system is not system and not _same_system(d.system, system):
            raise ArgumentError(
                f"designs[{name!r}]: every design must be for the same system (common random numbers), found one that differs from "
                f"designs[{first_name!r}]'s; run monte_carlo once per system",
                argument=f"designs[{name!r}]",
            )
        if (horizon := getattr(d, "horizon", None)) is not None and T > horizon:
            raise ArgumentError(
                f"n_steps: expected at most the horizon {horizon} of designs[{name!r}], found {T}; design a longer horizon", argument="n_steps"
            )
    system.require_horizon(T)
    if links is not None and path != "runtime":
        if not links.trivial:
            raise ArgumentError('links: unreliable links act on the online agents; use path="runtime"', argument="links")
        links = None  # reliable links on the error recursions: nothing to count
    _check_work(designs, system, T, R_, -(-R_ // B) if path == "runtime" else 0)
    n_blocks = -(-R_ // B)
    if chunk is None:  # at most 16 blocks a task, and some 32 tasks when there are enough blocks (balance)
        per_chunk = max(1, min(DEFAULT_BLOCKS_PER_CHUNK, -(-n_blocks // 32)))
    else:
        per_chunk = -(-V.positive_int(chunk, "chunk") // B)
    streams = RunStreams(rng)
    chunks = _chunks(n_blocks, per_chunk)
    spec = _Spec(dict(designs), system, T, R_, streams, B, path, graph, links)
    link_totals: dict[str, Any] = {}
    tot = {name: (ExactSums(T), ExactSums(T), ExactSums(2)) for name in designs}
    bar = _progress(R_, progress)
    try:
        parts = _serial(spec, chunks, bar) if scheduler in (None, "serial") else _dask(spec, chunks, bar, scheduler)
        for part in parts:  # exact sums: the order in which chunks come back does not matter
            for name, ls in part.pop("__links__", {}).items():
                if name in link_totals:
                    link_totals[name].merge(ls)
                else:
                    link_totals[name] = ls
            for name, (a1, a2, at) in part.items():
                s1, s2, st = tot[name]
                s1.merge(ExactSums(T, a1))
                s2.merge(ExactSums(T, a2))
                st.merge(ExactSums(2, at))
    finally:
        if bar is not None:
            bar.close()
    seed = {"entropy": streams.entropy, "spawn_key": list(streams.spawn_key)}
    out = {}
    for name, (s1, s2, st) in tot.items():
        ms = [_mean_sem(a, b, R_) for a, b in zip(s1.acc, s2.acc)]
        tm, ts = _mean_sem(st.acc[0], st.acc[1], R_)
        out[name] = MonteCarloResult(
            name, R_, np.array([m for m, _ in ms]), np.array([e for _, e in ms]), tm, ts, path, seed, B, per_chunk * B, link_totals.get(name)
        )
    return MonteCarloResults(out)
