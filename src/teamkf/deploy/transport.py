"""Transports: how frames move between agents (Zenoh on a network, or queues inside one process).

A :class:`Transport` delivers opaque frames (bytes, :mod:`teamkf.deploy.codec`)
addressed to one agent. It knows nothing of steps, deadlines or payloads; the
agent loop (:mod:`teamkf.deploy.agent`) does. Two implementations prove the seam:

* :class:`ZenohTransport` (the default): one Zenoh peer per agent, listening
  on the agent's endpoint from the roster and connecting to the others' (explicit
  endpoints, no multicast scouting); agent i subscribes to the key ``<prefix>/<i>``
  and publishes a frame for agent b on ``<prefix>/<b>``, reliable, with congestion
  control "block" (a full queue delays, never drops). Any Zenoh application —
  a ROS 2 node on rmw_zenoh, or a DDS system through zenoh-bridge-ros2dds — can
  subscribe to ``<prefix>/*`` and decode the frames (docs/deploy.md).
* :class:`QueueTransport`: agents as threads of one process, one ``queue.Queue`` per
  agent, drained by a delivery thread (:class:`QueueHub` holds them).
"""

from __future__ import annotations

import abc
import queue
import threading
from typing import Any, Callable, Mapping

from .._validation import require
from ..exceptions import TeamkfError

__all__ = ["Transport", "TransportError", "ZenohTransport", "QueueHub", "QueueTransport", "zenoh_module"]


class TransportError(TeamkfError, ConnectionError):
    """The network refused an agent's session (Zenoh's error, on one line, naming the agent and its endpoint)."""


Handler = Callable[[bytes], None]


class Transport(abc.ABC):
    """Moves frames between the agents of one run (one instance per agent)."""

    @abc.abstractmethod
    def start(self, on_frame: Handler) -> None:
        """Begin delivering the frames addressed to this agent to ``on_frame`` (called from any thread)."""

    @abc.abstractmethod
    def send(self, receiver: int, data: bytes) -> None:
        """Send one frame to agent ``receiver`` (best effort: a lost frame becomes a missed message)."""

    @abc.abstractmethod
    def close(self) -> None:
        """Stop receiving and release the network resources (idempotent)."""


def zenoh_module() -> Any:
    """``import zenoh`` with the install command in the error when it is missing."""
    return require("zenoh", "deploy")


class ZenohTransport(Transport):
    """A Zenoh peer for agent ``me`` (see the module docstring).

    Parameters
    ----------
    me : agent id
    endpoints : mapping agent id -> Zenoh endpoint ("tcp/127.0.0.1:7447"); ``me``'s is listened on,
        the others' are connected to
    prefix : key-expression prefix of the run (``teamkf/agents`` by default)
    listen : listen on ``endpoints[me]`` (False for a pure client, e.g. a monitor)
    tls : the roster's [tls] files (:class:`~teamkf.deploy.roster.TlsFiles`): Zenoh's
        ``transport/link/tls`` configuration for ``tls/HOST:PORT`` endpoints (mutual TLS when
        ``tls.mutual``)
    """

    def __init__(self, me: int, endpoints: Mapping[int, str], *, prefix: str = "teamkf/agents", listen: bool = True, tls: Any = None):
        self.me, self.prefix = int(me), prefix.rstrip("/")
        self.endpoints = dict(endpoints)
        self._listen = listen
        self.tls = tls
        self._session: Any = None
        self._sub: Any = None
        self._pubs: dict[int, Any] = {}
        self._lock = threading.Lock()

    def _config(self, z: Any) -> Any:
        import json

        c = z.Config()
        c.insert_json5("mode", '"peer"')
        mine = self.endpoints.get(self.me)
        c.insert_json5("listen/endpoints", json.dumps([mine] if self._listen and mine else []))
        c.insert_json5("connect/endpoints", json.dumps([e for a, e in sorted(self.endpoints.items()) if a != self.me or not self._listen]))
        c.insert_json5("scouting/multicast/enabled", "false")
        if self.tls is not None:
            c.insert_json5("transport/link/tls", json.dumps(self.tls.zenoh()))
        return c

    def open(self) -> None:
        """Open the Zenoh session; a :class:`TransportError` names the agent and its endpoint when Zenoh refuses it."""
        if self._session is None:
            z = zenoh_module()
            self._z = z
            try:
                self._session = z.open(self._config(z))
            except Exception as exc:  # noqa: BLE001 - zenoh.ZError (or a config error): one line, never the Rust trace
                from .roster import zenoh_reason

                raise TransportError(
                    f"agent {self.me}: Zenoh could not open a session listening on {self.endpoints.get(self.me)!r} "
                    f"and connecting to the others ({zenoh_reason(exc)}); check the roster's endpoints"
                ) from None

    def start(self, on_frame: Handler) -> None:
        self.open()
        key = f"{self.prefix}/{self.me}"
        try:
            self._sub = self._session.declare_subscriber(key, lambda s: on_frame(bytes(s.payload.to_bytes())))
        except Exception as exc:  # noqa: BLE001 - zenoh.ZError: an invalid key expression
            from .roster import zenoh_reason

            self.close()
            raise TransportError(f"agent {self.me}: Zenoh refused the key {key!r} ({zenoh_reason(exc)}); check the roster's prefix") from None

    def send(self, receiver: int, data: bytes) -> None:
        self.open()
        with self._lock:
            pub = self._pubs.get(receiver)
            if pub is None:
                z = self._z
                pub = self._session.declare_publisher(
                    f"{self.prefix}/{receiver}", reliability=z.Reliability.RELIABLE, congestion_control=z.CongestionControl.BLOCK
                )
                self._pubs[receiver] = pub
        pub.put(data)

    def close(self) -> None:
        with self._lock:
            s, self._session = self._session, None
            self._pubs.clear()
        if s is not None:
            try:
                s.close()
            except Exception:  # pragma: no cover - closing a peer that the runtime already dropped
                pass


class QueueHub:
    """The shared medium of :class:`QueueTransport`: one queue per agent of one process."""

    def __init__(self, n_agents: int):
        self.queues: list[queue.Queue[bytes | None]] = [queue.Queue() for _ in range(n_agents)]

    def transport(self, me: int) -> "QueueTransport":
        return QueueTransport(self, me)


class QueueTransport(Transport):
    """Agent ``me``'s end of a :class:`QueueHub` (agents as threads of one process)."""

    def __init__(self, hub: QueueHub, me: int):
        self.hub, self.me = hub, int(me)
        self._thread: threading.Thread | None = None

    def start(self, on_frame: Handler) -> None:
        q = self.hub.queues[self.me]

        def drain() -> None:
            while True:
                data = q.get()
                if data is None:
                    return
                on_frame(data)

        self._thread = threading.Thread(target=drain, name=f"teamkf-queue-{self.me}", daemon=True)
        self._thread.start()

    def send(self, receiver: int, data: bytes) -> None:
        if 0 <= receiver < len(self.hub.queues):
            self.hub.queues[receiver].put(bytes(data))

    def close(self) -> None:
        if self._thread is not None:
            self.hub.queues[self.me].put(None)
            self._thread.join(timeout=5)
            self._thread = None
