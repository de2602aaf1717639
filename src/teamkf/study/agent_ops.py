"""Operating deployed agents: the estimate stream, rejoin, the agents' reports, ``teamkf record merge``, run folders.

* :class:`AgentStream` (``teamkf agent --stream FILE``): row k of the file is ẑ_i(k) (raw little-endian
  float64), written as it is computed; steps the process did not run are NaN rows. With ``--rejoin`` the
  file of the process before is kept and continued, so one file holds every step the agent ran, and
  its length says how many its predecessor completed (``previous_steps`` in the report).
* :func:`report_json`: the agent's report (``--report``) with its run (run id, scenario, fingerprint,
  estimator, agents, steps, loss), what ``teamkf record merge`` checks.
* :func:`cmd_record_merge`: ``teamkf record merge REPORT... --out DROPS``.
* :func:`new_run_dir` / :func:`clean_stale_run_dirs`: ``teamkf deploy``'s temporary folder is named
  after its process id (``teamkf-deploy-<pid>-*``); a deploy that was SIGKILLed cannot remove it, so
  every later deploy removes the folders whose process is gone.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import shutil
import sys
import tempfile
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from ..exceptions import ArgumentError
from .agent_input import paced

__all__ = ["AgentStream", "check_rejoin", "rate_limited", "report_json", "cmd_record_merge", "new_run_dir", "clean_stale_run_dirs"]

rate_limited = paced


class AgentStream:
    """Row k = ẑ_i(k) of ``path`` (see the module docstring); ``keep``: continue the file of the process before."""

    def __init__(self, path: str, dz: int, *, keep: bool = False, opener: Any = None):
        self.row = 8 * int(dz)
        self.previous: int | None = None
        exists = keep and os.path.isfile(path) and not os.path.islink(path)
        self.fh: Any
        if exists:
            self.fh = open(path, "r+b")  # noqa: SIM115 - closed by close()
        else:  # the output guard's stream (no symbolic link, not an input), or a plain new file
            self.fh = opener() if opener is not None else open(path, "wb")  # noqa: SIM115
        if exists:
            size = os.fstat(self.fh.fileno()).st_size
            self.previous = size // self.row
            self.fh.truncate(self.previous * self.row)  # a row cut short by the crash
            self.previous = self._completed()
        self.rows = self.previous or 0

    def _completed(self) -> int:
        """Rows up to the last finite one (the process before may have padded NaN rows itself)."""
        self.fh.seek(0)
        z = np.frombuffer(self.fh.read(), dtype="<f8").reshape(-1, self.row // 8)
        ok = np.flatnonzero(~np.isnan(z).all(axis=1))
        return int(ok[-1]) + 1 if ok.size else 0

    def write(self, k: int, z: np.ndarray) -> None:
        if k > self.rows:  # the steps it did not run: NaN
            self.fh.seek(self.rows * self.row)
            self.fh.write(np.full((k - self.rows) * (self.row // 8), np.nan, dtype="<f8").tobytes())
        self.fh.seek(k * self.row)
        self.fh.write(np.asarray(z, dtype="<f8").tobytes())
        self.fh.flush()
        self.rows = max(self.rows, k + 1)

    def close(self) -> None:
        self.fh.close()


def check_rejoin(design: Any, i: int, graph: Any, *, rejoin: bool, agent: Any = None) -> Any:
    """Agent i's :class:`~teamkf.deploy.AgentCore`; with ``rejoin``, one line for a family that cannot restart at a later step."""
    from ..deploy import AgentCore
    from ..deploy.agent import restart_hook

    core = AgentCore(design, i, agent=agent, graph=graph)  # agent: rebuilt from its slice (--design), else from the design
    if rejoin and restart_hook(core) is None:
        raise ArgumentError(
            f"--rejoin: {design.estimator} defines no restart at a later step (a fresh agent from the design's prior needs "
            "the family's restart_state and its loss-tolerant step; teamkf's KCF, MTMSE and MMSE have them); restart the whole team instead",
            argument="--rejoin",
        )
    return core


def report_json(res: Any, **extra: Any) -> dict[str, Any]:
    """The agent's report: :meth:`~teamkf.deploy.AgentResult.to_json` and ``extra`` (its run, previous steps, input counts)."""
    d = res.to_json()
    d.update(extra)
    return d


# ---------------------------------------------------------------------------
# teamkf record merge
# ---------------------------------------------------------------------------
def cmd_record_merge(args: Any) -> int:
    """``teamkf record merge``: exit 0 with the record written; 2 (one line per problem on stderr) when the reports are not one run."""
    from ..deploy.merge import merge_reports, read_report
    from .outputs import check_output, write_atomic

    check_output(args.out, "--out", inputs=args.reports)
    reports = [(str(p), read_report(p)) for p in args.reports]
    record, problems = merge_reports(reports, died=dict(args.died))
    if problems:
        for line in problems[:-1]:
            print(f"teamkf record merge: {line}", file=sys.stderr)
        more = f" ({len(problems)} problems, above)" if len(problems) > 1 else ""
        raise ArgumentError(f"REPORT: {problems[-1]}{more}", argument="REPORT")
    text = json.dumps(record.to_json(), indent=1) + "\n"
    write_atomic(args.out, lambda fh: fh.write(text), text=True)
    if args.json:
        print(json.dumps({"out": args.out, "agents": record.n_agents, "steps": record.n_steps, "missed": len(record.missed)}))
    else:
        rj = "".join(f"; agent {a} rejoined at step {seg[0][0]}" for a, seg in sorted(record.rejoined.items()))
        print(f"{len(reports)} reports of run {record.run_id} merged: {len(record.missed)} missed messages{rj}; drop record written to {args.out}")
    return 0


# ---------------------------------------------------------------------------
# deploy's temporary folder
# ---------------------------------------------------------------------------
_RUN_DIR = re.compile(r"^teamkf-deploy-(\d+)-")


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def clean_stale_run_dirs(root: str | None = None) -> list[str]:
    """Remove this user's ``teamkf-deploy-<pid>-*`` folders whose process is gone (a SIGKILLed deploy); returns them."""
    base = Path(root or tempfile.gettempdir())
    gone: list[str] = []
    try:
        entries = list(base.iterdir())
    except OSError:
        return gone
    for d in entries:
        m = _RUN_DIR.match(d.name)
        if not m or not d.is_dir() or d.is_symlink():
            continue
        try:
            if d.stat().st_uid != os.getuid() or _alive(int(m.group(1))):
                continue
        except OSError:
            continue
        shutil.rmtree(d, ignore_errors=True)
        gone.append(str(d))
    return gone


@contextlib.contextmanager
def sigterm_interrupts() -> Iterator[None]:
    """SIGTERM raises :class:`~teamkf.deploy.launcher.Stopped` (a KeyboardInterrupt with the signal) meanwhile (main thread only)."""
    import signal
    import threading

    from ..deploy.launcher import Stopped

    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def on_term(signum: int, frame: Any) -> None:
        raise Stopped(signum)

    prev = signal.signal(signal.SIGTERM, on_term)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, prev)


def new_run_dir() -> Path:
    """A fresh ``teamkf-deploy-<pid>-*`` folder, after removing the stale ones."""
    clean_stale_run_dirs()
    return Path(tempfile.mkdtemp(prefix=f"teamkf-deploy-{os.getpid()}-"))
