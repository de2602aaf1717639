"""One agent on a real network: the step barrier, the deadline, the drop record.

Agent i runs the same online agent the in-process runtime runs
(``design.graph_agents()[i]``, :func:`teamkf.estimators.base.pass_messages`).
At step k it

1. waits until every message due at k has arrived — the payload in-neighbour j sent at
   s = k - τ_ji. Every agent sends a heartbeat to its out-neighbours every
   ``deadline / 4`` seconds, so a neighbour that is waiting on its own neighbours is
   known to be alive and is waited for; a neighbour *silent* for ``deadline`` seconds
   (killed, stopped, cut off) is *failed* and is not waited for again until one of its
   messages arrives in time. No step waits longer than ``n_agents x deadline`` (a
   live neighbour that never delivers: the step's hard deadline);
2. fuses what arrived **in in-neighbour order, then sent step** (the graph's order, as
   the in-process runtime), never in arrival order, with its own y_i(k);
3. sends its payload to every out-neighbour b (due at k + τ_ib), as raw little-endian
   arrays in a :mod:`~teamkf.deploy.codec` frame.

A message due at k that did not arrive is a *miss* (sender, sent step, reason:
``dropped`` by the sender's loss injection, ``silent`` sender, ``failed`` sender
(silent at an earlier step), ``left`` (it said goodbye), or ``deadline`` (the hard
deadline passed); a frame arriving after its step is counted ``late`` and never fused.
Agents run their family's loss-tolerant step (``tolerant``, the step the lossy
Monte Carlo runs, :mod:`teamkf.simulation.links`) from step 0: with every message
delivered it is the design's arithmetic in the design's order, so a run without
misses equals the in-process runtime bit for bit (the tests check it), and a miss
is handled as the family documents. A family without a tolerant step runs its
nominal step and stops with an error at its first miss (a node failure for the
others). The misses are the agent's drop record: :func:`teamkf.deploy.replay.replay`
re-runs the team in-process from the records to the same bits.
"""

from __future__ import annotations

import os
import signal
import threading
import time
from collections import Counter
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from ..estimators.base import checked_step, step_context
from ..exceptions import TeamkfError, UnsupportedOperationError
from .codec import BYE, DATA, DROPPED, HELLO, Frame, FrameError, decode_payload, encode_frame, open_frame
from .payload import CONTROL_LIMIT, HARD_LIMIT, frame_limit, learn_payloads
from .payload import set_tolerant as _set_tolerant
from .transport import Transport

__all__ = ["AgentCore", "AgentResult", "DeployError", "Mailbox", "REFUSED", "run_agent", "check_deployable", "drop_stream", "windows"]

#: appended to the seed's key for an agent's injected-loss draws
DROP_STREAM_KEY = 0xD23


class DeployError(TeamkfError, RuntimeError):
    """A deployment that cannot start or go on (neighbours that never joined, a refused design)."""


def check_deployable(design: Any, graph: Any = None) -> Any:
    """The graph the agents talk over; :class:`UnsupportedOperationError` for a design no network can run.

    A design with a graph of its own (KCF, CIKF, ...) talks over it. A design delivered by an
    information structure (MTMSE, MMSE) talks over ``graph`` (the scenario's), its agents relaying
    every measurement they learn first (:class:`~teamkf.estimators.base.MeasurementRelay`); the
    structure must be realizable on that graph (every y_j(s) reaches agent i by the time it is used).
    """
    if not design.realizable:
        why = (
            "it is the omniscient benchmark (every agent holds every y_j(k) at once)"
            if design.omniscient
            else f"its {design.label!r} variant is not realizable"
        )
        raise UnsupportedOperationError(design.estimator, "deployment on a network", f"{why}; deploy a realizable family or variant")
    own = design.delivery_graph
    if own is not None:
        return own
    if graph is None:
        raise UnsupportedOperationError(
            design.estimator, "deployment on a network", "its agents are delivered by an information structure; give the graph they talk over"
        )
    structure = getattr(design, "structure", None)
    if structure is not None:
        structure.validate_on(graph)
    return graph


def drop_stream(rng: int | None, index: int) -> np.random.Generator:
    """Agent ``index``'s injected-loss stream for the seed ``rng`` (None: 0): one uniform per out-edge and step.

    ``SeedSequence(rng, spawn_key=(DROP_STREAM_KEY, index))``: every agent draws its own stream from the
    team's seed alone, so the same seed drops the same messages on any machine.
    """
    return np.random.default_rng(np.random.SeedSequence(0 if rng is None else int(rng), spawn_key=(DROP_STREAM_KEY, int(index))))


def _is_step(v: Any) -> bool:
    return isinstance(v, int) and not isinstance(v, bool) and 0 <= v < 2**32


def restart_hook(core: "AgentCore") -> Callable[[int, int], Any] | None:
    """The family's ``restart_state(n_runs, k)`` (a fresh agent at step k from the design's prior), or None.

    Only a loss-tolerant agent can restart: its neighbours' messages before its restart are missing.
    """
    if not core.tolerant:
        return None
    for obj in (core.agent, getattr(core.agent, "inner", None)):
        hook = getattr(obj, "restart_state", None) if obj is not None else None
        if callable(hook):
            return hook  # type: ignore[no-any-return]
    return None


class AgentCore:
    """Agent i's arithmetic: the family's online agent behind the nominal inbox order.

    ``step(k, own, received)`` with ``received`` a mapping (sender, sent step) -> payload
    of the messages that arrived for step k; returns (z_i(k), payload).
    """

    def __init__(self, design: Any, index: int, *, tolerant: bool = True, agent: Any = None, graph: Any = None):
        self.graph = check_deployable(design, graph)
        self.index = int(index)
        self.agent = agent if agent is not None else design.graph_agents()[self.index]
        self.in_delays = [(j, self.graph.delay(j, self.index)) for j in self.graph.in_neighbors(self.index)]
        self.out_delays = sorted((b, self.graph.delay(self.index, b)) for b in self.graph.out_neighbors(self.index))
        #: True when the family's loss-tolerant step runs (see the module docstring)
        self.tolerant = _set_tolerant(self.agent) if tolerant else False
        self.state: Any = None
        self._dz, self._who = step_context(design)
        #: per in-neighbour: how far ahead its frames may be (:func:`windows`)
        self.windows = windows(self.graph, self.index)
        self._design = design
        self._specs: tuple[dict[int, Any], dict[int, int]] | None = None

    def payload_specs(self) -> tuple[dict[int, Any], dict[int, int]]:
        """Per in-neighbour: the structure of its payloads (:class:`~teamkf.deploy.payload.PayloadSpec`) and the largest data frame accepted.

        Learned once, offline, by stepping the team's design in-process (:func:`~teamkf.deploy.payload.learn_payloads`).
        """
        if self._specs is None:
            shipped = getattr(self._design, "info", {}).get("payload_specs")  # an agent rebuilt from its slice: learned by the team's design
            specs, sizes = shipped if shipped is not None else learn_payloads(self._design, self.graph)
            ins = [j for (j, _) in self.in_delays]
            self._specs = ({j: specs[j] for j in ins}, {j: frame_limit(sizes[j]) + 68 for j in ins})
        return self._specs

    def expected(self, k: int) -> list[tuple[int, int]]:
        """The (sender, sent step) due at step k, in in-neighbour order."""
        return [(j, k - d) for (j, d) in self.in_delays if k - d >= 0]

    def init(self) -> None:
        self.state = self.agent.init_state(1)

    def step(self, k: int, own: Any, received: dict[tuple[int, int], Any]) -> tuple[np.ndarray, Any]:
        due = self.expected(k)
        inbox = [(j, s, received[(j, s)]) for (j, s) in due if received.get((j, s)) is not None]
        self.state, z, payload = checked_step(self.agent, self.index, self.state, k, own, inbox, 1, self._dz, self._who)  # a plug-in's z: one line
        return z, payload


#: the counts of frames an agent refused, by reason (``teamkf deploy``'s "refused" column sums them)
REFUSED = (
    "oversize",
    "corrupt_short",
    "corrupt_magic",
    "corrupt_version",
    "corrupt_auth",
    "corrupt_unkeyed",
    "corrupt_checksum",
    "corrupt_payload",
    "bad_payload",
    "other_run",
    "misaddressed",
    "unknown_sender",
    "unknown_kind",
    "bad_step",
    "future",
    "replayed",
    "duplicate",
)
#: steps beyond the farthest an in-neighbour can legitimately be ahead that a frame may still be for
WINDOW_MARGIN = 4
#: the window for an in-neighbour that does not depend on this agent (no path from it): its lead is not bounded by the graph
UNBOUNDED_WINDOW = 64


def windows(graph: Any, i: int) -> dict[int, int]:
    """Per in-neighbour j of agent i: how many steps past i's last closed step a frame from j may be for.

    j cannot be ahead of i by more than the smallest total delay of a path i -> j (it waits for what i
    sent, relayed), so its frame for i is due at most ``dist(i, j) + τ_ji`` steps after i's last step;
    :data:`WINDOW_MARGIN` more absorbs the step i is in. Where no path i -> j exists (a graph that is
    not strongly connected), :data:`UNBOUNDED_WINDOW` plus the delay.
    """
    dist: Any = None
    try:
        dist = graph.geodesic_delays()
    except Exception:  # noqa: BLE001 - GraphError: not strongly connected
        dist = None
    out = {}
    for j in graph.in_neighbors(i):
        tau = int(graph.delay(j, i))
        d = UNBOUNDED_WINDOW if dist is None else int(dist[i, j])
        out[j] = d + tau + WINDOW_MARGIN
    return out


class Mailbox:
    """The frames that arrived for agent ``me``, checked and counted (thread-safe).

    A frame is refused and counted by reason — and changes nothing else — when it is larger than
    ``max_frame`` bytes (``oversize``), fails its tag under ``key`` (``corrupt_auth``; without a key
    the plain checksum, ``corrupt_checksum``), belongs to another run, another receiver or a sender
    that is not a peer or in-neighbour, is due more than ``windows[j]`` steps after the last closed
    step (``future``), is a hello whose heartbeat counter did not increase (``replayed``), a duplicate
    or late, or carries a payload that does not decode or does not match ``specs[j]``, the structure
    the sender's design sends (``bad_payload``). The checks run in that order; the payload is decoded
    only after the tag and the header passed.
    """

    def __init__(
        self,
        me: int,
        run_id: int,
        in_delays: Sequence[tuple[int, int]],
        peers: Sequence[int],
        *,
        key: bytes | None = None,
        specs: Mapping[int, Any] | None = None,
        limits: Mapping[int, int] | None = None,
        windows: Mapping[int, int] | None = None,
    ):
        self.me, self.run_id = me, run_id
        self.delay = dict(in_delays)
        self.peers = set(peers)
        self.key = key
        self.specs = dict(specs) if specs is not None else {}
        self.limits = dict(limits) if limits is not None else {}
        self.windows = dict(windows) if windows is not None else {j: d + UNBOUNDED_WINDOW + WINDOW_MARGIN for j, d in self.delay.items()}
        self.max_frame = max([CONTROL_LIMIT, *self.limits.values()]) if self.limits else HARD_LIMIT
        self.cond = threading.Condition()
        self.data: dict[tuple[int, int], Any] = {}
        self.notices: set[tuple[int, int]] = set()
        self.closed = -1
        self.heard: set[int] = set()
        self.acks: dict[int, set[int]] = {}
        self.beats: dict[int, int] = {}
        self.left: set[int] = set()
        self.failed: set[int] = set()
        self.last_seen: dict[int, float] = {}
        self.counts: Counter[str] = Counter()
        #: per peer: its next step as it last said (heartbeat ``step``, or a data frame's origin + 1), and the first it said
        self.peer_step: dict[int, int] = {}
        self.first_step: dict[int, int] = {}
        #: per peer that rejoined (its heartbeat's ``rejoin``): its first step since; what it sent before is not waited for
        self.resume: dict[int, int] = {}
        #: per in-neighbour (on this agent's rejoin): messages sent before this step never reached this process
        self.joined_at: dict[int, int] = {}
        self.quiet: set[int] = set()  # failed for their silence: a heartbeat brings them back
        self._awake = 0.0

    def tick(self, silence: float) -> None:
        """Call often (under ``cond``): a gap over silence / 2 since the last call is this process's own stall (SIGSTOP, a
        starved machine); every peer then gets a fresh ``silence`` from now, so the frames that waited meanwhile are read before
        anyone is declared silent."""
        now = time.monotonic()
        if self._awake and now - self._awake > silence / 2:
            for j in self.peers:
                self.last_seen[j] = max(self.last_seen.get(j, now), now)
            self.counts["own_stalls"] += 1
        self._awake = now

    def put(self, raw: bytes) -> None:
        if len(raw) > self.max_frame:  # before anything else: no work for a flood of large frames
            with self.cond:
                self.counts["oversize"] += 1
            return
        try:
            h = open_frame(raw, self.key)
        except FrameError as exc:
            with self.cond:
                self.counts[f"corrupt_{exc.reason}"] += 1
            return
        with self.cond:
            why = self._admit(h, len(raw))
            if why is not None:
                self.counts[why] += 1
                return
        try:  # decoded outside the lock: only frames that authenticated and are due reach here
            payload = decode_payload(h.body)
        except FrameError:
            payload, why = None, "bad_payload"
        else:
            why = self._check_payload(h, payload)
        with self.cond:
            if why is not None:
                self.counts[why] += 1
                return
            self._put(Frame(h.kind, h.run_id, h.sender, h.receiver, h.step, h.origin, payload, h.flags))
            self.cond.notify_all()

    def _admit(self, h: Any, size: int) -> str | None:
        """Why an authenticated frame is refused on its header alone (None: decode its payload)."""
        if h.run_id != self.run_id:
            return "other_run"
        if h.receiver != self.me:
            return "misaddressed"
        if h.kind in (HELLO, BYE):
            if h.sender not in self.peers:
                return "unknown_sender"
            if size > CONTROL_LIMIT:
                return "oversize"
            return None  # a hello's counter is checked in _put, beside its rejoin announcement (a restarted process counts from 1)
        if h.kind != DATA:
            return "unknown_kind"
        if h.sender not in self.delay:
            return "unknown_sender"
        if size > self.limits.get(h.sender, HARD_LIMIT):
            return "oversize"
        if h.step != h.origin + self.delay[h.sender]:
            return "bad_step"
        if h.step <= self.closed:
            return "late"
        if h.step > self.closed + self.windows.get(h.sender, 0):
            return "future"
        if (h.sender, h.origin) in self.data or (h.sender, h.origin) in self.notices:
            return "duplicate"
        return None

    def _check_payload(self, h: Any, payload: Any) -> str | None:
        if h.kind == HELLO:  # {"heard": [agents], "step": next step, "rejoin": step it rejoined at (a restarted process)}
            ok = isinstance(payload, dict) and set(payload) <= {"heard", "step", "rejoin"} and isinstance(payload.get("heard", []), list)
            ok = ok and all(isinstance(a, int) and not isinstance(a, bool) for a in payload.get("heard", []))
            ok = ok and all(_is_step(payload[k]) for k in ("step", "rejoin") if k in payload)
            return None if ok else "bad_payload"
        if h.kind == BYE:
            return None if payload is None else "bad_payload"
        if h.flags & DROPPED:
            return None if payload is None else "bad_payload"
        spec = self.specs.get(h.sender)
        if spec is None:
            return None
        return None if spec.why(payload) is None else "bad_payload"

    def _put(self, f: Frame) -> None:
        """Store an admitted frame (its tag, header and payload were checked); a race may still make it a duplicate or late."""
        c = self.counts
        if f.kind == HELLO:
            p = f.payload
            r: Any = p.get("rejoin")
            restarted = _is_step(r) and int(r) > self.resume.get(f.sender, -1)  # a restarted process counts its hellos from 1 again
            if f.origin <= self.beats.get(f.sender, 0) and not restarted:
                c["replayed"] += 1
                return
            if not restarted and f.sender in self.resume and r != self.resume[f.sender]:  # a hello of the process before the restart
                c["replayed"] += 1
                return
            self.beats[f.sender] = f.origin
            self.last_seen[f.sender] = time.monotonic()
            self.heard.add(f.sender)
            self.acks[f.sender] = {int(a) for a in p.get("heard", [])}
            self._progress(f.sender, p.get("step"))
            if restarted:  # fuse it again from its first on-time message
                self.resume[f.sender] = r
                self.failed.discard(f.sender)
                self.quiet.discard(f.sender)
                self.left.discard(f.sender)
                c["rejoins"] += 1
            elif f.sender in self.quiet:  # back after a silence (a stalled process resumed): wait for it again
                self.failed.discard(f.sender)
                self.quiet.discard(f.sender)
            return
        if f.kind == BYE:
            self.last_seen[f.sender] = time.monotonic()
            self.left.add(f.sender)
            return
        if f.step <= self.closed:
            c["late"] += 1
        elif (f.sender, f.origin) in self.data or (f.sender, f.origin) in self.notices:
            c["duplicate"] += 1
        else:
            self.last_seen[f.sender] = time.monotonic()
            self.failed.discard(f.sender)  # on time again: wait for it again
            self.quiet.discard(f.sender)
            self._progress(f.sender, f.origin + 1, f.origin)
            if f.flags & DROPPED:
                self.notices.add((f.sender, f.origin))
            else:
                self.data[(f.sender, f.origin)] = f.payload
                c["received"] += 1

    def _progress(self, j: int, step: Any, first: Any = None) -> None:
        if _is_step(step):
            self.peer_step[j] = max(self.peer_step.get(j, 0), step)
            self.first_step.setdefault(j, step if first is None else first)

    def waived(self, key: tuple[int, int]) -> str | None:
        """Why the message ``key`` (sender, sent step) is not waited for: it was sent before this agent (``rejoin``) or its
        sender (``failed``) restarted; None: wait for it."""
        j, s = key
        if s < self.joined_at.get(j, -1):
            return "rejoin"
        if s < self.resume.get(j, -1):
            return "failed"
        return None

    def collect(
        self, k: int, due: Sequence[tuple[int, int]], silence: float, hard: float, stop: threading.Event
    ) -> tuple[dict, list[tuple[int, int, str]]]:
        """Wait for the messages ``due`` at step k; a sender silent for ``silence`` s fails; never past ``hard`` (monotonic)."""
        silent: set[int] = set()
        with self.cond:
            while not stop.is_set():
                self.tick(silence)
                pending = [
                    key
                    for key in due
                    if key not in self.data
                    and key not in self.notices
                    and key[0] not in self.failed
                    and key[0] not in self.left
                    and self.waived(key) is None
                ]
                now = time.monotonic()
                if not pending or now >= hard:
                    break
                quiet = {j for (j, _) in pending if now - self.last_seen.get(j, now) > silence}
                if quiet:
                    silent |= quiet
                    self.failed |= quiet
                    self.quiet |= quiet
                    continue
                self.cond.wait(min(hard - now, silence / 8, 0.1))
            got, missed = {}, []
            for key in due:
                if key in self.data:
                    got[key] = self.data.pop(key)
                    continue
                j = key[0]
                if key in self.notices:
                    reason = "dropped"
                elif self.waived(key) is not None:
                    reason = str(self.waived(key))
                elif j in silent:
                    reason = "silent"
                elif j in self.left:
                    reason = "left"
                elif j in self.failed:
                    reason = "failed"
                else:
                    reason = "deadline"
                    self.failed.add(j)
                missed.append((j, key[1], reason))
            self.closed = k
            self.notices = {key for key in self.notices if key[1] + self.delay.get(key[0], 0) > k}
            for key in [key for key in self.data if key[1] + self.delay.get(key[0], 0) <= k]:
                self.data.pop(key)
            return got, missed


@dataclass
class AgentResult:
    """What one agent did: its estimates, its misses (the drop record) and its counts."""

    index: int
    n_steps: int
    estimates: np.ndarray
    steps_done: int = 0
    missed: list[tuple[int, int, str]] = field(default_factory=list)
    counts: dict[str, int] = field(default_factory=dict)
    failed_neighbours: list[int] = field(default_factory=list)
    tolerant: bool = False
    sent: int = 0
    dropped_sent: int = 0
    dropped_out: list[tuple[int, int]] = field(default_factory=list)  # (receiver, sent step) of the injected drops
    latency: list[float] = field(default_factory=list)
    cpu_s: float = 0.0
    error: str | None = None
    #: the first step this process ran (> 0 after ``rejoin``: steps 0..started-1 are not its own)
    started: int = 0

    def to_json(self) -> dict[str, Any]:
        lat = np.asarray(self.latency) if self.latency else np.zeros(0)
        return {
            "agent": self.index,
            "steps": self.n_steps,
            "steps_done": self.steps_done,
            "missed": [[j, s, r] for (j, s, r) in self.missed],
            "counts": dict(self.counts),
            "failed_neighbours": list(self.failed_neighbours),
            "tolerant": self.tolerant,
            "sent": self.sent,
            "dropped_sent": self.dropped_sent,
            "dropped_out": [[b, s] for (b, s) in self.dropped_out],
            "median_step_ms": float(np.median(lat) * 1e3) if lat.size else None,
            "p99_step_ms": float(np.quantile(lat, 0.99) * 1e3) if lat.size else None,
            "cpu_s": self.cpu_s,
            "error": self.error,
            "started": self.started,
        }


def run_agent(
    design: Any,
    index: int,
    transport: Transport,
    source: Callable[[int], Any],
    *,
    n_steps: int,
    run_id: int,
    peers: Sequence[int] | None = None,
    offsets: np.ndarray | None = None,
    deadline: float = 2.0,
    join_timeout: float = 30.0,
    p_drop: float = 0.0,
    rng: int | None = None,
    kill_at: int | None = None,
    hard_kill: bool = False,
    on_estimate: Callable[[int, np.ndarray], None] | None = None,
    stop: threading.Event | None = None,
    core: AgentCore | None = None,
    graph: Any = None,
    rejoin: bool = False,
    key: bytes | None = None,
) -> AgentResult:
    """Run agent ``index`` of ``design`` over ``transport`` for ``n_steps`` steps.

    Parameters
    ----------
    source : k -> y_i(k) of shape (1, d_y^i) (the run axis first, as the runtime), or None when
        there is no more data (the run ends at that step)
    offsets : (n_steps, d_z) known means added to the estimates (L(k) x̄(k), agent i's block), or None
    deadline : seconds of silence after which a neighbour is failed (heartbeats every deadline / 4); a
        step waits at most n_agents x deadline
    join_timeout : seconds it waits for its neighbours to join
    p_drop, rng : injected loss (``rng`` an integer seed, the CLI's ``--seed``): each message is dropped on the sending side with probability
        p_drop (independently per out-edge and step, :func:`drop_stream`), and a notice is sent instead
    kill_at : fault injection: the agent dies before step ``kill_at`` (``hard_kill``: SIGKILL to its own
        process; else it stops silently, as a crashed thread would)
    on_estimate : called with (k, ẑ_i(k)) after every step
    stop : set it to stop the agent (it says goodbye and returns)
    core : the agent's :class:`AgentCore` (default: built from ``design`` and ``graph``)
    graph : the graph the agents talk over, for a design delivered by an information structure
    rejoin : a restarted agent (its team runs): listen to the neighbours' heartbeats and data for the team's
        current step k0, start there from the design's prior (the family's ``restart_state``; refused with
        :class:`DeployError` for a family without one), announce ``rejoin = k0`` so that the out-neighbours
        wait for it again, and never wait for a message sent before it listened (missed as ``rejoin``)
    key : the team key (32 bytes): every frame is signed and checked with HMAC-SHA256 under it
        (:mod:`~teamkf.deploy.codec`); None runs unauthenticated (``--insecure``: anyone who reaches
        the network can steer the team)

    Returns
    -------
    AgentResult
    """
    core = core if core is not None else AgentCore(design, index, graph=graph)
    i = core.index
    n = design.n_agents
    peers = sorted(set(range(n) if peers is None else peers) - {i})
    stop = stop if stop is not None else threading.Event()
    specs, limits = core.payload_specs()
    box = Mailbox(i, run_id, core.in_delays, peers, key=key, specs=specs, limits=limits, windows=core.windows)
    res = AgentResult(i, n_steps, np.full((n_steps, int(design.cost.dz)), np.nan))
    draws = drop_stream(rng, i)
    outs = core.out_delays
    hello_period = [0.05]
    done = threading.Event()
    restart = restart_hook(core) if rejoin else None
    if rejoin and restart is None:
        raise DeployError(
            f"agent {i}: --rejoin: {design.estimator} defines no restart at a later step (its agents have no restart_state "
            f"{'' if core.tolerant else 'and no loss-tolerant step '}); restart the whole team instead"
        )
    progress = {"step": 0}  # the next step, told in every heartbeat (a rejoining neighbour starts from it)

    def send(kind: int, b: int, step: int, origin: int, payload: Any = None, flags: int = 0) -> None:
        data = encode_frame(Frame(kind, run_id, i, b, step, origin, payload, flags), key)  # a payload that cannot travel stops the agent
        try:
            transport.send(b, data)
        except Exception:  # noqa: BLE001 - a send that fails is a message lost, as on any network
            with box.cond:
                box.counts["send_errors"] += 1

    targets = [[] if rejoin else peers]  # a rejoining agent listens silently until it knows where the team is

    def heartbeat() -> None:
        beat = 0
        while not done.wait(hello_period[0]):
            with box.cond:
                heard = sorted(box.heard)
            beat += 1  # the receiver refuses a hello whose counter did not increase (a replayed one)
            for b in targets[0]:
                send(HELLO, b, 0, beat, {"heard": heard, **progress})
            with box.cond:
                box.tick(deadline)

    transport.start(box.put)
    beat = threading.Thread(target=heartbeat, name=f"teamkf-hello-{i}", daemon=True)
    beat.start()
    cpu0 = time.thread_time()
    try:
        k0 = 0
        if restart is not None:
            k0 = _listen(box, core, i, join_timeout, deadline, stop)
            if k0 >= n_steps:
                raise DeployError(f"agent {i}: --rejoin: the team is at step {k0}, past the last step {n_steps - 1}; nothing to rejoin")
            with box.cond:
                box.closed = k0 - 1
                box.data = {key: v for key, v in box.data.items() if key[1] + box.delay.get(key[0], 0) >= k0}
                box.notices = {key for key in box.notices if key[1] + box.delay.get(key[0], 0) >= k0}
                box.joined_at = {j: box.first_step.get(j, k0) for (j, _) in core.in_delays}
            progress["step"], progress["rejoin"] = k0, k0
            res.started = k0
            for b in peers:  # at once: the out-neighbours wait for it again from its first step
                send(HELLO, b, 0, 0, {"heard": sorted(box.heard), **progress})
        else:
            _join(box, core, i, join_timeout, stop)
        with box.cond:  # the neighbours were heard now: their silence counts from here
            t_join = time.monotonic()
            for j in peers:
                box.last_seen[j] = max(box.last_seen.get(j, t_join), t_join)
        targets[0] = sorted({b for (b, _) in outs} | {j for (j, _) in core.in_delays})  # heartbeats, and acks for late joiners
        hello_period[0] = min(deadline / 4, 0.5)
        if restart is not None:
            core.state = restart(1, k0)
        else:
            core.init()
        for k in range(k0, n_steps):
            if kill_at is not None and k == kill_at:
                if hard_kill:
                    os.kill(os.getpid(), signal.SIGKILL)
                res.error = f"killed by fault injection before step {k}"
                done.set()
                return res
            if stop.is_set():
                break
            own = source(k)
            if own is None or stop.is_set():
                break
            t0 = time.monotonic()
            got, missed = box.collect(k, core.expected(k), deadline, t0 + deadline * max(2, n), stop)
            if stop.is_set():
                break
            res.missed.extend(missed)
            z, payload = core.step(k, own, got)
            zi = np.asarray(z, dtype=float)[0]
            if offsets is not None:
                zi = zi + offsets[k]
            res.estimates[k] = zi
            res.steps_done = k + 1
            progress["step"] = k + 1
            if on_estimate is not None:
                on_estimate(k, zi)
            u = draws.random(len(outs))  # one draw per out-edge and step, whatever happens
            for q, (b, d) in enumerate(outs):
                if k + d >= n_steps or payload is None:
                    continue
                res.sent += 1
                if u[q] < p_drop:
                    res.dropped_sent += 1
                    res.dropped_out.append((b, k))
                    send(DATA, b, k + d, k, None, DROPPED)
                else:
                    send(DATA, b, k + d, k, payload)
            res.latency.append(time.monotonic() - t0)
        if stop.is_set():
            res.error = "interrupted"
    except Exception as exc:  # noqa: BLE001 - any failure of this agent is reported, and is a node failure for the others
        res.error = f"{type(exc).__name__}: {exc}"
    finally:
        res.cpu_s = time.thread_time() - cpu0
        done.set()
        if not (res.error or "").startswith("killed"):  # a crash says nothing; everything else says goodbye
            for b in peers:
                send(BYE, b, 0, 0)
        time.sleep(0.2)  # let the last frames leave before the Zenoh connection closes
        transport.close()
        with box.cond:
            res.counts = dict(box.counts)
            res.failed_neighbours = sorted({j for (j, _, r) in res.missed if r in ("silent", "deadline", "failed")})
        res.tolerant = core.tolerant
    return res


def _listen(box: Mailbox, core: AgentCore, i: int, timeout: float, deadline: float, stop: threading.Event) -> int:
    """A rejoining agent: the team's next step, from its neighbours' heartbeats and data (every neighbour heard, or
    ``deadline`` s after the first was, at most ``timeout`` s); one step later, so that its first messages are on time."""
    nbrs = {j for (j, _) in core.in_delays} | {b for (b, _) in core.out_delays}
    end = time.monotonic() + timeout
    first: float | None = None
    with box.cond:
        while not stop.is_set():
            now = time.monotonic()
            heard = {j for j in nbrs if j in box.peer_step}
            if heard and first is None:
                first = now
            if heard and (heard == nbrs or now - first >= deadline):  # type: ignore[operator]
                return max(box.peer_step[j] for j in heard) + 1
            if now >= end:
                raise DeployError(
                    f"agent {i}: --rejoin: no neighbour ({sorted(nbrs)}) was heard within {timeout:g} s: the team is not running "
                    "(start it without --rejoin), or check the roster's endpoints"
                )
            box.cond.wait(min(end - now, 0.05))
    raise DeployError(f"agent {i}: --rejoin: interrupted before the team's step was known")


def _join(box: Mailbox, core: AgentCore, i: int, timeout: float, stop: threading.Event) -> None:
    """Wait until every in-neighbour is heard and every out-neighbour has heard this agent."""
    ins = {j for (j, _) in core.in_delays}
    outs = {b for (b, _) in core.out_delays}
    end = time.monotonic() + timeout
    with box.cond:
        while not stop.is_set():
            missing_in = ins - box.heard
            missing_out = {b for b in outs if i not in box.acks.get(b, set())}
            if not missing_in and not missing_out:
                return
            left = end - time.monotonic()
            if left <= 0:
                raise DeployError(
                    f"agent {i}: neighbours {sorted(missing_in | missing_out)} did not join within {timeout:g} s; start them, or check the roster's endpoints"
                )
            box.cond.wait(min(left, 0.25))
