"""What one deployed agent reads: its own log, or live ``step,y0,...`` lines on stdin.

* :func:`read_own_log`: ``teamkf agent --measurements FILE`` takes a log of only agent i's rows
  (every ``agent`` cell equal to i, or no ``agent`` column at all) as well as a team log; the
  other agents' columns are never used by agent i (they are laid out as zeros). The steps present
  define the number of steps T (``--steps`` shortens it). A step without a row of agent i (a lost
  sample) is refused in one line naming the step: no family has an online model of a missing own
  measurement (the recorded-gaps design needs every gap in advance).
* :class:`StepLines`: ``--measurements -`` reads one line per step, ``step,y0,...`` (comma- or
  space-separated; the step first). A line whose step is the one expected is used; a *repeated*
  step or one *out of order* (a step already passed) is named in a one-line warning on stderr and
  ignored; a *gap* (the line's step is ahead of the expected one: lines were lost) stops the agent
  with one line naming the missing step, since no family fuses a missing own measurement online.
  A line without its step (only the d_y numbers: the format before steps were required) is refused
  with the new format in the message. Nothing is ever shifted silently.
* :func:`paced`: ``--rate HZ`` releases step k of a log at t0 + (k - k0) / HZ (a recorded log played
  at its sensor's rate).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import IO, Any, Callable

import numpy as np

from ..exceptions import ArgumentError
from . import measurements as M
from .measurements import format as F

__all__ = ["read_own_log", "StepLines", "paced"]


def read_own_log(path: str, system: Any, horizon: int | None, i: int) -> M.MeasurementLog:
    """Agent ``i``'s log (own rows only, or a team log) as a team :class:`~teamkf.study.measurements.MeasurementLog`.

    The other agents' measurements (and offsets) are zeros: agent i consumes only its own column.
    A missing own value is refused with its step (see the module docstring).
    """
    p = Path(path)
    suffix = F.file_suffix(p, "--measurements")
    if not p.exists():
        raise FileNotFoundError(2, "No such file or directory", str(p))
    if suffix == ".npz":
        log = F.read_npz(p, system, horizon)
    else:
        log = _read_rows(p, suffix, system, horizon, i)
    yi = log.y[i]
    gone = np.flatnonzero(np.isnan(yi).any(axis=1))
    if gone.size:
        s = int(gone[0])
        raise M.MeasurementFileError(
            f"--measurements: {p}: agent {i} has no value for step {s} (a lost sample; the log runs to step {log.n_steps - 1}); "
            "no family fuses a missing own measurement online: fill it, or end the log before it",
            argument="--measurements",
        )
    ys = [yi if j == i else np.zeros_like(log.y[j]) for j in range(system.n_agents)]
    d = None if log.d is None else [log.d[j] if j == i else np.zeros_like(log.d[j]) for j in range(system.n_agents)]
    return M.MeasurementLog.from_arrays(ys, system, horizon, source=log.source, u=log.u, b=log.b, d=d)


def _read_rows(p: Path, suffix: str, system: Any, horizon: int | None, i: int) -> M.MeasurementLog:
    csv = suffix == ".csv"
    df = F._read_table(p, suffix)
    if "agent" not in df.columns:  # an own log may leave the agent out
        df.insert(1 if "step" in df.columns else 0, "agent", i)
    cols = F.check_columns(df, p, system)
    if len(df) == 0:
        raise F.file_error(p, "", f"no data rows; expected one row per step of agent {i}")
    step, agent, vals = F.validate_rows(df, p, system, horizon, None, csv)
    if not (agent == i).any():
        raise F.file_error(p, "column 'agent'", f"no row of agent {i} (found agents {sorted(set(agent.tolist()))}); give this agent's log")
    dys = system.dy
    own_only = bool((agent == i).all())
    T = int(step[agent == i].max()) + 1 if own_only else int(step.max()) + 1
    dv = F.offset_values(df, cols, p, system, agent, vals, csv)

    ys = F.per_agent_rows(vals, step, agent, T, dys)
    u, b = F.step_inputs(df, cols, step, T, p, csv)
    ds = None if dv is None else F.per_agent_rows(dv, step, agent, T, dys)
    if ds is not None:  # the others' offsets never reach agent i; their absent rows are not missing values here
        ds = [dj if j == i else np.zeros_like(dj) for j, dj in enumerate(ds)]
    ys = [yj if j == i else np.zeros_like(yj) for j, yj in enumerate(ys)]
    return M.MeasurementLog.from_arrays(ys, system, horizon, source=str(p), u=u, b=b, d=ds)


class StepLines:
    """``--measurements -``: live ``step,y0,...`` lines (see the module docstring); call it with the step k expected.

    Parameters
    ----------
    stream : the text stream (stdin)
    d_y : agent i's measurement width
    n_steps : the run's steps (lines for steps >= n_steps are refused)
    ybar : (n_steps, d_y) known means removed from y, or None
    agent, estimator : named in the messages
    warn : where the one-line warnings go (default: stderr)
    """

    def __init__(
        self,
        stream: IO[str],
        d_y: int,
        n_steps: int,
        ybar: np.ndarray | None = None,
        *,
        agent: int = 0,
        estimator: str = "",
        warn: Callable[[str], None] | None = None,
    ):
        self.stream, self.d_y, self.n_steps, self.ybar = stream, int(d_y), int(n_steps), ybar
        self.agent, self.estimator = agent, estimator
        self.warn = warn if warn is not None else (lambda m: print(m, file=sys.stderr, flush=True))
        self.line_no = 0
        self.last: int | None = None
        #: lines ignored: "repeated", "out_of_order", "before_start" (a rejoined agent skips the steps it missed)
        self.counts: dict[str, int] = {"repeated": 0, "out_of_order": 0, "before_start": 0}
        self.start: int | None = None

    def _where(self) -> str:
        return f"--measurements -: line {self.line_no}"

    def _parse(self, line: str) -> tuple[int, np.ndarray]:
        fields = line.replace(",", " ").split()
        fmt = f"'step,y0{',...' if self.d_y > 1 else ''}' (the step, then {self.d_y} number{'s' if self.d_y > 1 else ''})"
        if len(fields) == self.d_y:
            raise ArgumentError(
                f"{self._where()}: expected {fmt}, found {line.strip()!r} without its step; every live line carries its step "
                "now (so a lost line is detected, not shifted): prefix each line with its step",
                argument="--measurements",
            )
        if len(fields) != self.d_y + 1:
            raise ArgumentError(f"{self._where()}: expected {fmt}, found {line.strip()!r}", argument="--measurements")
        try:
            s = int(fields[0])
        except ValueError:
            raise ArgumentError(
                f"{self._where()}: expected {fmt} with an integer step first, found {fields[0]!r}", argument="--measurements"
            ) from None
        if not 0 <= s < self.n_steps:
            raise ArgumentError(f"{self._where()}: step {s} is outside the run's steps 0..{self.n_steps - 1}", argument="--measurements")
        try:
            y = np.array([[float(v) for v in fields[1:]]])
        except ValueError:
            y = np.array([[np.nan]])
        if y.shape != (1, self.d_y) or not np.all(np.isfinite(y)):
            raise ArgumentError(f"{self._where()}: step {s}: expected {self.d_y} finite numbers, found {line.strip()!r}", argument="--measurements")
        return s, y

    def __call__(self, k: int) -> Any:
        if k >= self.n_steps:
            return None
        if self.start is None:
            self.start = k
        while True:
            line = self.stream.readline()
            if not line:
                return None
            self.line_no += 1
            if not line.strip():
                continue
            s, y = self._parse(line)
            if s < k:
                if s < self.start and (self.last is None or s > self.last):  # a rejoined agent: the steps before its first
                    self.counts["before_start"] += 1
                    self.last = s
                    continue
                kind = "repeated" if s == self.last else "out_of_order"
                self.counts[kind] += 1
                what = f"step {s} again" if kind == "repeated" else f"step {s} out of order (after step {self.last})"
                self.warn(f"teamkf agent {self.agent}: warning: {self._where()}: {what}, step {k} expected; line ignored")
                continue
            if s > k:
                missing = f"step {k}" if s == k + 1 else f"steps {k}..{s - 1}"
                raise ArgumentError(
                    f"{self._where()}: step {s} follows step {k - 1}: {missing} missing (a lost line); "
                    f"{self.estimator or 'the family'} has no online model of a missing own measurement, so agent {self.agent} stops here",
                    argument="--measurements",
                )
            self.last = s
            return y if self.ybar is None else y - self.ybar[k]


def paced(source: Callable[[int], Any], rate: float | None, stop: Any = None) -> Callable[[int], Any]:
    """``source`` releasing step k at t0 + (k - k0) / rate seconds (k0 the first step asked for); ``rate`` None: unpaced."""
    if rate is None:
        return source
    t0: list[float] = []

    def at_rate(k: int) -> Any:
        if not t0:
            t0.append(time.monotonic() - k / rate)
        wait = t0[0] + k / rate - time.monotonic()
        if wait > 0:
            if stop is not None:
                stop.wait(wait)
            else:
                time.sleep(wait)
        return source(k)

    return at_rate
