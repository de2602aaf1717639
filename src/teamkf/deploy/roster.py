"""The roster: which agents take part in a run, and where each one listens.

A small TOML (or JSON) file, the same on every machine::

    run_id = 4711                    # every frame carries it; frames of other runs are refused
    prefix = "teamkf/agents"         # Zenoh key prefix: agent i listens on "<prefix>/<i>"

    [[agents]]
    id = 0
    endpoint = "tcp/192.168.1.10:7447"

    [[agents]]
    id = 1
    endpoint = "tcp/192.168.1.11:7447"

Agent i listens on its own endpoint and connects to the others' (no multicast
discovery needed, so it works across subnets and in containers).

Every entry is checked when the file is read (:meth:`Roster.from_dict`: the keys, the
ids, the endpoints' protocol (``tcp``, ``udp``, ``ws`` with ``HOST:PORT``, port
1..65535, or ``unixsock-stream`` with a path), the prefix as a Zenoh key expression),
and before an agent opens its session (:meth:`Roster.check_network`: every host
resolves, and the agent's own endpoint can be listened on: an address of this
machine, a port not in use), so a mistake is one line naming the file, the agent and
its endpoint, never an error of the Zenoh runtime.
"""

from __future__ import annotations

import errno
import json
import socket
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

from ..exceptions import ArgumentError

__all__ = ["Roster", "free_ports", "parse_endpoint", "zenoh_reason", "ENDPOINT_PROTOCOLS"]

#: the Zenoh link protocols a roster may name, and the address each takes (TLS and QUIC need
#: certificates, which a roster does not configure)
ENDPOINT_PROTOCOLS = {"tcp": "HOST:PORT", "udp": "HOST:PORT", "ws": "HOST:PORT", "unixsock-stream": "PATH"}
_EXAMPLE = '"tcp/127.0.0.1:7447"'


def parse_endpoint(endpoint: str) -> tuple[str, str, int | None]:
    """``(protocol, host or path, port or None)`` of a Zenoh endpoint ``"tcp/HOST:PORT"``; a ValueError says what is wrong.

    Zenoh's ``?metadata`` and ``#configuration`` tails are allowed and ignored here. An IPv6 host is
    written in brackets (``tcp/[::1]:7447``).
    """
    proto, sep, rest = endpoint.partition("/")
    if not sep or not proto:
        raise ValueError(f"expected a Zenoh endpoint PROTOCOL/ADDRESS like {_EXAMPLE}, found {endpoint!r}")
    if proto in ("tls", "quic"):
        raise ValueError(f"{proto} needs TLS certificates, which a roster does not configure; use tcp (e.g. {_EXAMPLE})")
    if proto not in ENDPOINT_PROTOCOLS:
        raise ValueError(f"expected a protocol {', '.join(ENDPOINT_PROTOCOLS)} (e.g. {_EXAMPLE}), found {proto!r} in {endpoint!r}")
    addr = rest.split("#", 1)[0].split("?", 1)[0]
    if ENDPOINT_PROTOCOLS[proto] == "PATH":
        if not addr.strip():
            raise ValueError(f"expected {proto}/PATH (a socket file), found {endpoint!r}")
        return proto, addr, None
    host, colon, port = addr.rpartition(":")
    if not colon or not host:
        raise ValueError(f"expected {proto}/HOST:PORT (e.g. {_EXAMPLE}), found {endpoint!r}")
    if host.startswith("["):
        if not host.endswith("]") or len(host) < 3:
            raise ValueError(f"expected an IPv6 host in brackets, e.g. tcp/[::1]:7447, found {endpoint!r}")
        host = host[1:-1]
    elif ":" in host:
        raise ValueError(f"write an IPv6 host in brackets (tcp/[{host}]:{port}), found {endpoint!r}")
    if any(c.isspace() or not c.isprintable() for c in host) or any(c in host for c in "/[]"):
        raise ValueError(f"expected a host name or an IP address, found {host!r} in {endpoint!r}")
    if not port.isascii() or not port.isdigit() or not 1 <= int(port) <= 65535:
        raise ValueError(f"expected a port 1..65535, found {port!r} in {endpoint!r}")
    return proto, host, int(port)


def _check_prefix(prefix: Any) -> str | None:
    """What is wrong with a Zenoh key prefix, or None (a trailing '/' is dropped, as the transport does)."""
    if not isinstance(prefix, str):
        return f"expected a string, found {type(prefix).__name__}"
    p = prefix.rstrip("/")
    if not p:
        return "expected a non-empty key prefix"
    if p.startswith("/") or "//" in p:
        return "expected chunks separated by single '/', no leading '/'"
    bad = [c for c in p if c in "*$?#" or c.isspace() or not c.isprintable()]
    if bad:
        return f"expected no wildcards (* $), no ? or #, no spaces or control characters (here {bad[0]!r})"
    return None


@dataclass(frozen=True)
class Roster:
    """Agents and their Zenoh endpoints (see the module docstring)."""

    endpoints: Mapping[int, str]
    run_id: int = 0
    prefix: str = "teamkf/agents"
    #: where it was read from ("--roster FILE"), for messages
    source: str = field(default="--roster", compare=False)

    @property
    def agents(self) -> list[int]:
        return sorted(self.endpoints)

    def check(self, n_agents: int, argument: str = "--roster") -> None:
        """Every agent 0..n-1 of the scenario, and no other, has an endpoint."""
        want = list(range(n_agents))
        if self.agents != want:
            raise ArgumentError(
                f"{self.source if self.source != '--roster' else argument}: expected one [[agents]] entry for each agent 0..{n_agents - 1} "
                f"of the scenario, found ids {self.agents}; list every agent of the scenario once",
                argument=argument,
            )

    def to_toml(self) -> str:
        lines = [f"run_id = {self.run_id}", f'prefix = "{self.prefix}"', ""]
        for a in self.agents:
            lines += ["[[agents]]", f"id = {a}", f'endpoint = "{self.endpoints[a]}"', ""]
        return "\n".join(lines)

    def write(self, path: str | Path) -> None:
        """Write the roster as TOML, atomically (:func:`teamkf._files.write_atomic`); its folder must exist."""
        from .._files import write_atomic

        text = self.to_toml()
        write_atomic(path, lambda fh: fh.write(text), text=True)

    @classmethod
    def read(cls, path: str | Path, argument: str = "--roster") -> "Roster":
        p = Path(path)
        try:
            text = p.read_text(encoding="utf-8")
        except FileNotFoundError:
            raise ArgumentError(
                f"{argument}: no such file {p}; write a roster (docs/deploy.md) or let teamkf deploy write one", argument=argument
            ) from None
        except UnicodeDecodeError as exc:
            raise ArgumentError(
                f"{argument}: {p}: expected a UTF-8 TOML or JSON text file, found undecodable bytes at position {exc.start}", argument=argument
            ) from None
        try:
            if p.suffix.lower() == ".json":
                d = json.loads(text)
            else:
                import tomllib

                d = tomllib.loads(text)
        except ValueError as exc:
            raise ArgumentError(
                f"{argument}: {p} is not valid {'JSON' if p.suffix.lower() == '.json' else 'TOML'} ({exc})", argument=argument
            ) from None
        return cls.from_dict(d, f"{argument}: {p}")

    @classmethod
    def from_dict(cls, d: Any, where: str = "--roster") -> "Roster":
        """A roster from its parsed file (``where`` names the file in the messages); every entry is checked."""

        def bad(entry: str, what: str) -> ArgumentError:
            return ArgumentError(f"{where}: {entry}: {what}; fix the roster (docs/deploy.md)", argument="--roster")

        if not isinstance(d, dict):
            raise bad("top level", f"expected a table with run_id, prefix and [[agents]] entries, found {type(d).__name__}")
        unknown = sorted(set(d) - {"run_id", "prefix", "agents"})
        if unknown:
            raise bad(unknown[0], "unknown key; expected run_id, prefix and [[agents]] entries (id, endpoint)")
        if not isinstance(d.get("agents"), list) or not d["agents"]:
            raise bad("agents", f"expected [[agents]] entries with id and endpoint, found {d.get('agents')!r}")
        eps: dict[int, str] = {}
        seen: dict[str, int] = {}
        for q, a in enumerate(d["agents"]):
            if not isinstance(a, dict) or isinstance(a.get("id"), bool) or not isinstance(a.get("id"), int) or not isinstance(a.get("endpoint"), str):
                raise bad(f"agents[{q}]", f"expected id = <integer> and endpoint = {_EXAMPLE}, found {a!r}")
            extra = sorted(set(a) - {"id", "endpoint"})
            if extra:
                raise bad(f"agents[{q}].{extra[0]}", "unknown key; an [[agents]] entry has id and endpoint")
            if a["id"] < 0:
                raise bad(f"agents[{q}].id", f"expected an agent id >= 0, found {a['id']}")
            if a["id"] in eps:
                raise bad(f"agents[{q}]", f"agent {a['id']} is listed twice")
            try:
                parse_endpoint(a["endpoint"])
            except ValueError as exc:
                raise bad(f"agents[{q}].endpoint", str(exc)) from None
            key = a["endpoint"].split("#", 1)[0].split("?", 1)[0]
            if key in seen:
                raise bad(f"agents[{q}].endpoint", f"{a['endpoint']!r} is also agent {seen[key]}'s endpoint; give every agent its own port")
            seen[key] = a["id"]
            eps[a["id"]] = a["endpoint"]
        run_id = d.get("run_id", 0)
        if isinstance(run_id, bool) or not isinstance(run_id, int) or not 0 <= run_id < 2**64:
            raise bad("run_id", f"expected an integer in 0..2**64-1, found {run_id!r}")
        prefix = d.get("prefix", "teamkf/agents")
        why = _check_prefix(prefix)
        if why is not None:
            raise bad("prefix", f'{why} (a Zenoh key prefix like "teamkf/agents"), found {prefix!r}')
        return cls(eps, run_id, prefix, where)

    def check_network(self, me: int | None = None) -> None:
        """Every agent's host resolves; agent ``me``'s endpoint can be listened on (an address of this machine, a free port).

        Raises
        ------
        ArgumentError
            One line naming the roster, the agent and its endpoint.
        """
        for a in self.agents:
            ep = self.endpoints[a]
            proto, host, port = parse_endpoint(ep)
            if port is None:
                if a == me and Path(host).exists():
                    self._refuse(a, f"the socket file {host} exists (another agent listens there?); remove it or pick another path")
                continue
            kind = socket.SOCK_DGRAM if proto == "udp" else socket.SOCK_STREAM
            try:
                infos = socket.getaddrinfo(host, port, type=kind)
            except (socket.gaierror, UnicodeError) as exc:
                self._refuse(
                    a,
                    f"the host {host!r} cannot be resolved ({getattr(exc, 'strerror', None) or exc}); give an IP address or a name this machine resolves",
                )
            if a != me:
                continue
            family, _, _, _, addr = infos[0]
            s = socket.socket(family, kind)
            try:
                if kind == socket.SOCK_STREAM:
                    s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as Zenoh's listener: a closed connection's TIME_WAIT is no conflict
                s.bind(addr)
            except OSError as exc:
                if exc.errno == errno.EADDRINUSE:
                    why = f"port {port} is in use on {host} (another agent or program listens there); stop it or give agent {a} a free port"
                elif exc.errno == errno.EADDRNOTAVAIL:
                    why = (
                        f"{host} is not an address of this machine, so agent {a} cannot listen there; run agent {a} on the machine with that address"
                    )
                elif exc.errno == errno.EACCES:
                    why = f"listening on port {port} needs privileges here; pick a port >= 1024"
                else:
                    why = f"agent {a} cannot listen there ({exc.strerror or exc})"
                self._refuse(a, why)
            finally:
                s.close()
        try:  # Zenoh's own verdict on the key expressions, when it is installed (the prefix rules above are its rules)
            import zenoh
        except ImportError:
            return
        try:
            zenoh.KeyExpr(f"{self.prefix.rstrip('/')}/{self.agents[0]}")
        except Exception as exc:  # noqa: BLE001 - zenoh.ZError: its message, one line
            raise ArgumentError(
                f"{self.source}: prefix: Zenoh refuses {self.prefix!r} ({zenoh_reason(exc)}); fix the roster", argument="--roster"
            ) from None

    def _refuse(self, agent: int, why: str) -> None:
        raise ArgumentError(f"{self.source}: agent {agent}'s endpoint {self.endpoints[agent]!r}: {why}", argument="--roster")


def zenoh_reason(exc: BaseException) -> str:
    """A Zenoh error's message on one line, without the Rust source locations (``at /root/.cargo/...rs:62``)."""
    import re

    text = re.sub(r"\s*at \S+\.rs:\d+\.?", "", " ".join(str(exc).split()))
    return text.strip(" .[") or type(exc).__name__


def free_ports(n: int, host: str = "127.0.0.1") -> list[int]:
    """``n`` TCP ports that are free on ``host`` now (the OS picks them)."""
    socks, ports = [], []
    try:
        for _ in range(n):
            s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            s.bind((host, 0))
            socks.append(s)
            ports.append(int(s.getsockname()[1]))
    finally:
        for s in socks:
            s.close()
    return ports
