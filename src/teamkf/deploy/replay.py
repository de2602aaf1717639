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
     "missed": [[receiver, sender, sent_step, "dropped"], ...],
     "scenario": "platoon-6", "fingerprint": "3f2a..."}   # the deployed scenario: its name, a hash of its tables

Every entry is checked when it is read (:meth:`DropRecord.read`: types, agents 0..n-1,
no self-edges, steps 0..T-1, reasons from :data:`REASONS`, ``stopped`` steps 0..T-1)
and against the scenario and log it is replayed on (:meth:`DropRecord.check`: the
scenario's name and fingerprint when the record has them, its agent count, the log's
steps (a record shorter or longer than the log is of another run), every miss on an
edge of the graph, due before the last step); each refusal is one line naming the
file and the entry (``missed[3].receiver``).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from ..exceptions import ArgumentError
from .agent import AgentCore, AgentResult

__all__ = ["DropRecord", "replay", "REASONS"]

FORMAT, FORMAT_VERSION = "teamkf-drops", 1

#: why a message was missed (:mod:`teamkf.deploy.agent`): the sender's injected loss, a silent or failed
#: sender, one that said goodbye, the step's hard deadline
REASONS = ("dropped", "silent", "failed", "left", "deadline")
_KEYS = ("format", "version", "estimator", "agents", "steps", "run_id", "p_drop", "seed", "tolerant", "stopped", "missed", "scenario", "fingerprint")
_FIX = "write it again with teamkf deploy --record, or replay the record on the scenario and log it was written for"


def _is_int(v: Any) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


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
    scenario: str | None = None  # the deployed scenario's name
    fingerprint: str | None = None  # a hash of its tables (teamkf.study.deploy.scenario_fingerprint)
    #: where it was read from ("--drops: FILE"), for messages
    source: str = field(default="--drops", compare=False)

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
            "scenario": self.scenario,
            "fingerprint": self.fingerprint,
        }

    def write(self, path: str | Path) -> None:
        """Write the record as JSON, atomically (:func:`teamkf._files.write_atomic`); its folder must exist."""
        from .._files import write_atomic

        text = json.dumps(self.to_json(), indent=1) + "\n"
        write_atomic(path, lambda fh: fh.write(text), text=True)

    @classmethod
    def read(cls, path: str | Path) -> "DropRecord":
        """Read a drop record and check every entry (see the module docstring); one :class:`ArgumentError` line names the entry."""
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
        return cls.from_json(d, f"--drops: {p}")

    @classmethod
    def from_json(cls, d: dict[str, Any], where: str = "--drops") -> "DropRecord":
        """A record from its parsed JSON, every entry checked (``where`` names the file in the messages)."""

        def bad(entry: str, expected: str, found: Any) -> ArgumentError:
            return ArgumentError(f"{where}: {entry}: expected {expected}, found {found!r}; {_FIX}", argument="--drops")

        for k in d:
            if k not in _KEYS:
                raise bad(k, f"no such entry (a drop record has {', '.join(_KEYS)})", k)
        for k in ("estimator", "agents", "steps", "missed"):
            if k not in d:
                raise ArgumentError(f"{where}: {k}: missing; {_FIX}", argument="--drops")
        est = d["estimator"]
        if not isinstance(est, str) or not est:
            raise bad("estimator", 'a family name (e.g. "mtmse")', est)
        n, T = d["agents"], d["steps"]
        if not _is_int(n) or n < 1:
            raise bad("agents", "the number of agents, an integer >= 1", n)
        if not _is_int(T) or T < 1:
            raise bad("steps", "the number of steps, an integer >= 1", T)
        run_id = d.get("run_id", 0)
        if not _is_int(run_id) or not 0 <= run_id < 2**64:
            raise bad("run_id", "an integer in 0..2**64-1", run_id)
        p_drop = d.get("p_drop", 0.0)
        if isinstance(p_drop, bool) or not isinstance(p_drop, (int, float)) or not 0.0 <= p_drop <= 1.0:
            raise bad("p_drop", "a probability in [0, 1]", p_drop)
        seed = d.get("seed")
        if seed is not None and (not _is_int(seed) or seed < 0):
            raise bad("seed", "null or an integer >= 0", seed)
        tolerant = d.get("tolerant", True)
        if not isinstance(tolerant, bool):
            raise bad("tolerant", "true or false", tolerant)
        for k in ("scenario", "fingerprint"):
            if d.get(k) is not None and not isinstance(d[k], str):
                raise bad(k, "null or a string", d[k])
        stopped_in = d.get("stopped", {})
        if not isinstance(stopped_in, dict):
            raise bad("stopped", 'a table agent -> steps it completed, e.g. {"3": 120}', stopped_in)
        stopped: dict[int, int] = {}
        for a, k in stopped_in.items():
            if not (isinstance(a, str) and a.isascii() and a.isdigit() and int(a) < n and str(int(a)) == a):
                raise bad(f"stopped[{a!r}]", f"an agent 0..{n - 1} as a key", a)
            if not _is_int(k) or not 0 <= k < T:
                raise bad(f"stopped[{a!r}]", f"the steps agent {a} completed, 0..{T - 1} (an agent that completed all {T} is not listed)", k)
            stopped[int(a)] = k
        missed_in = d["missed"]
        if not isinstance(missed_in, list):
            raise bad("missed", "a list of [receiver, sender, sent_step, reason]", missed_in)
        missed: list[tuple[int, int, int, str]] = []
        seen: dict[tuple[int, int, int], int] = {}
        for q, m in enumerate(missed_in):
            if not isinstance(m, list) or len(m) != 4:
                raise bad(f"missed[{q}]", "[receiver, sender, sent_step, reason]", m)
            i, j, s, why = m
            for name, v in (("receiver", i), ("sender", j)):
                if not _is_int(v) or not 0 <= v < n:
                    raise bad(f"missed[{q}].{name}", f"an agent 0..{n - 1}", v)
            if i == j:
                raise bad(f"missed[{q}].sender", f"an agent other than the receiver {i} (an agent sends itself nothing)", j)
            if not _is_int(s) or not 0 <= s < T:
                raise bad(f"missed[{q}].sent_step", f"a step 0..{T - 1}", s)
            if why not in REASONS:
                raise bad(f"missed[{q}].reason", f"one of {', '.join(REASONS)}", why)
            if (i, j, s) in seen:
                raise bad(f"missed[{q}]", f"each message once (it is missed[{seen[(i, j, s)]}] again)", m)
            seen[(i, j, s)] = q
            missed.append((i, j, s, why))
        return cls(est, n, T, tuple(missed), stopped, tolerant, run_id, float(p_drop), seed, d.get("scenario"), d.get("fingerprint"), where)

    def check(
        self,
        *,
        n_agents: int,
        n_steps: int,
        graph: Any = None,
        estimator: str | None = None,
        scenario: str | None = None,
        fingerprint: str | None = None,
    ) -> None:
        """Refuse, in one line naming the entry, a record of another scenario, estimator or log.

        Parameters
        ----------
        n_agents : the scenario's agents
        n_steps : the log's steps (the record must have as many)
        graph : the graph the agents talked over: every miss must be on one of its edges, due before the last step
        estimator, scenario, fingerprint : the deployment's family, scenario name and fingerprint (checked where the record has them)
        """
        w = self.source

        def bad(entry: str, what: str) -> ArgumentError:
            return ArgumentError(f"{w}: {entry}: {what}", argument="--drops")

        if scenario is not None and self.scenario is not None and self.scenario != scenario:
            raise bad("scenario", f"the record is of scenario {self.scenario!r}, not {scenario!r}; replay it on the scenario it was written for")
        if fingerprint is not None and self.fingerprint is not None and self.fingerprint != fingerprint:
            raise bad(
                "fingerprint",
                f"the record was written for another version of scenario {self.scenario or scenario!r} or another estimator than "
                f"{self.estimator!r} (fingerprint {self.fingerprint} in the record, {fingerprint} now); replay it on the scenario file it was deployed with",
            )
        if estimator is not None and self.estimator != estimator:
            raise bad("estimator", f"the record is of {self.estimator!r}, not {estimator!r}")
        if self.n_agents != n_agents:
            raise bad("agents", f"the record has {self.n_agents} agents, the scenario {n_agents}; replay it on the deployed scenario")
        if self.n_steps != n_steps:
            raise bad(
                "steps",
                f"the record has {self.n_steps} steps, the measurements {n_steps}; replay it on the deployed log (a record "
                f"{'shorter' if self.n_steps < n_steps else 'longer'} than the log is of another run)",
            )
        if graph is None:
            return
        for q, (i, j, s, _) in enumerate(self.missed):
            if j not in graph.in_neighbors(i):
                raise bad(
                    f"missed[{q}]",
                    f"agent {j} -> agent {i} is not an edge of the scenario's graph (agent {i} hears {sorted(graph.in_neighbors(i))}); "
                    "the record is of another graph",
                )
            due = s + graph.delay(j, i)
            if due >= n_steps:
                raise bad(
                    f"missed[{q}].sent_step",
                    f"agent {j}'s message sent at step {s} is due at step {due}, after the last step {n_steps - 1}; nothing was sent then",
                )


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
    agents = design.graph_agents()
    cores = [AgentCore(design, i, tolerant=record.tolerant, agent=agents[i], graph=graph) for i in range(n)]
    record.check(n_agents=n, n_steps=int(ys[0].shape[1]), graph=cores[0].graph)
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
