"""Sized before started: memory and work of a request, estimated before anything is allocated.

Every public entry whose cost grows with its arguments (runs, steps, state size,
agents, grid points, horizon, memory, iterations) calls :func:`check_memory`
and :func:`check_work` with its estimate first. An impossible request then ends at
once in one :class:`~teamkf.exceptions.ResourceError` that names the argument,
gives the estimate and says what to change, instead of a ``MemoryError`` minutes
later or a silent hang.

Memory
    is compared with what the machine has available now (Linux ``MemAvailable``
    from ``/proc/meminfo``, else ``os.sysconf``; psutil is not needed): at most
    :data:`MEMORY_FRACTION` of it.
Work
    is counted in floating-point operations plus Python-level loop iterations,
    converted to seconds with deliberately optimistic rates (:data:`FLOPS`,
    :data:`LOOPS`). A request whose optimistic time exceeds :func:`work_limit_s`
    (2 hours, or ``TEAMKF_MAX_HOURS``) is refused; a slower but possible one
    runs, with a progress bar and an ETA on a terminal.
"""

from __future__ import annotations

import math
import os
from collections.abc import Iterator
from contextlib import contextmanager

from .exceptions import ResourceError

__all__ = [
    "BATCHED_OPS",
    "DESIGN_STEP_LOOPS",
    "FLOPS",
    "STEP_LOOPS",
    "announce",
    "check_steps",
    "LOOPS",
    "MEMORY_FRACTION",
    "available_memory",
    "check_memory",
    "check_size",
    "check_sweep",
    "check_work",
    "command_settings",
    "format_bytes",
    "format_seconds",
    "hours_argument",
    "max_hours",
    "work_limit_s",
]

#: a computation may use at most this fraction of the memory available when it starts
MEMORY_FRACTION = 0.9
#: floating-point operations per second assumed by :func:`check_work` (optimistic: a refusal is never premature)
FLOPS = 1e11
#: Python-level loop iterations per second assumed by :func:`check_work` (optimistic)
LOOPS = 1e7
#: elementary operations per second of batched small-matrix work (a Monte Carlo over runs): a few times what one core does
BATCHED_OPS = 2e7
#: default limit of :func:`check_work`, in hours (``TEAMKF_MAX_HOURS`` overrides it)
DEFAULT_MAX_HOURS = 2.0


def available_memory() -> int | None:
    """Bytes of memory available to a new allocation now (Linux ``MemAvailable``; else free physical pages), None if unknown."""
    try:
        with open("/proc/meminfo", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return int(os.sysconf("SC_AVPHYS_PAGES")) * int(os.sysconf("SC_PAGE_SIZE"))
    except (ValueError, OSError, AttributeError):  # pragma: no cover - non-POSIX
        return None


def format_bytes(n: float) -> str:
    """``1.5 GiB``-style size (up to EiB; beyond, in powers of ten)."""
    if not math.isfinite(n):
        return "an unbounded amount"
    for unit in ("bytes", "KiB", "MiB", "GiB", "TiB", "PiB", "EiB"):
        if abs(n) < 1024 or unit == "EiB":
            if unit == "EiB" and abs(n) >= 1024:
                return f"{n * 1024.0**6:.2e} bytes"
            return f"{n:.0f} {unit}" if unit == "bytes" else f"{n:.1f} {unit}"
        n /= 1024
    return f"{n:.1f} EiB"  # pragma: no cover


def format_seconds(s: float) -> str:
    """``3.2 hours``-style duration (seconds to years; beyond, in e-notation years)."""
    if not math.isfinite(s):
        return "forever"
    for limit, div, unit in ((120, 1, "s"), (7200, 60, "minutes"), (172800, 3600, "hours"), (3.156e7 * 2, 86400, "days")):
        if s < limit:
            return f"{s / div:.0f} {unit}" if unit == "s" else f"{s / div:.1f} {unit}"
    years = s / 3.156e7
    return f"{years:.1f} years" if years < 1e4 else f"{years:.1e} years"


def work_limit_s() -> float:
    """The longest optimistic run time accepted, in seconds (``TEAMKF_MAX_HOURS``, default 2 h; not a finite number > 0: ArgumentError)."""
    from ._validation import env_hours

    return env_hours("TEAMKF_MAX_HOURS", DEFAULT_MAX_HOURS) * 3600.0  # a bad value is one ArgumentError naming it, never ignored


def hours_argument(text: str) -> float:
    """The ``--max-hours`` argument of the ``teamkf`` command: a finite number of hours > 0 (argparse type)."""
    import argparse

    try:
        hours = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number of hours > 0 (e.g. 24), found {text!r}") from None
    if not (math.isfinite(hours) and hours > 0):
        raise argparse.ArgumentTypeError(
            f"expected a finite number of hours > 0 (e.g. 24; for no practical limit a large number such as 1e6), found {text!r}"
        )
    return hours


@contextmanager
def max_hours(hours: float | None) -> Iterator[None]:
    """``with max_hours(24): ...`` raises the work limit of :func:`check_work` to ``hours`` inside the block (None: unchanged).

    It sets ``TEAMKF_MAX_HOURS`` for the block (so that worker processes started inside inherit it) and restores it after.
    """
    if hours is None:
        yield
        return
    old = os.environ.get("TEAMKF_MAX_HOURS")
    os.environ["TEAMKF_MAX_HOURS"] = repr(float(hours))
    try:
        yield
    finally:
        if old is None:
            os.environ.pop("TEAMKF_MAX_HOURS", None)
        else:
            os.environ["TEAMKF_MAX_HOURS"] = old


@contextmanager
def command_settings(hours: float | None) -> Iterator[None]:
    """The settings of one ``teamkf`` command: ``--max-hours`` (over ``TEAMKF_MAX_HOURS``), then every ``TEAMKF_*`` variable checked.

    A bad value (``TEAMKF_MAX_HOURS=abc``, ``TEAMKF_PROGRESS=maybe``, ...) is one
    :class:`~teamkf.exceptions.ArgumentError` naming the variable before any work
    (:func:`teamkf._validation.check_environment`); a set variable whose name is close to one teamkf reads
    (``TEAMKF_MAX_HOUR``) is one ``teamkf: warning:`` line on stderr.
    """
    import sys

    from ._validation import check_environment

    with max_hours(hours):
        for note in check_environment():
            print(f"teamkf: warning: {note}", file=sys.stderr)
        yield


def check_memory(estimate: float, what: str, *, argument: str, fix: str, available: int | None = None) -> None:
    """Refuse a computation whose predicted peak memory exceeds what the machine has.

    Parameters
    ----------
    estimate : float
        Predicted peak memory in bytes (a float: products of large sizes do not overflow).
    what : str
        The computation, for the message (``"the MTMSE design over T = 100000 steps"``).
    argument : str
        The argument that sets the size (``"horizon"``, ``"n_runs"``); named in the error.
    fix : str
        How to make it fit.
    available : int, optional
        Bytes available (default :func:`available_memory`; tests pass a number).

    Raises
    ------
    teamkf.exceptions.ResourceError
        When ``estimate > MEMORY_FRACTION * available``.
    """
    avail = available_memory() if available is None else available
    if avail is None or estimate <= MEMORY_FRACTION * avail:
        return
    raise ResourceError(
        f"{argument}: {what} needs about {format_bytes(estimate)} of memory, but this machine has {format_bytes(avail)} available; {fix}",
        argument=argument,
    )


def check_work(flops: float, what: str, *, argument: str, fix: str, loops: float = 0.0, rate: float = FLOPS, limit_s: float | None = None) -> float:
    """Refuse a computation whose optimistic run time exceeds the limit; returns that time in seconds.

    The time is :math:`t = \\text{flops} / F + \\text{loops} / L` with the optimistic rates
    :data:`FLOPS` and :data:`LOOPS`, so a refused request would take longer than the limit
    on any machine teamkf runs on.

    Parameters
    ----------
    flops : float
        Floating-point operations.
    what : str
        The computation, for the message.
    argument : str
        The argument that sets the size; named in the error.
    fix : str
        How to make it smaller.
    loops : float
        Python-level loop iterations (each costs at least :math:`1/L` seconds).
    rate : float
        Operations per second for ``flops`` (default :data:`FLOPS`; batched small-matrix
        work such as a Monte Carlo passes :data:`BATCHED_OPS`).
    limit_s : float, optional
        The limit (default :func:`work_limit_s`).

    Raises
    ------
    teamkf.exceptions.ResourceError
    """
    t = float(flops) / rate + float(loops) / LOOPS
    limit = work_limit_s() if limit_s is None else limit_s
    if t > limit:
        raise ResourceError(
            f"{argument}: {what} needs at least {format_seconds(t)} of computing (about {float(flops) + float(loops):.2g} operations), "
            f"over the limit of {format_seconds(limit)}; {fix} (or raise the limit: teamkf --max-hours H, or TEAMKF_MAX_HOURS=H)",
            argument=argument,
        )
    return t


def check_size(n: float, argument: str, *, maximum: float, what: str, fix: str) -> None:
    """Refuse a count (agents, grid points, runs) above a representable or sensible ``maximum``.

    Raises
    ------
    teamkf.exceptions.ResourceError
    """
    if n > maximum:
        raise ResourceError(f"{argument}: {what} {n:,.0f} exceeds the largest this computation can hold ({maximum:,.0f}); {fix}", argument=argument)


#: loop iterations one step of any recursion over the horizon costs at least (a few numpy calls: 10 us at :data:`LOOPS`)
STEP_LOOPS = 100
#: loop iterations one step of a built-in design costs at least: 0.1 ms (measured on one core: 0.38 ms per step of the
#: centralized Kalman recursion of 2 agents, 1.0 ms of MTMSE, 1.6 ms of KCF)
DESIGN_STEP_LOOPS = 1000
#: a computation estimated longer than this many seconds says so on a terminal before it starts
ANNOUNCE_S = 30.0


def announce(seconds: float, what: str) -> None:
    """On a terminal (where progress bars are shown), say once that ``what`` will take about ``seconds`` or more, and that Ctrl-C stops it."""
    if seconds > ANNOUNCE_S:
        import sys

        from ._progress import progress_enabled

        if progress_enabled():
            print(f"teamkf: {what}: about {format_seconds(seconds)} or more of computing; Ctrl-C stops it", file=sys.stderr)


def check_steps(n_steps: int, n_agents: int = 1, *, what: str = "a recursion", argument: str = "horizon", per_step: float = STEP_LOOPS) -> float:
    r"""Refuse a recursion over ``n_steps`` steps whose Python-level loop alone exceeds the work limit; announce a long one.

    Every design and simulation of teamkf steps through the horizon in Python, each step costing at least
    ``per_step`` loop iterations (:data:`STEP_LOOPS`; :data:`DESIGN_STEP_LOOPS` for a built-in design), so
    :math:`t \ge T \cdot` ``per_step`` :math:`/ L` (:data:`LOOPS`).

    Returns
    -------
    float
        The estimate in seconds.

    Raises
    ------
    teamkf.exceptions.ResourceError
        Naming ``argument``.
    """
    t = check_work(
        0.0,
        f"{what} over T = {n_steps:,} steps",
        argument=argument,
        fix="use a shorter horizon (or omit it for a steady-state design)",
        loops=float(n_steps) * per_step,
    )
    announce(t, f"{what} over T = {n_steps:,} steps")
    return t


#: loop iterations a sweep's grid point costs besides its Monte Carlo (reading its scenario, designing, writing its Parquet part): ~10 ms
POINT_LOOPS = 1e5


def check_sweep(sizes: list[int], runs: int, T: int, dx: int, dy: int, n_agents: int, n_estimators: int) -> None:
    """Refuse, before any grid point is built, a sweep whose grid or runs would take longer than the limit.

    Parameters
    ----------
    sizes : list of int
        The number of values of each grid key (the grid has their product of points).
    runs, T : int
        Monte Carlo runs per point (0: analytic only) and steps.
    dx, dy, n_agents, n_estimators : int
        The base scenario's sizes.

    Raises
    ------
    teamkf.exceptions.ResourceError
        Naming ``grid`` (too many points) or ``runs``.
    """
    n_points = math.prod(sizes)
    shape = " x ".join(map(str, sizes))
    check_work(
        0.0,
        f"a grid of {shape} = {n_points:,} points",
        argument="grid",
        fix="use fewer values per key (or split the sweep into several files)",
        loops=n_points * POINT_LOOPS,
    )
    if runs:
        per = 50.0 + dx * dx + dx * dy + n_estimators * n_agents * dx * (dx + dy)
        check_work(
            float(n_points) * runs * T * per,
            f"{n_points:,} grid points x {runs:,} Monte Carlo runs x {T} steps x {n_estimators} estimators",
            argument="runs",
            fix="use fewer runs (the 95 % interval only shrinks like 1/sqrt(runs)) or fewer grid points",
            loops=n_points * POINT_LOOPS,
            rate=BATCHED_OPS,
        )
