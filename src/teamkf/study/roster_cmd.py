"""``teamkf roster new``: write a roster and a fresh team key for agents on real machines.

::

    teamkf roster new --endpoints tcp/192.168.1.10:7447 tcp/192.168.1.11:7447 --out roster.toml

writes ``roster.toml`` (a random run id, the prefix, one [[agents]] entry per endpoint, in order,
and ``key_file``) and the key file next to it (``roster.key``: 64 hex digits, mode 0600). Copy
both to every machine over a channel you trust (scp); whoever holds the key can speak for any
agent of the team. With ``--tls-root-ca``, ``--tls-certificate`` and ``--tls-private-key`` the
roster gets a [tls] table (paths as given, relative to the roster's folder) and ``tls/`` endpoints
are accepted. Existing files are never overwritten.
"""

from __future__ import annotations

import os
import secrets
from pathlib import Path
from typing import Any, Callable

from ..exceptions import ArgumentError

__all__ = ["add_parser", "cmd_roster_new"]


def add_parser(add: Callable[..., Any]) -> None:
    """Add ``teamkf roster new`` (``add(name, help)`` returns a subparser)."""
    p = add("roster", "write a roster and a fresh team key for teamkf agent on real machines")
    sub = p.add_subparsers(dest="roster_command", metavar="new", required=True)
    n = add("new", "write ROSTER (TOML) and its key file (mode 0600); never overwrites", sub)  # with the options every command takes
    n.add_argument("--endpoints", nargs="+", required=True, metavar="ENDPOINT", help="agent 0's endpoint, agent 1's, ... (e.g. tcp/10.0.0.1:7447)")
    n.add_argument("--out", required=True, metavar="ROSTER", help="the roster to write (.toml); the key goes to ROSTER with the suffix .key")
    n.add_argument("--key-out", metavar="FILE", help="where to write the key (default: ROSTER with the suffix .key, next to it)")
    n.add_argument("--prefix", default="teamkf/agents", metavar="KEY", help="the Zenoh key prefix (default teamkf/agents)")
    n.add_argument("--run-id", type=int, metavar="N", help="the run id (default: random; give every run its own)")
    n.add_argument("--tls-root-ca", metavar="PEM", help="[tls] root_ca: the CA that signed every agent's certificate")
    n.add_argument("--tls-certificate", metavar="PEM", help="[tls] certificate: the machine's certificate")
    n.add_argument("--tls-private-key", metavar="PEM", help="[tls] private_key: its private key (mode 0600)")
    n.add_argument("--no-mutual", action="store_true", help="[tls] mutual = false: only the listening side shows a certificate")
    n.set_defaults(func=cmd_roster_new)


def cmd_roster_new(args: Any) -> int:
    """Write the roster and its key; every problem is one line before anything is written."""
    from ..deploy.roster import Roster, write_key
    from .outputs import check_output

    out = check_output(args.out, "--out", fmt=(".toml",))
    key_path = Path(args.key_out) if args.key_out else out.with_suffix(".key")
    check_output(str(key_path), "--key-out")
    for p, flag in ((out, "--out"), (key_path, "--key-out")):
        if p.exists():
            raise ArgumentError(f"{flag}: {p} exists; teamkf roster new never overwrites a roster or a key: choose another path", argument=flag)
    if os.path.abspath(out) == os.path.abspath(key_path):
        raise ArgumentError("--key-out: the key file must not be the roster", argument="--key-out")
    tls_given = [args.tls_root_ca, args.tls_certificate, args.tls_private_key]
    if any(tls_given) and not all(tls_given):
        raise ArgumentError("--tls-root-ca: give all of --tls-root-ca, --tls-certificate and --tls-private-key, or none", argument="--tls-root-ca")
    run_id = secrets.randbits(63) if args.run_id is None else args.run_id
    rel_key = os.path.relpath(key_path.resolve(), out.resolve().parent)
    d: dict[str, Any] = {
        "run_id": run_id,
        "prefix": args.prefix,
        "agents": [{"id": i, "endpoint": e} for i, e in enumerate(args.endpoints)],
    }
    if all(tls_given):
        d["tls"] = {
            "root_ca": args.tls_root_ca,
            "certificate": args.tls_certificate,
            "private_key": args.tls_private_key,
            "mutual": not args.no_mutual,
        }
    try:  # every check a read roster gets, before writing
        roster = Roster.from_dict(d, "--endpoints", base=out.resolve().parent)
    except ArgumentError as exc:
        what = exc.detail.removeprefix("--endpoints: ")
        flag = "--endpoints" if what.startswith("agents") else "--tls-root-ca" if what.startswith("tls") else "--prefix"
        raise ArgumentError(f"{flag}: {what}", argument=flag) from None
    roster = Roster(roster.endpoints, roster.run_id, roster.prefix, roster.source, None, rel_key, roster.tls)
    key = secrets.token_bytes(32)
    write_key(key_path, key)
    try:
        fd = os.open(out, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(roster.to_toml())
    except BaseException:
        key_path.unlink(missing_ok=True)
        raise
    Roster.read(out)  # what an agent will read: the key is found and well-formed
    print(f"roster for {len(args.endpoints)} agents written to {out} (run id {run_id}); team key (mode 0600) written to {key_path}")
    print("copy both to every machine over a channel you trust; whoever holds the key can speak for any agent")
    return 0
