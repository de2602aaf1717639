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
"""

from __future__ import annotations

import json
import socket
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

from ..exceptions import ArgumentError

__all__ = ["Roster", "free_ports"]


@dataclass(frozen=True)
class Roster:
    """Agents and their Zenoh endpoints (see the module docstring)."""

    endpoints: Mapping[int, str]
    run_id: int = 0
    prefix: str = "teamkf/agents"

    @property
    def agents(self) -> list[int]:
        return sorted(self.endpoints)

    def check(self, n_agents: int, argument: str = "--roster") -> None:
        """Every agent 0..n-1 of the scenario, and no other, has an endpoint."""
        want = list(range(n_agents))
        if self.agents != want:
            raise ArgumentError(
                f"{argument}: expected one [[agents]] entry for each agent 0..{n_agents - 1} of the scenario, found ids {self.agents}",
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
        return cls.from_dict(d, f"{argument} {p}")

    @classmethod
    def from_dict(cls, d: Any, where: str = "roster") -> "Roster":
        if not isinstance(d, dict) or not isinstance(d.get("agents"), list) or not d["agents"]:
            raise ArgumentError(f"{where}: expected [[agents]] entries with id and endpoint", argument="--roster")
        eps: dict[int, str] = {}
        for q, a in enumerate(d["agents"]):
            if not isinstance(a, dict) or isinstance(a.get("id"), bool) or not isinstance(a.get("id"), int) or not isinstance(a.get("endpoint"), str):
                raise ArgumentError(f'{where}: agents[{q}]: expected id = <integer> and endpoint = "tcp/HOST:PORT", found {a!r}', argument="--roster")
            if a["id"] in eps:
                raise ArgumentError(f"{where}: agents[{q}]: agent {a['id']} is listed twice", argument="--roster")
            if "/" not in a["endpoint"]:
                raise ArgumentError(
                    f'{where}: agents[{q}].endpoint: expected a Zenoh endpoint like "tcp/127.0.0.1:7447", found {a["endpoint"]!r}',
                    argument="--roster",
                )
            eps[a["id"]] = a["endpoint"]
        run_id = d.get("run_id", 0)
        if isinstance(run_id, bool) or not isinstance(run_id, int) or not 0 <= run_id < 2**64:
            raise ArgumentError(f"{where}: run_id: expected an integer in 0..2**64-1, found {run_id!r}", argument="--roster")
        prefix = d.get("prefix", "teamkf/agents")
        if not isinstance(prefix, str) or not prefix or any(c in prefix for c in "*$?#"):
            raise ArgumentError(f"{where}: prefix: expected a Zenoh key prefix without wildcards, found {prefix!r}", argument="--roster")
        return cls(eps, run_id, prefix)


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
