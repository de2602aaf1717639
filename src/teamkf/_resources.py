"""Resources of long computations: memory estimates checked up front, progress on stderr.

Every computation whose memory grows with the horizon or the number of runs
calls :func:`check_memory` with its estimate *before* allocating anything, so
an impossible request fails at once with the estimate instead of with a
``MemoryError`` minutes later. Long loops wrap their iterable in :func:`teamkf._progress.progress`
(re-exported here): a tqdm bar on stderr after a delay, on a terminal only
unless asked for, never with ``progress=False``.
"""

from __future__ import annotations

import os
from typing import TypeVar

from ._progress import progress  # noqa: F401  (the one progress bar of teamkf; re-exported)
from .exceptions import ArgumentError

__all__ = ["available_memory", "check_memory", "format_bytes", "progress", "MEMORY_FRACTION"]

#: a computation may use at most this fraction of the memory available when it starts
MEMORY_FRACTION = 0.9

T_ = TypeVar("T_")


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
    """``1.5 GiB``-style size."""
    for unit in ("bytes", "KiB", "MiB", "GiB", "TiB", "PiB"):
        if abs(n) < 1024 or unit == "PiB":
            return f"{n:.0f} {unit}" if unit == "bytes" else f"{n:.1f} {unit}"
        n /= 1024
    return f"{n:.1f} PiB"  # pragma: no cover


def check_memory(estimate: float, what: str, *, argument: str, fix: str, available: int | None = None) -> None:
    """Refuse a computation whose predicted memory exceeds what the machine has.

    Parameters
    ----------
    estimate : float
        Predicted peak memory in bytes.
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
    teamkf.exceptions.ArgumentError
        When ``estimate > MEMORY_FRACTION * available``.
    """
    avail = available_memory() if available is None else available
    if avail is None or estimate <= MEMORY_FRACTION * avail:
        return
    raise ArgumentError(
        f"{argument}: {what} needs about {format_bytes(estimate)} of memory, but this machine has {format_bytes(avail)} available; {fix}",
        argument=argument,
    )
