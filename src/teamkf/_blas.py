"""The one BLAS-thread limiter of teamkf.

Medium-sized GEMMs (the CIKF design, the bulk filter's triangular inverses,
every sweep point) run faster on one BLAS thread than on OpenBLAS's spinning
worker threads when the machine is shared or oversubscribed (measured on the
2-core project machine: up to 10-30x), and a sweep needs one thread per point
so that serial and Dask runs give bit-identical numbers.

:func:`blas_threads` uses threadpoolctl when it is installed, else OpenBLAS's
own ``openblas_set_num_threads`` found through ``/proc/self/maps`` (Linux);
elsewhere it does nothing. ``n = None`` leaves BLAS alone.
"""

from __future__ import annotations

import contextlib
from typing import Any, Iterator

__all__ = ["blas_threads", "single_thread_blas"]

_SETTERS = ("openblas_set_num_threads", "openblas_set_num_threads64_", "scipy_openblas_set_num_threads64_", "scipy_openblas_set_num_threads")


def _openblas_handles() -> list[tuple[Any, Any]]:
    """(setter, getter) pairs of every OpenBLAS loaded in this process (Linux /proc/self/maps; else none)."""
    import ctypes
    import re

    try:
        with open("/proc/self/maps") as fh:
            paths = sorted(set(re.findall(r"(/\S*openblas\S*\.so\S*)", fh.read())))
    except OSError:
        return []
    out = []
    for path in paths:
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        for name in _SETTERS:
            getter = name.replace("set_num_threads", "get_num_threads")
            if hasattr(lib, name) and hasattr(lib, getter):
                out.append((getattr(lib, name), getattr(lib, getter)))
                break
    return out


def _load_blas() -> None:
    """Load SciPy's BLAS/LAPACK (it may bundle its own OpenBLAS) before the limit is set: a library loaded inside the
    block would run on its default threads there, and a process that loaded it earlier would not (the serial and Dask
    runs of one computation could then differ in their last bits)."""
    try:
        import scipy.linalg  # noqa: F401
    except ImportError:  # pragma: no cover - SciPy is a dependency
        pass


@contextlib.contextmanager
def blas_threads(n: int | None) -> Iterator[None]:
    """Limit BLAS to ``n`` threads inside the block (None: leave it alone)."""
    if n is None:
        yield
        return
    _load_blas()
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:
        threadpool_limits = None
    if threadpool_limits is not None:
        with threadpool_limits(limits=int(n), user_api="blas"):
            yield
        return
    restore: list[tuple[Any, int]] = []
    try:
        for setter, getter in _openblas_handles():
            old = int(getter())
            setter(int(n))
            restore.append((setter, old))
    except Exception:  # pragma: no cover - best effort only
        pass
    try:
        yield
    finally:
        for setter, old in restore:
            setter(old)


def single_thread_blas() -> contextlib.AbstractContextManager[None]:
    """``blas_threads(1)``."""
    return blas_threads(1)
