"""The team's drop record, and its in-process replay to the same bits.

Every deployed agent records the messages it missed (:mod:`teamkf.deploy.agent`);
the team's record is their union, with the senders' injected drops (a receiver
that was killed took its own record with it; the sender knows what it dropped) and
the agents that stopped early. What a killed agent missed for other reasons (a real
loss before it died) is lost with it, and a replay can then differ in what that
agent sent before it died. Replaying it
runs the same :class:`~teamkf.deploy.agent.AgentCore` of every agent in one process,
in lockstep: at step k agent i fuses every message due at k that is **not** in the
record (in in-neighbour order), exactly what it fused on the network, so the replay's
estimates equal the deployment's bit for bit. Every agent steps to the end (a failed
agent's later messages are in its receivers' records, so nobody fuses them); the
estimates of an agent that stopped (``stopped``: the steps whose estimates it wrote, what a
killed process had streamed) are NaN from there, as in the deployment's file. ``teamkf filter --drops DROPS`` runs it.

File (JSON, ``format = "teamkf-drops"``, version 1)::

    {"format": "teamkf-drops", "version": 1, "estimator": "mtmse", "agents": 6, "steps": 200,
     "run_id": 123, "p_drop": 0.2, "seed": 7, "tolerant": true,   # the agents ran their loss-tolerant step
     "stopped": {"3": 120},                       # agent -> steps it completed (a failed agent)
     "missed": [[receiver, sender, sent_step, "dropped"], ...]}
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from ..exceptions import ArgumentError, ShapeError
from .agent import AgentCore, AgentResult

__all__ = ["DropRecord", "replay"]

FORMAT, FORMAT_VERSION = "teamkf-drops", 1


@dataclass(frozen=True)
class DropRecord:
    """What every agent of a deployment missed (see the module docstring)."""

    estimator: str
    n_agents: int
    n_steps: int
    missed: tuple[tuple[int, int, int, str], ...] = ()
    stopped: dict[int, int] = field(default_factory=dict)
    tolerant: bool = True
    run_id: int = 0
    p_drop: float = 0.0
    seed: int | None = None

    @classmethod
    def from_results(cls, estimator: str, results: Sequence[AgentResult | None], n_steps: int, **info: Any) -> "DropRecord":
        missed: set[tuple[int, int, int, str]] = set()
        stopped = {}
        for i, r in enumerate(results):
            if r is None:
                stopped[i] = 0
                continue
            missed |= {(r.index, j, s, why) for (j, s, why) in r.missed}
            # the sender's injected drops too: a receiver that died took its own record with it
            missed |= {(b, r.index, s, "dropped") for (b, s) in r.dropped_out}
            if r.steps_done < n_steps:
                stopped[r.index] = r.steps_done
        return cls(estimator, len(results), n_steps, tuple(sorted(missed)), stopped, **info)

    def to_json(self) -> dict[str, Any]:
        return {
            "format": FORMAT,
            "version": FORMAT_VERSION,
            "estimator": self.estimator,
            "agents": self.n_agents,
            "steps": self.n_steps,
            "run_id": self.run_id,
            "p_drop": self.p_drop,
            "seed": self.seed,
            "tolerant": self.tolerant,
            "stopped": {str(a): s for a, s in sorted(self.stopped.items())},
            "missed": [list(m) for m in self.missed],
        }

    def write(self, path: str | Path) -> None:
        """Write the record as JSON, atomically (:func:`teamkf._files.write_atomic`); its folder must exist."""
        from .._files import write_atomic

        text = json.dumps(self.to_json(), indent=1) + "\n"
        write_atomic(path, lambda fh: fh.write(text), text=True)

    @classmethod
    def read(cls, path: str | Path) -> "DropRecord":
        p = Path(path)
        try:
            d = json.loads(p.read_text(encoding="utf-8"))
        except FileNotFoundError:
            raise ArgumentError(f"--drops: no such file {p}; write one with teamkf deploy --record", argument="--drops") from None
        except (UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise ArgumentError(f"--drops: {p} is not a JSON drop record ({exc})", argument="--drops") from None
        if not isinstance(d, dict) or d.get("format") != FORMAT:
            raise ArgumentError(f"--drops: {p}: expected a drop record (format {FORMAT!r}, written by teamkf deploy --record)", argument="--drops")
        if d.get("version") != FORMAT_VERSION:
            raise ArgumentError(f"--drops: {p}: expected version {FORMAT_VERSION}, found {d.get('version')!r}", argument="--drops")
        try:
            missed = tuple((int(a), int(b), int(s), str(r)) for a, b, s, r in d["missed"])
            return cls(
                str(d["estimator"]),
                int(d["agents"]),
                int(d["steps"]),
                missed,
                {int(a): int(s) for a, s in d.get("stopped", {}).items()},
                bool(d.get("tolerant", True)),
                int(d.get("run_id", 0)),
                float(d.get("p_drop", 0.0)),
                None if d.get("seed") is None else int(d["seed"]),
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise ArgumentError(f"--drops: {p}: malformed drop record ({type(exc).__name__}: {exc})", argument="--drops") from None


def replay(design: Any, ys: Sequence[np.ndarray], record: DropRecord, offsets: np.ndarray | None = None, *, graph: Any = None) -> np.ndarray:
    """Re-run a deployment in-process from its drop record.

    Parameters
    ----------
    design : the deployed design (its family and variant)
    ys : per agent (1, n_steps, d_y^i) measurements, as the agents consumed them (known means removed)
    record : the team's :class:`DropRecord`
    offsets : (n_steps, n d_z) known means added to the estimates, or None
    graph : the graph the agents talked over (a design delivered by an information structure)

    Returns
    -------
    z : (n_steps, n d_z), NaN for the steps an agent did not complete
    """
    n, T = design.n_agents, record.n_steps
    if record.n_agents != n:
        raise ShapeError(f"--drops: the record has {record.n_agents} agents, the scenario {n}; replay it on the deployed scenario")
    if ys[0].shape[1] < T:
        raise ShapeError(f"--drops: the record has {T} steps, the measurements {ys[0].shape[1]}; replay it on the deployed log")
    agents = design.graph_agents()
    cores = [AgentCore(design, i, tolerant=record.tolerant, agent=agents[i], graph=graph) for i in range(n)]
    for c in cores:
        c.init()
    lost = {(a, b, s) for (a, b, s, _) in record.missed}
    dz = int(design.cost.dz)
    out = np.full((T, n * dz), np.nan)
    sent: list[dict[int, Any]] = [{} for _ in range(n)]
    max_delay = max((d for (_, _, d) in cores[0].graph.edges), default=1)
    broken: set[int] = set()
    for k in range(T):
        payloads: dict[int, Any] = {}
        for i, c in enumerate(cores):
            if i in broken:
                continue
            got = {(j, s): sent[j][s] for (j, s) in c.expected(k) if (i, j, s) not in lost and s in sent[j]}
            try:
                z, payloads[i] = c.step(k, ys[i][:, k], got)
            except Exception:  # noqa: BLE001 - as the deployed agent: its error stops it (a node failure)
                broken.add(i)
                continue
            if k < record.stopped.get(i, T):  # a stopped agent's later estimates were never written
                zi = np.asarray(z, dtype=float)[0]
                out[k, i * dz : (i + 1) * dz] = zi if offsets is None else zi + offsets[k, i * dz : (i + 1) * dz]
        for i, p in payloads.items():
            sent[i][k] = p
            sent[i].pop(k - max_delay - 1, None)  # nobody needs it any more
    return out
