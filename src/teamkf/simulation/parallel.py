"""Map a pure per-point function over grid points: serially, or on Dask through the sweep engine's clients.

The studies (``teamkf reproduce bulk-*``, ...) write each grid computation as
``func(point)`` and call :func:`map_points`; ``teamkf reproduce NAME
--scheduler local|ADDRESS`` (or :func:`use_scheduler` from Python) sends the
same points to an embedded ``LocalCluster`` or an existing Dask cluster.
Results come back in the order of the points, so serial and Dask runs give
identical numbers (every point function is deterministic).
"""

from __future__ import annotations

import contextlib
import contextvars
import logging
import os
from typing import Any, Callable, Iterable, Iterator, TypeVar

from .. import _validation as V
from .._progress import progress
from ..exceptions import ArgumentError

__all__ = ["map_points", "process_map", "pool_workers", "use_scheduler", "current_scheduler", "local_cluster", "with_plugins", "WORKER_ENV"]

#: environment of the worker processes of the embedded LocalCluster (one BLAS thread each)
WORKER_ENV = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}

P = TypeVar("P")
R = TypeVar("R")

_SCHEDULER: contextvars.ContextVar[Any] = contextvars.ContextVar("teamkf_scheduler", default="serial")


def current_scheduler() -> Any:
    """The scheduler :func:`map_points` uses now (set by :func:`use_scheduler`; default "serial")."""
    return _SCHEDULER.get()


@contextlib.contextmanager
def use_scheduler(scheduler: Any) -> Iterator[None]:
    """Within the block, :func:`map_points` runs on ``scheduler`` ("serial", "processes" (:func:`process_map`: forked
    workers, one per core), "local", an address or a Client)."""
    token = _SCHEDULER.set(scheduler or "serial")
    try:
        yield
    finally:
        _SCHEDULER.reset(token)


def map_points(func: Callable[[P], R], points: Iterable[P], *, scheduler: Any = None) -> list[R]:
    """``[func(p) for p in points]``, on the current (or given) scheduler, results in point order."""
    pts = list(points)
    sched = scheduler if scheduler is not None else _SCHEDULER.get()
    if sched in (None, "serial") or len(pts) <= 1:
        return [func(p) for p in progress(pts, desc=getattr(func, "__name__", "points"), unit="point")]
    if sched == "processes":
        return process_map(func, pts, desc=getattr(func, "__name__", "points"))
    client, owned = _open_client(sched, None)
    try:
        futures = client.map(with_plugins(func, client), pts, pure=False, retries=3)
        return list(client.gather(futures))
    finally:
        for obj in owned:
            obj.close()


def pool_workers(n_jobs: int) -> int:
    """Worker processes for ``n_jobs`` independent jobs: one per available core (``TEAMKF_WORKERS`` overrides), at most ``n_jobs``."""
    env = V.env_count("TEAMKF_WORKERS")  # not a whole number >= 1: one ArgumentError naming the variable
    return max(1, min(int(n_jobs), env if env is not None else _cpu_count()))


#: set in :func:`process_map`'s workers (a worker maps its own points serially: no nested pools)
_IN_WORKER = [False]
#: (func, items) of the running :func:`process_map`: inherited by the forked workers, so neither is pickled
_JOB: list[Any] = []


def _quiet_worker() -> None:
    """Initializer of :func:`process_map`'s workers: no progress bars of their own, one BLAS thread each."""
    from .._progress import set_quiet

    _IN_WORKER[0] = True
    set_quiet(True)
    try:
        from threadpoolctl import threadpool_limits

        threadpool_limits(1)
    except Exception:  # pragma: no cover - threadpoolctl missing: BLAS as configured
        pass


def _call(q: int) -> Any:
    func, xs = _JOB[0]
    return func(xs[q])


def process_map(func: Callable[[P], R], items: Iterable[P], *, desc: str = "points", unit: str = "point", workers: int | None = None) -> list[R]:
    """``[func(x) for x in items]`` in forked worker processes (one per core), results in item order.

    For the grid points of a reproduction that are independent and each seeded on its own, so the results
    do not depend on the number of workers. Serial (in this process) with one worker, one item, inside a
    worker, or where ``fork`` is not available; ``TEAMKF_WORKERS`` sets the number of workers. ``func`` and
    the items are inherited by the forked workers (not pickled: ``func`` may be a closure or read module
    state set up before the call); only the results are pickled back. A progress bar over the items is shown
    on a terminal (:mod:`teamkf._progress`); the workers' own bars are silenced and they use one BLAS
    thread each.
    """
    import multiprocessing as mp

    xs = list(items)
    n = pool_workers(len(xs)) if workers is None else max(1, min(int(workers), len(xs)))
    if n <= 1 or _IN_WORKER[0] or _JOB or "fork" not in mp.get_all_start_methods():
        return [func(x) for x in progress(xs, desc=desc, unit=unit)]
    from concurrent.futures import ProcessPoolExecutor, as_completed

    from .._progress import bar

    out: list[Any] = [None] * len(xs)
    _JOB.append((func, xs))
    try:
        with (
            bar(len(xs), desc=desc, unit=unit) as b,
            ProcessPoolExecutor(max_workers=n, mp_context=mp.get_context("fork"), initializer=_quiet_worker) as ex,
        ):
            futs = {ex.submit(_call, q): q for q in range(len(xs))}
            for fut in as_completed(futs):
                out[futs[fut]] = fut.result()
                b.update(1)
    finally:
        _JOB.clear()
    return out


def _cpu_count() -> int:
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not on Linux
        return max(1, os.cpu_count() or 1)


def local_cluster(n_workers: int | None = None, **kwargs: Any) -> Any:
    """The embedded Dask cluster of ``scheduler="local"``: a ``LocalCluster`` tuned for sweep points.

    ``n_workers`` single-threaded worker processes (default: one per available
    core), no dashboard, quiet logs; ``kwargs`` go to ``LocalCluster``. The
    workers start with :data:`WORKER_ENV` (one BLAS / OpenMP thread each: the
    points are the parallelism) and *without* ``MALLOC_TRIM_THRESHOLD_``,
    which Dask sets to 65536 by default: a fixed glibc malloc threshold turns
    off glibc's adaptive mmap threshold, and the many mid-sized numpy arrays
    of designs and Monte Carlo runs then cost about 40 % more time per point.
    (Workers restarted by their nanny get the same environment.) Close it
    with ``.close()``.

    Side effect: ``MALLOC_TRIM_THRESHOLD_`` is removed from this process's
    environment (where an earlier Dask cluster may have put it), as a worker
    restarted later inherits it from here.
    """
    distributed = V.require("distributed", "dask")
    import dask

    environ = {k: v for k, v in (dask.config.get("distributed.nanny.pre-spawn-environ", default={}) or {}).items() if k != "MALLOC_TRIM_THRESHOLD_"}
    environ.update(WORKER_ENV)
    # A nanny copies pre-spawn-environ into this process's environment before it spawns (or restarts) a
    # worker, which inherits it; so a MALLOC_TRIM_THRESHOLD_ left here by an earlier Dask cluster would
    # reach our workers: it is removed for good. The other variables are put back as they were.
    saved = {k: os.environ.get(k) for k in environ}
    os.environ.pop("MALLOC_TRIM_THRESHOLD_", None)
    options = {
        "threads_per_worker": 1,
        "processes": True,
        "dashboard_address": None,
        "silence_logs": logging.ERROR,
        "env": dict(WORKER_ENV),
        # workers import teamkf's numerical stack while the cluster starts, not in their first task
        "preload": ["teamkf.study.evaluate"],
        **kwargs,
    }
    try:
        with dask.config.set({"distributed.nanny.pre-spawn-environ": environ}):
            return distributed.LocalCluster(n_workers=n_workers or _cpu_count(), **options)
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def _open_client(scheduler: Any, n_workers: int | None) -> tuple[Any, list[Any]]:
    """A Dask client for ``scheduler`` and the objects this run owns (closed at the end, in order).

    The plug-ins loaded in this process (``--plugin``, ``TEAMKF_PLUGINS``, :func:`~teamkf.estimators.registry.load_plugin`)
    are loaded on every worker, present and future (a ``WorkerPlugin``), before any task of a plug-in family
    is unpickled there. A worker that holds another version of a plug-in (its file was edited since, or
    another run loaded it) gets this run's version from the shipped source; where that cannot be (an
    importable module that differs there, or two families of one name), the run is refused in one line
    naming the worker and the scheduler. Tasks wrapped with :func:`with_plugins` check the versions again.
    """
    client, owned = _connect(scheduler, n_workers)
    from ..estimators.registry import loaded_plugins, plugin_identities

    plugins = loaded_plugins()
    if plugins:
        import uuid

        name = f"teamkf-plugins-{uuid.uuid4().hex[:12]}"  # this run's: unregistered when it ends
        try:
            client.register_plugin(_plugin_loader(plugins, plugin_identities(), _address(client)), name=name)
        except BaseException:
            _forget(client, name)
            for obj in owned:
                obj.close()
            raise
        owned.insert(0, _Unregister(client, name))
    return client, owned


def _address(client: Any) -> str:
    try:
        return str(client.scheduler.address)
    except AttributeError:  # pragma: no cover - an unusual client
        return "?"


def _forget(client: Any, name: str) -> None:
    try:
        client.unregister_worker_plugin(name)
    except Exception:  # noqa: BLE001  (best effort: the plug-in may not have reached the scheduler)
        pass


class _Unregister:
    """Owned by a run: removes its plug-in loader from the cluster when the run ends (the workers keep the modules)."""

    def __init__(self, client: Any, name: str) -> None:
        self.client, self.name = client, name

    def close(self) -> None:
        if getattr(self.client, "status", "running") == "running":
            _forget(self.client, self.name)


def _where(scheduler: str) -> str:
    """ "the Dask worker ADDRESS of the cluster at SCHEDULER" on a worker ("" elsewhere)."""
    try:
        from distributed import get_worker

        return f"the Dask worker {get_worker().address} of the cluster at {scheduler}"
    except (ImportError, ValueError):
        return ""


def _plugin_loader(plugins: Any, identities: Any = None, scheduler: str = "?") -> Any:
    """A Dask ``WorkerPlugin`` that loads the driver's teamkf plug-ins (this version of each) on a worker when it starts."""
    from distributed.diagnostics.plugin import WorkerPlugin

    from ..estimators.registry import load_plugins_into

    class TeamkfPlugins(WorkerPlugin):
        def __init__(self, plugins: Any, identities: Any, scheduler: str) -> None:
            self.plugins, self.identities, self.scheduler = plugins, identities, scheduler

        def setup(self, worker: Any) -> None:
            where = f"the Dask worker {worker.address} of the cluster at {self.scheduler}"
            load_plugins_into(self.plugins, self.identities, where)

    return TeamkfPlugins(plugins, identities, scheduler)


class _WithPlugins:
    """A task function that first checks, on the worker, that it holds this run's plug-in versions (:func:`with_plugins`)."""

    def __init__(self, func: Callable[..., Any], identities: dict[str, str], scheduler: str) -> None:
        self.func, self.identities, self.scheduler = func, identities, scheduler
        self.__name__ = getattr(func, "__name__", "task")

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        from ..estimators.registry import check_plugin_identities

        check_plugin_identities(self.identities, _where(self.scheduler))
        return self.func(*args, **kwargs)


def with_plugins(func: Callable[..., R], client: Any) -> Callable[..., R]:
    """``func`` as a Dask task that carries the identities (name, sha256) of this process's plug-ins.

    On the worker it refuses to run, in one line naming the worker, the scheduler and both hashes, unless the
    worker holds exactly these versions: a plug-in edited or replaced meanwhile is never used silently.
    Without plug-ins ``func`` is returned as it is.
    """
    from ..estimators.registry import plugin_identities

    ids = plugin_identities()
    if not ids:
        return func
    return _WithPlugins(func, ids, _address(client))  # type: ignore[return-value]


def _connect(scheduler: Any, n_workers: int | None) -> tuple[Any, list[Any]]:
    """A Dask client for ``scheduler`` and the objects this run owns (closed at the end), before plug-ins."""
    distributed = V.require("distributed", "dask")
    if isinstance(scheduler, distributed.Client):
        return scheduler, []
    if not isinstance(scheduler, str):
        if hasattr(scheduler, "scheduler_address"):
            client = distributed.Client(scheduler)
            return client, [client]
        raise ArgumentError(
            f"scheduler: expected 'local', 'serial', a Dask scheduler address, a Client or a cluster, found {type(scheduler).__name__}",
            argument="scheduler",
        )
    if scheduler == "local":
        cluster = local_cluster(n_workers)
        try:
            client = distributed.Client(cluster)
        except BaseException:
            cluster.close()
            raise
        return client, [client, cluster]
    try:
        client = distributed.Client(scheduler, timeout="10s")
    except (OSError, TimeoutError, ValueError) as exc:
        raise ArgumentError(
            f"scheduler: cannot connect to a Dask scheduler at {scheduler!r} ({' '.join(str(exc).split())}); "
            "give the address of a running scheduler (tcp://host:8786), or 'local' / 'serial'"
        ) from None
    return client, [client]
