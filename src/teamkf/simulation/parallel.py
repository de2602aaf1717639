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
from typing import Any, Callable, Iterable, Iterator, TypeVar

from .._progress import progress

__all__ = ["map_points", "use_scheduler", "current_scheduler"]

P = TypeVar("P")
R = TypeVar("R")

_SCHEDULER: contextvars.ContextVar[Any] = contextvars.ContextVar("teamkf_scheduler", default="serial")


def current_scheduler() -> Any:
    return _SCHEDULER.get()


@contextlib.contextmanager
def use_scheduler(scheduler: Any) -> Iterator[None]:
    """Within the block, :func:`map_points` runs on ``scheduler`` ("serial", "local", an address or a Client)."""
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
    from ..study.sweep import _open_client

    client, owned = _open_client(sched, None)
    try:
        futures = client.map(func, pts, pure=False, retries=3)
        return list(client.gather(futures))
    finally:
        for obj in owned:
            obj.close()
