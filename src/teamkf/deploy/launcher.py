"""Start one OS process per agent, watch them, and leave none behind.

:func:`launch` starts the given commands (one per agent), each in a process group of
its own and, on Linux, with ``PR_SET_PDEATHSIG`` so that a child dies with the
launcher even when the launcher is killed with SIGKILL. On Ctrl-C (SIGINT) or
SIGTERM (its handlers are installed explicitly, also where a shell started it with
SIGINT ignored) the launcher forwards SIGINT to every child (they say goodbye and
exit), waits ``grace`` seconds, then SIGKILLs the rest, reaps them all and
re-raises :class:`Stopped` (a :class:`KeyboardInterrupt` carrying the signal). A child that outlives ``timeout`` is
killed and reported.
"""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from typing import Any, Callable, Sequence

__all__ = ["ChildResult", "Stopped", "launch"]


class Stopped(KeyboardInterrupt):
    """The launcher was stopped by ``signum`` (SIGINT or SIGTERM); its children were stopped and reaped."""

    def __init__(self, signum: int = signal.SIGINT):
        super().__init__(signum)
        self.signum = int(signum)


@dataclass
class ChildResult:
    """One child: its exit status (negative: killed by that signal), whether the launcher killed it, its stderr tail."""

    index: int
    pid: int
    returncode: int
    timed_out: bool
    stderr: str


def _pdeathsig() -> None:  # pragma: no cover - runs in the child between fork and exec
    try:
        import ctypes

        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass


def launch(
    commands: Sequence[Sequence[str]], *, timeout: float, grace: float = 5.0, on_start: Callable[[list[int]], None] | None = None, env: Any = None
) -> list[ChildResult]:
    """Run ``commands`` (one process each) to the end; see the module docstring.

    Returns one :class:`ChildResult` per command, in order.
    """
    procs: list[subprocess.Popen[bytes]] = []
    timed_out: set[int] = set()
    prev = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}

    def on_term(signum: int, frame: Any) -> None:
        raise Stopped(signum)

    in_main = _is_main_thread()
    if in_main:  # explicitly: a shell starts background jobs with SIGINT ignored
        for sig in prev:
            signal.signal(sig, on_term)
    try:
        for cmd in commands:
            procs.append(
                subprocess.Popen(
                    list(cmd),
                    stdout=subprocess.DEVNULL,
                    stderr=subprocess.PIPE,
                    start_new_session=True,
                    preexec_fn=_pdeathsig if sys.platform.startswith("linux") else None,
                    env=env,
                )
            )
        if on_start is not None:
            on_start([p.pid for p in procs])
        errs = _drain(procs)
        end = time.monotonic() + timeout
        while any(p.poll() is None for p in procs):
            if time.monotonic() > end:
                for q, p in enumerate(procs):
                    if p.poll() is None:
                        timed_out.add(q)
                        p.kill()
                break
            time.sleep(0.05)
        for p in procs:
            p.wait()
        return [
            ChildResult(q, p.pid, int(p.returncode), q in timed_out, b"".join(errs[q]).decode("utf-8", "replace")[-4000:])
            for q, p in enumerate(procs)
        ]
    except BaseException:
        _stop_all(procs, grace)
        raise
    finally:
        if in_main:
            for sig, h in prev.items():
                signal.signal(sig, h)


def _is_main_thread() -> bool:
    import threading

    return threading.current_thread() is threading.main_thread()


def _drain(procs: Sequence[subprocess.Popen[bytes]]) -> list[list[bytes]]:
    """Read every child's stderr on a thread (a full pipe would block the child)."""
    import threading

    out: list[list[bytes]] = [[] for _ in procs]

    def read(q: int, p: subprocess.Popen[bytes]) -> None:
        assert p.stderr is not None
        for line in p.stderr:
            out[q].append(line)
            if len(out[q]) > 200:
                del out[q][:100]

    for q, p in enumerate(procs):
        threading.Thread(target=read, args=(q, p), daemon=True).start()
    return out


def _stop_all(procs: Sequence[subprocess.Popen[bytes]], grace: float) -> None:
    """SIGINT every live child, wait up to ``grace`` s, SIGKILL the rest, reap all."""
    for p in procs:
        if p.poll() is None:
            try:
                p.send_signal(signal.SIGINT)
            except ProcessLookupError:
                pass
    end = time.monotonic() + grace
    for p in procs:
        try:
            p.wait(timeout=max(0.0, end - time.monotonic()))
        except subprocess.TimeoutExpired:
            p.kill()
    for p in procs:
        p.wait()
