"""Resources of long computations: memory estimates checked up front, progress on stderr.

Every computation whose memory grows with the horizon or the number of runs
calls :func:`check_memory` with its estimate *before* allocating anything, so
an impossible request fails at once with the estimate instead of with a
``MemoryError`` minutes later. Long loops wrap their iterable in :func:`teamkf._progress.progress`
(re-exported here): a tqdm bar on stderr after a delay, on a terminal only
unless asked for, never with ``progress=False``.
"""

from __future__ import annotations

from typing import TypeVar

from . import _budget
from ._budget import MEMORY_FRACTION, available_memory, format_bytes  # noqa: F401  (re-exported)
from ._progress import progress  # noqa: F401  (the one progress bar of teamkf; re-exported)

__all__ = ["available_memory", "check_memory", "format_bytes", "progress", "MEMORY_FRACTION"]

T_ = TypeVar("T_")


def check_memory(estimate: float, what: str, *, argument: str, fix: str, available: int | None = None) -> None:
    """Refuse a computation whose predicted memory exceeds what the machine has (:func:`teamkf._budget.check_memory`).

    Raises
    ------
    teamkf.exceptions.ResourceError
        When ``estimate > MEMORY_FRACTION * available``.
    """
    _budget.check_memory(estimate, what, argument=argument, fix=fix, available=available_memory() if available is None else available)
