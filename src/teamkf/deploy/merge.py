"""The team's drop record from the agents' own reports (``teamkf record merge``): a run on separate machines.

Each ``teamkf agent --report FILE`` writes its report (JSON): what it missed, what it dropped on purpose,
the steps it ran (``started`` .. ``steps_done``) and its run (``run``: run id, scenario name and
fingerprint, estimator, agents, steps, p_drop, seed). :func:`merge_reports` checks that the reports
belong to one run (the same ``run`` table in every report), that every agent is there once (a
restarted agent, ``--rejoin``, adds a report of its own, starting later), and builds the team's
:class:`~teamkf.deploy.replay.DropRecord`, which ``teamkf filter --drops`` replays in-process. An
agent whose process died without a report is given with ``died = {agent: steps it completed}``
(what its ``--stream`` file holds); a rejoined agent's report says that itself when it had the
stream file of the process before it.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Mapping, Sequence

from ..exceptions import ArgumentError
from .replay import DropRecord

__all__ = ["RUN_KEYS", "merge_reports", "read_report"]

#: what every report of one run says the same
RUN_KEYS = ("run_id", "scenario", "fingerprint", "estimator", "agents", "steps", "p_drop", "seed")


def read_report(path: str | Path) -> dict[str, Any]:
    """One agent's report (``teamkf agent --report``), parsed; one line for a file that is none."""
    p = Path(path)
    try:
        d = json.loads(p.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ArgumentError(f"REPORT: no such file {p}; write it with teamkf agent --report", argument="REPORT") from None
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ArgumentError(f"REPORT: {p} is not a JSON agent report ({exc})", argument="REPORT") from None
    if not isinstance(d, dict) or not isinstance(d.get("run"), dict) or "agent" not in d:
        raise ArgumentError(
            f"REPORT: {p}: expected an agent report with its run (written by teamkf agent --report), found no 'run' table", argument="REPORT"
        )
    return d


def _int(v: Any) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def merge_reports(reports: Sequence[tuple[str, Mapping[str, Any]]], *, died: Mapping[int, int] | None = None) -> tuple[DropRecord, list[str]]:
    """The team's drop record from ``(name, report)`` pairs; returns (record, problems).

    The problems (one line each: another run, an agent twice or missing, a malformed entry) make
    the record unusable; the caller reports them. ``died``: agent -> steps completed, for an agent
    whose process left no report.
    """
    died = dict(died or {})
    problems: list[str] = []
    if not reports:
        return DropRecord("", 1, 1), ["no reports given"]
    name0, r0 = reports[0]
    run0 = r0["run"]
    for name, r in reports[1:]:
        for key in RUN_KEYS:
            if r["run"].get(key) != run0.get(key):
                problems.append(f"{name}: run {key} is {r['run'].get(key)!r}, {name0}'s is {run0.get(key)!r}: a report of another run")
                break
    n: Any = run0.get("agents")
    T: Any = run0.get("steps")
    if not (_int(n) and n >= 1 and _int(T) and T >= 1):
        return DropRecord("", 1, 1), problems + [f"{name0}: run: expected agents and steps (integers >= 1), found {n!r} and {T!r}"]
    by_agent: dict[int, list[tuple[str, Mapping[str, Any]]]] = {}
    for name, r in reports:
        a: Any = r.get("agent")
        start: Any = r.get("started", 0)
        done: Any = r.get("steps_done", 0)
        if not (_int(a) and 0 <= a < n):
            problems.append(f"{name}: agent: expected an agent 0..{n - 1}, found {a!r}")
            continue
        if not (_int(start) and _int(done) and 0 <= start <= done <= T):
            problems.append(f"{name}: started {start!r}, steps_done {done!r}: expected 0 <= started <= steps_done <= {T}")
            continue
        by_agent.setdefault(a, []).append((name, r))
    missed: dict[tuple[int, int, int], str] = {}
    dropped: dict[tuple[int, int, int], str] = {}
    stopped: dict[int, int] = {}
    rejoined: dict[int, tuple[tuple[int, int], ...]] = {}
    interrupted = False
    for a in range(n):
        runs = sorted(by_agent.get(a, []), key=lambda nr: int(nr[1].get("started", 0)))
        for (n1, r1), (n2, r2) in zip(runs, runs[1:]):
            if r1.get("started", 0) == r2.get("started", 0) or r2.get("started", 0) < r1.get("steps_done", 0):
                problems.append(f"agent {a}: {n1} and {n2} cover the same steps: give each of its processes' reports once")
        if not runs:
            if a in died:
                stopped[a] = died[a]
            else:
                problems.append(f"agent {a}: no report; give its report (teamkf agent --report), or --died {a}:STEPS if its process died without one")
            continue
        first = runs[0][1]
        segs = []
        if int(first.get("started", 0)) > 0:  # its first process died without a report
            prev: Any = died.get(a, first.get("previous_steps"))
            if not _int(prev):
                problems.append(
                    f"agent {a}: {runs[0][0]} rejoined at step {first['started']} and its first process left no report; "
                    f"give --died {a}:STEPS (the steps its --stream file holds)"
                )
                continue
            stopped[a] = int(prev)
        else:
            if int(first["steps_done"]) < T:
                stopped[a] = int(first["steps_done"])
            runs = runs[1:]
        for _, r in runs:
            if int(r["steps_done"]) > int(r["started"]):
                segs.append((int(r["started"]), int(r["steps_done"])))
        if segs:
            rejoined[a] = tuple(segs)
        for name, r in by_agent.get(a, []):
            interrupted |= r.get("error") == "interrupted"
            try:
                for j, s, why in r.get("missed", []):
                    missed.setdefault((a, int(j), int(s)), str(why))
                for b, s in r.get("dropped_out", []):
                    dropped.setdefault((int(b), a, int(s)), "dropped")
            except (TypeError, ValueError):
                problems.append(f"{name}: missed/dropped_out: expected [sender, step, reason] and [receiver, step] entries")
    for dkey, dwhy in dropped.items():
        missed.setdefault(dkey, dwhy)  # the receiver's own record wins; a receiver that died took its record with it
    tolerant = all(bool(r.get("tolerant", True)) for _, r in reports)
    done_by = [rejoined[a][-1][1] if a in rejoined else stopped.get(a, T) for a in range(n)]
    try:
        record = DropRecord.from_json(
            {
                "estimator": run0.get("estimator"),
                "agents": n,
                "steps": T,
                "run_id": run0.get("run_id", 0),
                "p_drop": run0.get("p_drop", 0.0),
                "seed": run0.get("seed"),
                "tolerant": tolerant,
                "stopped": {str(a): s for a, s in sorted(stopped.items())},
                "missed": [[*k, w] for k, w in sorted(missed.items())],
                "scenario": run0.get("scenario"),
                "fingerprint": run0.get("fingerprint"),
                "rejoined": {str(a): [list(g) for g in seg] for a, seg in sorted(rejoined.items())},
                "complete": not interrupted,
                "completed": None if not interrupted else min(done_by),
            },
            "merged record",
        )
    except ArgumentError as exc:
        return DropRecord("", 1, 1), problems + [str(exc)]
    return record, problems
