"""Progress bars for long loops: tqdm on a terminal, silent everywhere else.

:func:`progress` wraps an iterable; :func:`bar` is the same bar for work that is counted by hand
(points finished on a cluster, runs, rows). This module is the package's one progress bar. :func:`progress` returns the iterable itself (no cost) unless
every one of these holds:

* ``enabled`` is not False (the ``progress=`` argument of the calling function),
* the output stream (stderr) is a terminal,
* the environment variable ``TEAMKF_PROGRESS`` is not ``0`` / ``false`` / ``no`` / ``off`` (another value than these and ``1`` / ``true`` / ``yes`` / ``on`` is an error),
* :func:`set_quiet` has not been called with True (the CLI's ``--quiet``), and
* tqdm is installed (it comes with ``pip install 'teamkf[dask]'``).

The bar appears only once the loop has run for ``delay`` seconds (2 s by default),
so short loops never print anything; from then on it is redrawn at least every second, so a job
whose work items each take long (one Monte Carlo block, one sweep point) still shows its bar and its
elapsed time. A terminal that reports no width (a pseudo-terminal nobody sized) gets an 80-column bar.

Examples
--------
>>> items = [1, 2, 3]
>>> progress(items, desc="silenced", enabled=False) is items   # no bar: the iterable itself
True
"""

from __future__ import annotations

import os
import sys
import threading
import weakref
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from typing import Any, TypeVar

__all__ = ["progress", "bar", "Bar", "set_quiet", "quiet", "progress_enabled", "DELAY"]

T = TypeVar("T")

#: seconds a loop must run before its bar is shown
DELAY = 2.0

_QUIET = False


def set_quiet(value: bool = True) -> bool:
    """Silence (or re-enable) every progress bar of the process; returns the previous setting."""
    global _QUIET
    old, _QUIET = _QUIET, bool(value)
    return old


@contextmanager
def quiet(value: bool = True) -> Iterator[None]:
    """``with quiet(): ...`` runs the block without progress bars (``quiet(False)`` leaves the setting as it is)."""
    old = set_quiet(value or _QUIET)
    try:
        yield
    finally:
        set_quiet(old)


def _is_tty(stream: Any) -> bool:
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):
        return False


def _width(stream: Any) -> dict[str, Any]:
    """tqdm's size keywords: follow the terminal, or 80 x 24 (``$COLUMNS``, ``$LINES``) where it reports a size of 0.

    A pseudo-terminal that nobody sized reports 0 x 0, and tqdm then draws nothing at all.
    """
    try:
        size = os.get_terminal_size(stream.fileno())
        if size.columns > 0 and size.lines > 0:
            return {"dynamic_ncols": True}
    except (AttributeError, ValueError, OSError):
        pass

    def env(name: str, default: int) -> int:
        v = os.environ.get(name, "")
        return int(v) if v.isdigit() and int(v) > 0 else default

    return {"ncols": env("COLUMNS", 80), "nrows": env("LINES", 24)}


#: the bars drawn by the heartbeat thread (tqdm redraws a bar only when it is updated)
_LIVE: "weakref.WeakKeyDictionary[Any, float]" = weakref.WeakKeyDictionary()  # bar -> when the heartbeat last drew it
_HEART: list[threading.Thread] = []
_HEART_LOCK = threading.Lock()
#: seconds between two redraws of a bar that nothing updated
BEAT = 1.0


def _watch(t: Any) -> Any:
    """Have the heartbeat draw tqdm bar ``t`` once its delay is over, and redraw it every :data:`BEAT` s."""
    with _HEART_LOCK:
        _LIVE[t] = 0.0
        if not _HEART or not _HEART[0].is_alive():
            _HEART[:] = [threading.Thread(target=_beat, name="teamkf-progress", daemon=True)]
            _HEART[0].start()
    return t


def _beat() -> None:
    import time

    while True:
        time.sleep(BEAT / 4)
        with _HEART_LOCK:
            live = list(_LIVE.items())
            if not live:  # the thread ends with the last bar; the next bar starts another
                _HEART.clear()
                return
        for t, drawn in live:
            try:
                now = t._time()
                if t.disable:  # closed
                    drawn = -1.0
                elif now >= t.start_t + t.delay and now - max(t.last_print_t, drawn) >= BEAT:
                    t.refresh()
                    drawn = now
            except Exception:  # pragma: no cover - a bar closed meanwhile: drawn by nobody
                drawn = -1.0
            with _HEART_LOCK:
                if drawn < 0:
                    _LIVE.pop(t, None)
                elif t in _LIVE:
                    _LIVE[t] = drawn
        del live, t  # no reference kept while asleep: a bar nobody holds is collected


def progress_enabled(enabled: bool | None = None, stream: Any = None) -> bool:
    """Whether a bar would be shown on ``stream`` (default stderr) with ``progress=enabled``."""
    if enabled is False or _QUIET:
        return False
    from ._validation import env_switch

    if env_switch("TEAMKF_PROGRESS") is False:  # a value that is not yes or no: one ArgumentError naming it
        return False
    if enabled is not True and not _is_tty(sys.stderr if stream is None else stream):  # True: asked for, shown anyway
        return False
    try:
        import tqdm  # noqa: F401
    except ImportError:
        return False
    return True


def progress(
    iterable: Iterable[T],
    *,
    desc: str | None = None,
    total: int | None = None,
    enabled: bool | None = None,
    unit: str = "it",
    stream: Any = None,
    delay: float | None = None,
) -> Iterable[T]:
    """``iterable``, with a tqdm bar on a terminal (see the module docstring for when it is silent).

    Parameters
    ----------
    iterable : what the loop runs over
    desc : label of the bar
    total : number of items (default: ``len(iterable)`` when it has one)
    enabled : False silences the bar (a function's ``progress=False``); True shows it even when the stream is not
        a terminal (unless quiet); None: only on a terminal
    unit : what one item is ("step", "point", ...)
    stream : where the bar is written (default: stderr)
    delay : seconds before the bar first appears (default :data:`DELAY`)
    """
    out = sys.stderr if stream is None else stream
    if not progress_enabled(enabled, out):
        return iterable
    from tqdm import tqdm

    return _watch(tqdm(iterable, desc=desc, total=total, unit=unit, file=out, delay=DELAY if delay is None else delay, leave=False, **_width(out)))


class Bar:
    """A progress bar updated by hand: ``with bar(total, desc=...) as b: ... b.update(n)``.

    Silent (every method a no-op) under the same rules as :func:`progress`: off a terminal, under
    ``TEAMKF_PROGRESS=0``, after :func:`set_quiet`, with ``enabled=False``, or without tqdm. On a terminal it
    shows the count, the rate and the time left (ETA) once the work has run for ``delay`` seconds.
    """

    def __init__(
        self,
        total: int | None,
        *,
        desc: str | None = None,
        unit: str = "it",
        enabled: bool | None = None,
        initial: int = 0,
        stream: Any = None,
        delay: float | None = None,
        unit_scale: bool = False,
    ) -> None:
        out = sys.stderr if stream is None else stream
        self._tqdm: Any = None
        if progress_enabled(enabled, out):
            from tqdm import tqdm

            self._tqdm = tqdm(
                total=total,
                initial=initial,
                desc=desc,
                unit=unit,
                unit_scale=unit_scale,
                file=out,
                delay=DELAY if delay is None else delay,
                leave=False,
                smoothing=0.1,
                **_width(out),
            )
            _watch(self._tqdm)

    @property
    def shown(self) -> bool:
        """True when the bar writes to its stream (a terminal, not silenced)."""
        return self._tqdm is not None

    def update(self, n: int = 1) -> None:
        """Count ``n`` more items done."""
        if self._tqdm is not None:
            self._tqdm.update(n)

    def close(self) -> None:
        """Remove the bar (idempotent)."""
        if self._tqdm is not None:
            self._tqdm.close()
            self._tqdm = None

    def __enter__(self) -> "Bar":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


def bar(total: int | None, **kwargs: Any) -> Bar:
    """A :class:`Bar` over ``total`` items (keywords as :class:`Bar`)."""
    return Bar(total, **kwargs)
