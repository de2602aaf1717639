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

Two optional entries secure it (paths relative to the roster's folder)::

    key_file = "team.key"            # the team key: 64 hex digits (32 bytes), mode 0600 or 0400

    [tls]                            # encrypted links: endpoints "tls/HOST:PORT"
    root_ca = "ca.pem"               # the CA that signed every agent's certificate
    certificate = "agent.pem"        # this machine's certificate (and chain), PEM
    private_key = "agent-key.pem"    # its private key, PEM (mode 0600 or 0400)
    mutual = true                    # mutual TLS: each side checks the other's certificate

Every frame is signed with HMAC-SHA256 under the team key (:mod:`~teamkf.deploy.codec`);
``teamkf agent`` refuses a roster without ``key_file`` unless told ``--insecure``.

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
import os
import socket
import stat
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

from ..exceptions import ArgumentError

__all__ = ["Roster", "TlsFiles", "free_ports", "parse_endpoint", "read_key", "write_key", "zenoh_reason", "ENDPOINT_PROTOCOLS"]

#: the Zenoh link protocols a roster may name, and the address each takes (``tls`` needs the roster's
#: [tls] table; QUIC is not configured)
ENDPOINT_PROTOCOLS = {"tcp": "HOST:PORT", "udp": "HOST:PORT", "ws": "HOST:PORT", "tls": "HOST:PORT", "unixsock-stream": "PATH"}
_EXAMPLE = '"tcp/127.0.0.1:7447"'


def parse_endpoint(endpoint: str, tls: bool = False) -> tuple[str, str, int | None]:
    """``(protocol, host or path, port or None)`` of a Zenoh endpoint ``"tcp/HOST:PORT"``; a ValueError says what is wrong.

    Zenoh's ``?metadata`` and ``#configuration`` tails are allowed and ignored here. An IPv6 host is
    written in brackets (``tcp/[::1]:7447``). ``tls/HOST:PORT`` only with ``tls`` (a roster with a [tls] table).
    """
    proto, sep, rest = endpoint.partition("/")
    if not sep or not proto:
        raise ValueError(f"expected a Zenoh endpoint PROTOCOL/ADDRESS like {_EXAMPLE}, found {endpoint!r}")
    if proto == "quic":
        raise ValueError(f"quic is not configured by a roster; use tcp (e.g. {_EXAMPLE}) or tls with a [tls] table")
    if proto == "tls" and not tls:
        raise ValueError(
            f"tls needs TLS certificates: add a [tls] table (root_ca, certificate, private_key; docs/deploy.md), or use tcp (e.g. {_EXAMPLE})"
        )
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


_KEY_HINT = "64 hex digits (32 random bytes) on one line; teamkf roster new writes one"


def read_key(path: str | Path, where: str = "key_file") -> bytes:
    """The team key in ``path`` (hex text, at least 32 bytes), refused with one line when missing, malformed or readable by others."""
    p = Path(path)
    try:
        st = p.stat()
        raw = p.read_bytes() if stat.S_ISREG(st.st_mode) else None
    except FileNotFoundError:
        raise ArgumentError(f"{where}: no such key file {p}; write one with teamkf roster new, or run with --insecure", argument="--roster") from None
    except PermissionError:
        raise ArgumentError(f"{where}: cannot read the key file {p} (no permission)", argument="--roster") from None
    if raw is None:
        raise ArgumentError(f"{where}: {p} is not a regular file; expected the team key ({_KEY_HINT})", argument="--roster")
    if os.name == "posix" and st.st_mode & 0o077:
        raise ArgumentError(
            f"{where}: the key file {p} has mode {stat.S_IMODE(st.st_mode):04o}, readable by other users; expected 0600 or 0400 (chmod 600 {p})",
            argument="--roster",
        )
    text = raw.decode("ascii", "replace").strip()
    try:
        key = bytes.fromhex(text)
    except ValueError:
        key = b""
    if len(key) < 32:
        found = f"{len(key)} bytes" if key else f"{len(raw)} bytes that are not hex digits"
        raise ArgumentError(f"{where}: the key file {p}: expected {_KEY_HINT}, found {found}", argument="--roster")
    return key


def write_key(path: str | Path, key: bytes) -> None:
    """Write ``key`` as hex to a new file ``path`` with mode 0600 (refusing an existing file)."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "w", encoding="ascii") as fh:
        fh.write(key.hex() + "\n")


@dataclass(frozen=True)
class TlsFiles:
    """The roster's [tls] table: certificate paths (resolved against the roster's folder) and whether TLS is mutual."""

    root_ca: str
    certificate: str
    private_key: str
    mutual: bool = True
    #: as written in the roster (relative paths stay relative in :meth:`Roster.to_toml`)
    written: Mapping[str, str] = field(default_factory=dict, compare=False)

    def zenoh(self) -> dict[str, Any]:
        """The ``transport/link/tls`` section of a Zenoh configuration."""
        return {
            "root_ca_certificate": self.root_ca,
            "listen_certificate": self.certificate,
            "listen_private_key": self.private_key,
            "connect_certificate": self.certificate,
            "connect_private_key": self.private_key,
            "enable_mtls": bool(self.mutual),
        }


@dataclass(frozen=True)
class Roster:
    """Agents and their Zenoh endpoints, the team key and the TLS files (see the module docstring)."""

    endpoints: Mapping[int, str]
    run_id: int = 0
    prefix: str = "teamkf/agents"
    #: where it was read from ("--roster FILE"), for messages
    source: str = field(default="--roster", compare=False)
    #: the team key (HMAC-SHA256), read from ``key_file``; None: no key (``--insecure`` only)
    key: bytes | None = field(default=None, compare=False, repr=False)
    #: the key file as written in the roster (relative to its folder)
    key_file: str | None = None
    tls: TlsFiles | None = None

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
        lines = [f"run_id = {self.run_id}", f'prefix = "{self.prefix}"']
        if self.key_file is not None:
            lines.append(f"key_file = {json.dumps(self.key_file)}")
        lines.append("")
        if self.tls is not None:
            w = dict(self.tls.written) or {"root_ca": self.tls.root_ca, "certificate": self.tls.certificate, "private_key": self.tls.private_key}
            lines += ["[tls]", *(f"{k} = {json.dumps(w[k])}" for k in ("root_ca", "certificate", "private_key"))]
            lines += [f"mutual = {'true' if self.tls.mutual else 'false'}", ""]
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
        return cls.from_dict(d, f"{argument}: {p}", base=p.parent)

    @classmethod
    def from_dict(cls, d: Any, where: str = "--roster", base: str | Path | None = None) -> "Roster":
        """A roster from its parsed file (``where`` names the file in the messages); every entry is checked.

        ``key_file`` and the [tls] paths are relative to ``base`` (the roster's folder; default: the current one);
        the key is read and checked here.
        """
        folder = Path(base) if base is not None else Path(".")

        def bad(entry: str, what: str) -> ArgumentError:
            return ArgumentError(f"{where}: {entry}: {what}; fix the roster (docs/deploy.md)", argument="--roster")

        if not isinstance(d, dict):
            raise bad("top level", f"expected a table with run_id, prefix and [[agents]] entries, found {type(d).__name__}")
        unknown = sorted(set(d) - {"run_id", "prefix", "agents", "key_file", "tls"})
        if unknown:
            raise bad(unknown[0], "unknown key; expected run_id, prefix, key_file, [tls] and [[agents]] entries (id, endpoint)")
        tls = _tls(d.get("tls"), folder, bad)
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
                parse_endpoint(a["endpoint"], tls=tls is not None)
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
        key_file, key = d.get("key_file"), None
        if key_file is not None:
            if not isinstance(key_file, str) or not key_file.strip():
                raise bad("key_file", f"expected the path of the team key file (relative to the roster), found {key_file!r}")
            key = read_key(folder / key_file, f"{where}: key_file")
        return cls(eps, run_id, prefix, where, key, key_file, tls)

    def check_network(self, me: int | None = None) -> None:
        """Every agent's host resolves; agent ``me``'s endpoint can be listened on (an address of this machine, a free port).

        Raises
        ------
        ArgumentError
            One line naming the roster, the agent and its endpoint.
        """
        for a in self.agents:
            ep = self.endpoints[a]
            proto, host, port = parse_endpoint(ep, tls=self.tls is not None)
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


def _tls(t: Any, folder: Path, bad: Any) -> TlsFiles | None:
    """The [tls] table: every file exists, is readable and is PEM; the private key is not readable by others."""
    if t is None:
        return None
    if not isinstance(t, dict):
        raise bad("tls", f"expected a [tls] table with root_ca, certificate, private_key (and mutual), found {t!r}")
    extra = sorted(set(t) - {"root_ca", "certificate", "private_key", "mutual"})
    if extra:
        raise bad(f"tls.{extra[0]}", "unknown key; the [tls] table has root_ca, certificate, private_key and mutual")
    paths = {}
    for name in ("root_ca", "certificate", "private_key"):
        v = t.get(name)
        if not isinstance(v, str) or not v.strip():
            raise bad(f"tls.{name}", f"expected the path of a PEM file (relative to the roster), found {v!r}")
        p = folder / v
        if not p.is_file():
            raise bad(f"tls.{name}", f"no such file {p}")
        try:
            head = p.read_bytes()[:4096]
        except OSError as exc:
            raise bad(f"tls.{name}", f"cannot read {p} ({exc.strerror or exc})") from None
        if b"-----BEGIN" not in head:
            raise bad(f"tls.{name}", f"{p} is not a PEM file (no '-----BEGIN' line)")
        if name == "private_key" and os.name == "posix" and p.stat().st_mode & 0o077:
            raise bad(f"tls.{name}", f"{p} has mode {stat.S_IMODE(p.stat().st_mode):04o}, readable by other users; expected 0600 (chmod 600 {p})")
        paths[name] = str(p.resolve())
    mutual = t.get("mutual", True)
    if not isinstance(mutual, bool):
        raise bad("tls.mutual", f"expected true or false, found {mutual!r}")
    return TlsFiles(
        paths["root_ca"], paths["certificate"], paths["private_key"], mutual, {k: t[k] for k in ("root_ca", "certificate", "private_key")}
    )


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
