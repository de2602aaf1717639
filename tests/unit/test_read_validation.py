"""Every file teamkf reads is validated (issue "Reliability, round 4", point 2).

One parametrized row per bad input the testers found: rosters and endpoints (``teamkf agent
--roster``), drop records (``teamkf filter --drops``), population scenarios given to the
deployment commands, ``--steps``/``--kill-at``/``--id`` below their range, measurement and truth
files of the wrong column types (Parquet categoricals and text, NPZ booleans). Each must give
exit status 2, exactly one stderr line ``teamkf: error: ...`` naming the file, the entry and what
was expected, no traceback, and leave every file as it was (no output written).

A corrupt cache part (the leaderboard's JSON parts, a sweep's Parquet parts) is recomputed with
one ``teamkf: warning:`` line and gives the same numbers as a clean run.
"""

from __future__ import annotations

import copy
import hashlib
import json
import os
import shutil
import socket
from pathlib import Path
from typing import Any, Callable

import numpy as np
import pytest

from teamkf.cli import main

pd = pytest.importorskip("pandas")
pytest.importorskip("pyarrow")

T = 6
SCENARIO = f"""name = "tiny"
horizon = {T}
estimators = ["mtmse"]
[system]
A = [[0.9, 0.1, 0.0], [0.0, 0.8, 0.1], [0.0, 0.0, 0.7]]
Q = 1.0
Sigma_x = 1.0
[[agents]]
C = [[1.0, 0.0, 0.0]]
R = 0.5
[[agents]]
C = [[0.0, 1.0, 0.0]]
R = 0.5
[[agents]]
C = [[0.0, 0.0, 1.0]]
R = 0.5
[graph]
kind = "line"
delay = 1
[cost]
kind = "average"
lambda = 1.0
"""
N = 3
#: two misses on edges of the line 0 - 1 - 2 (delay 1), due before the last step
GOOD_MISSES = [[1, 0, 0, "dropped"], [2, 1, 3, "silent"]]


@pytest.fixture(scope="module")
def base(tmp_path_factory) -> dict[str, Path]:
    """tiny.toml (3 agents, T = 6), other.toml (another scenario), tiny-v2.toml (the same name, another R),
    log.csv, truth.csv and drops.json (written by teamkf deploy --record, its misses replaced by GOOD_MISSES)."""
    d = tmp_path_factory.mktemp("reads")
    (d / "tiny.toml").write_text(SCENARIO)
    (d / "other.toml").write_text(SCENARIO.replace('name = "tiny"', 'name = "other"'))
    (d / "tiny-v2.toml").write_text(SCENARIO.replace("R = 0.5\n[graph]", "R = 0.7\n[graph]"))
    rng = np.random.default_rng(7)
    rows = [f"{t},{i},{rng.normal():.6f}" for t in range(T) for i in range(N)]
    (d / "log.csv").write_text("step,agent,y0\n" + "\n".join(rows) + "\n")
    (d / "truth.csv").write_text("step,x0,x1,x2\n" + "".join(f"{t},0.1,0.2,0.3\n" for t in range(T)))
    rc = main(
        ["--quiet", "deploy", str(d / "tiny.toml"), "--measurements", str(d / "log.csv"), "--out", str(d / "est.csv")]
        + ["--record", str(d / "drops.json"), "--transport", "queue"]
    )
    assert rc == 0
    rec = json.loads((d / "drops.json").read_text())
    assert rec["scenario"] == "tiny" and len(rec["fingerprint"]) == 16 and rec["agents"] == N and rec["steps"] == T
    rec["missed"] = GOOD_MISSES
    (d / "drops.json").write_text(json.dumps(rec))
    return {"dir": d, "scenario": d / "tiny.toml", "log": d / "log.csv", "truth": d / "truth.csv", "drops": d / "drops.json"}


def _snapshot(*folders: Path) -> dict[str, str]:
    return {str(p): hashlib.sha256(p.read_bytes()).hexdigest() for f in folders for p in sorted(f.rglob("*")) if p.is_file()}


# ---------------------------------------------------------------------------
# rows: (id, build(tmp, base) -> argv, words the one line must hold)
# ---------------------------------------------------------------------------
def _roster(
    endpoints: list[str], prefix: str = "teamkf/t", extra: str = "", key: tuple[str, int] | None = ("ab" * 32, 0o600)
) -> Callable[[Path, dict], list[str]]:
    """``teamkf agent`` (agent 0) with a roster of ``endpoints``; ``FREE`` is a free loopback port, ``BUSY`` one in use.

    ``key``: the key file's text and mode (``key_file = "team.key"``), or None for a roster without a key.
    """

    def build(tmp: Path, b: dict) -> list[str]:
        from teamkf.deploy import free_ports

        free = iter(free_ports(len(endpoints)))
        text = f'run_id = 1\nprefix = "{prefix}"\n'
        if key is not None:
            (tmp / "team.key").write_text(key[0])
            os.chmod(tmp / "team.key", key[1])
            text += 'key_file = "team.key"\n'
        text += extra
        for i, ep in enumerate(endpoints):
            ep = ep.replace("FREE", str(next(free))).replace("BUSY", str(b.get("busy")))
            text += f'\n[[agents]]\nid = {i}\nendpoint = "{ep}"\n'
        (tmp / "roster.toml").write_text(text)
        return ["agent", str(b["scenario"]), "--id", "0", "--roster", str(tmp / "roster.toml"), "--measurements", str(b["log"])] + [
            "--join-timeout",
            "1",
        ]

    return build


def _ep(a: str) -> list[str]:
    """Agent 0 at ``a``, the others on free loopback ports."""
    return [a, "tcp/127.0.0.1:FREE", "tcp/127.0.0.1:FREE"]


OK = _ep("tcp/127.0.0.1:FREE")


ROSTER_ROWS: list[tuple[str, Callable[..., list[str]], list[str]]] = [
    ("port-99999", _roster(_ep("tcp/127.0.0.1:99999")), ["roster.toml", "agents[0].endpoint", "port 1..65535", "'99999'"]),
    ("port-0", _roster(_ep("tcp/127.0.0.1:0")), ["agents[0].endpoint", "port 1..65535"]),
    ("port-not-a-number", _roster(_ep("tcp/127.0.0.1:http")), ["agents[0].endpoint", "port 1..65535", "'http'"]),
    ("port-missing", _roster(_ep("tcp/127.0.0.1")), ["agents[0].endpoint", "tcp/HOST:PORT"]),
    ("protocol-unknown", _roster(_ep("foo/127.0.0.1:7000")), ["agents[0].endpoint", "protocol", "'foo'"]),
    ("protocol-tls", _roster(_ep("tls/127.0.0.1:7000")), ["agents[0].endpoint", "TLS certificates", "use tcp"]),
    ("protocol-none", _roster(_ep("127.0.0.1:7000")), ["agents[0].endpoint", "PROTOCOL/ADDRESS"]),
    ("ipv6-without-brackets", _roster(_ep("tcp/::1:7000")), ["agents[0].endpoint", "brackets"]),
    ("host-unassignable", _roster(_ep("tcp/192.0.2.1:7000")), ["roster.toml", "agent 0's endpoint", "192.0.2.1", "not an address of this machine"]),
    (
        "host-unresolvable",
        _roster(["tcp/127.0.0.1:FREE", "tcp/no-such-host.invalid:7000", "tcp/127.0.0.1:FREE"]),
        ["agent 1's endpoint", "'no-such-host.invalid'", "cannot be resolved"],
    ),
    ("endpoint-twice", _roster(["tcp/127.0.0.1:7447", "tcp/127.0.0.1:7447", "tcp/127.0.0.1:FREE"]), ["agents[1].endpoint", "agent 0's endpoint"]),
    ("prefix-leading-slash", _roster(OK, prefix="/teamkf"), ["roster.toml", "prefix", "'/teamkf'"]),
    ("prefix-empty-chunk", _roster(OK, prefix="teamkf//t"), ["prefix", "single '/'"]),
    ("prefix-wildcard", _roster(OK, prefix="teamkf/*"), ["prefix", "wildcards"]),
    ("prefix-dollar", _roster(OK, prefix="teamkf/$x"), ["prefix", "wildcards"]),
    ("prefix-space", _roster(OK, prefix="team kf"), ["prefix", "spaces"]),
    ("prefix-empty", _roster(OK, prefix="/"), ["prefix", "non-empty"]),
    ("roster-unknown-key", _roster(OK, extra="prefx = 1\n"), ["roster.toml", "prefx", "unknown key"]),
    ("port-in-use", _roster(_ep("tcp/127.0.0.1:BUSY")), ["roster.toml", "agent 0's endpoint", "is in use on 127.0.0.1"]),
    ("roster-without-key", _roster(OK, key=None), ["roster.toml", "no key_file", "teamkf roster new", "--insecure"]),
    ("key-readable-by-others", _roster(OK, key=("ab" * 32, 0o644)), ["roster.toml", "key_file", "team.key", "mode 0644", "chmod 600"]),
    ("key-too-short", _roster(OK, key=("abcd", 0o600)), ["roster.toml", "key_file", "64 hex digits", "found 2 bytes"]),
    ("key-not-hex", _roster(OK, key=("not a key at all", 0o600)), ["key_file", "not hex digits"]),
    ("key-file-missing", _roster(OK, extra='key_file = "gone.key"\n', key=None), ["roster.toml", "key_file", "no such key file", "gone.key"]),
    ("tls-endpoint-without-table", _roster(_ep("tls/127.0.0.1:FREE")), ["agents[0].endpoint", "[tls] table", "use tcp"]),
    (
        "tls-table-missing-file",
        _roster(OK, extra='[tls]\nroot_ca = "ca.pem"\ncertificate = "c.pem"\nprivate_key = "k.pem"\n'),
        ["tls.root_ca", "no such file"],
    ),
]


def _record(change: Callable[[dict], Any], scenario: str = "tiny.toml") -> Callable[[Path, dict], list[str]]:
    def build(tmp: Path, b: dict) -> list[str]:
        d = copy.deepcopy(json.loads(b["drops"].read_text()))
        change(d)
        (tmp / "drops.json").write_text(json.dumps(d))
        return [
            "filter",
            str(b["dir"] / scenario),
            "--measurements",
            str(b["log"]),
            "--drops",
            str(tmp / "drops.json"),
            "--out",
            str(tmp / "replay.csv"),
        ]

    return build


def _miss(entry: list[Any]) -> Callable[[dict], None]:
    return lambda d: d.__setitem__("missed", [*GOOD_MISSES, entry])


DROP_ROWS: list[tuple[str, Callable[..., list[str]], list[str]]] = [
    ("receiver-out-of-range", _record(_miss([7, 0, 0, "dropped"])), ["drops.json", "missed[2].receiver", "agent 0..2", "found 7"]),
    ("sender-negative", _record(_miss([1, -1, 0, "dropped"])), ["missed[2].sender", "agent 0..2", "found -1"]),
    ("self-edge", _record(_miss([1, 1, 0, "dropped"])), ["missed[2].sender", "other than the receiver"]),
    ("not-an-edge", _record(_miss([2, 0, 0, "dropped"])), ["missed[2]", "not an edge", "graph"]),
    ("step-negative", _record(_miss([1, 0, -1, "dropped"])), ["missed[2].sent_step", f"step 0..{T - 1}", "found -1"]),
    ("step-too-large", _record(_miss([1, 0, T, "dropped"])), ["missed[2].sent_step", f"step 0..{T - 1}", f"found {T}"]),
    ("step-due-after-the-end", _record(_miss([1, 0, T - 1, "dropped"])), ["missed[2].sent_step", f"due at step {T}", "after the last step"]),
    ("step-float", _record(_miss([1, 0, 1.0, "dropped"])), ["missed[2].sent_step", "found 1.0"]),
    ("reason-unknown", _record(_miss([1, 0, 1, "lost"])), ["missed[2].reason", "dropped, silent", "'lost'"]),
    ("entry-short", _record(_miss([1, 0])), ["missed[2]", "[receiver, sender, sent_step, reason]"]),
    ("entry-twice", _record(_miss(list(GOOD_MISSES[0]))), ["missed[2]", "missed[0] again"]),
    ("missed-not-a-list", _record(lambda d: d.__setitem__("missed", {"0": 1})), ["missed", "a list"]),
    ("tolerant-no", _record(lambda d: d.__setitem__("tolerant", "no")), ["drops.json", "tolerant", "true or false", "'no'"]),
    ("stopped-negative", _record(lambda d: d.__setitem__("stopped", {"0": -5})), ["stopped['0']", f"0..{T - 1}", "found -5"]),
    ("stopped-too-large", _record(lambda d: d.__setitem__("stopped", {"0": T})), ["stopped['0']", f"0..{T - 1}"]),
    ("stopped-unknown-agent", _record(lambda d: d.__setitem__("stopped", {"5": 1})), ["stopped['5']", "agent 0..2"]),
    ("stopped-not-a-table", _record(lambda d: d.__setitem__("stopped", [1])), ["stopped", "a table"]),
    (
        "steps-shorter-than-the-log",
        _record(lambda d: (d.__setitem__("steps", T - 2), d.__setitem__("completed", T - 2) if "completed" in d else None)),
        ["drops.json", "steps", f"{T - 2} steps", f"measurements {T}", "shorter"],
    ),
    ("steps-longer-than-the-log", _record(lambda d: d.__setitem__("steps", T + 3)), ["steps", "longer"]),
    ("steps-zero", _record(lambda d: d.__setitem__("steps", 0)), ["steps", "integer >= 1"]),
    ("agents-other", _record(lambda d: d.__setitem__("agents", 4)), ["agents", "4 agents", "scenario 3"]),
    ("agents-bool", _record(lambda d: d.__setitem__("agents", True)), ["agents", "integer >= 1"]),
    ("seed-negative", _record(lambda d: d.__setitem__("seed", -1)), ["seed", "integer >= 0"]),
    ("p-drop-above-one", _record(lambda d: d.__setitem__("p_drop", 2)), ["p_drop", "[0, 1]"]),
    ("unknown-entry", _record(lambda d: d.__setitem__("stoped", {})), ["drops.json", "stoped", "no such entry"]),
    ("estimator-unknown", _record(lambda d: d.__setitem__("estimator", "nosuch")), ["drops.json", "estimator", "'nosuch'"]),
    ("estimator-not-deployed", _record(lambda d: d.__setitem__("estimator", "kcf")), ["fingerprint", "another estimator"]),
    ("record-of-another-scenario", _record(lambda d: None, "other.toml"), ["drops.json", "scenario", "'tiny'", "not 'other'"]),
    ("record-of-another-version", _record(lambda d: None, "tiny-v2.toml"), ["drops.json", "fingerprint", "another version of scenario 'tiny'"]),
]


def _parquet(kind: str) -> Callable[[Path, dict], list[str]]:
    def build(tmp: Path, b: dict) -> list[str]:
        df = pd.read_csv(b["log"])
        if kind == "category":
            df["y0"] = df["y0"].astype(str).astype("category")
        elif kind == "text":
            df["y0"] = df["y0"].astype(str)
        elif kind == "bytes":
            df["y0"] = [b"x"] * len(df)
        df.to_parquet(tmp / "log.parquet")
        return ["filter", str(b["scenario"]), "--measurements", str(tmp / "log.parquet"), "--out", str(tmp / "est.csv")]

    return build


def _truth_parquet_category(tmp: Path, b: dict) -> list[str]:
    df = pd.read_csv(b["truth"])
    df["x0"] = df["x0"].astype(str).astype("category")
    df.to_parquet(tmp / "truth.parquet")
    return ["filter", str(b["scenario"]), "--measurements", str(b["log"]), "--truth", str(tmp / "truth.parquet"), "--out", str(tmp / "est.csv")]


def _npz(arrays: dict[str, Any]) -> Callable[[Path, dict], list[str]]:
    def build(tmp: Path, b: dict) -> list[str]:
        np.savez(tmp / "log.npz", **arrays)
        return ["filter", str(b["scenario"]), "--measurements", str(tmp / "log.npz"), "--out", str(tmp / "est.csv")]

    return build


def _garbage_npz(tmp: Path, b: dict) -> list[str]:
    (tmp / "log.npz").write_bytes(b"\x00\x01garbage")
    return ["filter", str(b["scenario"]), "--measurements", str(tmp / "log.npz"), "--out", str(tmp / "est.csv")]


def _csv_text(tmp: Path, b: dict) -> list[str]:
    lines = b["log"].read_text().splitlines()
    lines[2] = "0,1,abc"
    (tmp / "log.csv").write_text("\n".join(lines) + "\n")
    return ["filter", str(b["scenario"]), "--measurements", str(tmp / "log.csv"), "--out", str(tmp / "est.csv")]


FILE_ROWS: list[tuple[str, Callable[..., list[str]], list[str]]] = [
    ("parquet-y0-categorical", _parquet("category"), ["log.parquet", "column 'y0'", "numeric column", "dtype category"]),
    ("parquet-y0-text", _parquet("text"), ["log.parquet", "column 'y0'", "numeric column", "text"]),
    ("parquet-y0-bytes", _parquet("bytes"), ["log.parquet", "column 'y0'", "expected a number", "dtype object"]),
    ("truth-parquet-x0-categorical", _truth_parquet_category, ["truth.parquet", "column 'x0'", "dtype category"]),
    (
        "npz-booleans",
        _npz({"agent0": np.ones((T, 1), bool), "agent1": np.ones((T, 1)), "agent2": np.ones((T, 1))}),
        ["log.npz", "'agent0'", "dtype bool"],
    ),
    ("npz-not-a-zip", _garbage_npz, ["log.npz", "not an NPZ file"]),
    ("csv-text-in-y0", _csv_text, ["log.csv", "row 2 (line 3), column 'y0'", "expected a number", "'abc'"]),
]


def _population(cmd: str) -> Callable[[Path, dict], list[str]]:
    def build(tmp: Path, b: dict) -> list[str]:
        if cmd == "deploy":
            return ["deploy", "interference", "--measurements", str(b["log"]), "--out", str(tmp / "est.csv"), "--transport", "queue"]
        if cmd == "agent":
            argv = _roster(OK)(tmp, b)
            argv[1] = "interference"
            return argv
        return ["filter", "interference", "--measurements", str(b["log"]), "--drops", str(b["drops"]), "--out", str(tmp / "est.csv")]

    return build


def _agent_flag(flag: str, value: str) -> Callable[[Path, dict], list[str]]:
    def build(tmp: Path, b: dict) -> list[str]:
        argv = _roster(OK)(tmp, b)
        if flag == "--id":
            argv[argv.index("--id") + 1] = value
            return argv
        return argv + [flag, value]

    return build


OTHER_ROWS: list[tuple[str, Callable[..., list[str]], list[str]]] = [
    ("deploy-population-scenario", _population("deploy"), ["SCENARIO", "interference", "population scenario", "no agents to deploy"]),
    ("filter-drops-population-scenario", _population("filter"), ["SCENARIO", "population scenario", "no agents to replay"]),
    ("agent-population-scenario", _population("agent"), ["SCENARIO", "population scenario", "no agents to run"]),
    ("agent-steps-negative", _agent_flag("--steps", "-5"), ["--steps", "integer >= 1", "-5"]),
    ("agent-steps-zero", _agent_flag("--steps", "0"), ["--steps", "integer >= 1"]),
    ("agent-kill-at-negative", _agent_flag("--kill-at", "-1"), ["--kill-at", "integer >= 0"]),
    ("agent-id-negative", _agent_flag("--id", "-1"), ["--id", "integer >= 0"]),
]

ROWS = ROSTER_ROWS + DROP_ROWS + FILE_ROWS + OTHER_ROWS


@pytest.mark.parametrize("build, words", [pytest.param(b, w, id=name) for name, b, w in ROWS])
def test_a_bad_file_is_one_line_naming_the_entry(build, words, base, tmp_path, capsys):
    busy = socket.socket(socket.AF_INET, socket.SOCK_STREAM)  # a port another program listens on
    busy.bind(("127.0.0.1", 0))
    busy.listen()
    try:
        argv = build(tmp_path, {**base, "busy": busy.getsockname()[1]})
        before = _snapshot(tmp_path, base["dir"])
        capsys.readouterr()
        rc = main(argv)
        out, err = capsys.readouterr()
    finally:
        busy.close()
    lines = err.strip().splitlines()
    assert rc == 2, (rc, err)
    assert len(lines) == 1 and lines[0].startswith("teamkf: error: "), err
    assert "Traceback" not in err and "ZError" not in err and ".rs:" not in err
    for w in words:
        assert w in lines[0], (w, lines[0])
    assert _snapshot(tmp_path, base["dir"]) == before  # nothing written, nothing changed


def test_the_good_record_replays_and_the_deployment_round_trips(base, tmp_path, capsys):
    """The rows above fail for their one mistake: the record they start from replays; a record as written replays to the deployment's file."""
    assert (
        main(["filter", str(base["scenario"]), "--measurements", str(base["log"]), "--drops", str(base["drops"]), "--out", str(tmp_path / "r.csv")])
        == 0
    )
    rec = tmp_path / "rec.json"
    args = ["--measurements", str(base["log"]), "--p-drop", "0.3", "--seed", "2"]
    assert (
        main(["deploy", str(base["scenario"]), *args[:2], "--out", str(tmp_path / "d.csv"), "--record", str(rec), "--transport", "queue", *args[2:]])
        == 0
    )
    assert json.loads(rec.read_text())["missed"]  # something was dropped
    assert main(["filter", str(base["scenario"]), *args[:2], "--drops", str(rec), "--out", str(tmp_path / "r2.csv")]) == 0
    assert (tmp_path / "d.csv").read_bytes() == (tmp_path / "r2.csv").read_bytes()
    capsys.readouterr()


def test_a_roster_that_passes_its_checks_but_zenoh_refuses_is_one_line(base, tmp_path, capsys, monkeypatch):
    """What Zenoh still refuses after the checks (here: a session that cannot open) is one line naming the roster and the endpoint."""
    pytest.importorskip("zenoh")
    from teamkf.deploy import ZenohTransport
    from teamkf.deploy.transport import zenoh_module

    z = zenoh_module()

    def refuse(config):
        raise z.ZError("Can not create a new TCP listener at /root/.cargo/git/checkouts/zenoh/io/lib.rs:62.")

    monkeypatch.setattr(z, "open", refuse)
    argv = _roster(OK)(tmp_path, base)
    capsys.readouterr()
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "roster.toml" in err[0] and "agent 0" in err[0] and "tcp/127.0.0.1:" in err[0], err
    assert ".rs:" not in err[0] and "Can not create a new TCP listener" in err[0]
    assert ZenohTransport  # the transport the agent opens


# ---------------------------------------------------------------------------
# cache parts: recomputed with one warning, the same numbers
# ---------------------------------------------------------------------------
def _rows(results: list[dict[str, Any]]) -> list[dict[str, Any]]:
    return [{k: v for k, v in r.items() if k != "seconds"} for res in results for r in res["rows"]]


@pytest.fixture(scope="module")
def leaderboard_cache(tmp_path_factory):
    """The exact parts of the first quick leaderboard network, computed once into a cache folder."""
    from teamkf.experiments import leaderboard as L

    d = tmp_path_factory.mktemp("cache")
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("TEAMKF_CACHE_DIR", str(d))
        mp.setenv("TEAMKF_WORKERS", "1")
        clean = L._exact_results(True, L.HORIZON, [0])
    assert not clean[0]["cached"] and len(list(d.glob("*.json"))) == len(L.PARTS)
    return d, clean


def _set(path: list[Any], value: Any) -> Callable[[dict], None]:
    def change(d: dict) -> None:
        obj = d
        for k in path[:-1]:
            obj = obj[k]
        obj[path[-1]] = value

    return change


def _text(f: Callable[[str], str]) -> Callable[[str], str]:
    f.on_text = True  # type: ignore[attr-defined]
    return f


@pytest.mark.parametrize(
    "corrupt, why",
    [
        pytest.param(_text(lambda text: text[: len(text) // 2]), "not readable JSON", id="truncated-json"),
        pytest.param(_text(lambda text: "\x00\x01"), "not readable JSON", id="binary"),
        pytest.param(_text(lambda text: "[1, 2]"), "expected an object", id="not-an-object"),
        pytest.param(_set(["raw"], 5), "part.raw: expected list", id="raw-wrong-type"),
        pytest.param(_set(["raw", 0, "stage_costs"], "x"), "raw[0].stage_costs", id="stage-costs-wrong-type"),
        pytest.param(_set(["raw", 0, "stage_costs"], [1.0, 2.0]), "raw[0].stage_costs: expected 40 numbers", id="stage-costs-short"),
        pytest.param(_set(["raw", 1, "realizable"], "yes"), "raw[1].realizable: expected bool", id="row-wrong-type"),
        pytest.param(lambda d: d.pop("n_agents"), "missing 'n_agents'", id="key-missing"),
        pytest.param(_set(["version"], 1), "version", id="wrong-version"),
        pytest.param(lambda d: d.pop("format"), "format", id="no-format"),
    ],
)
def test_a_corrupt_leaderboard_part_is_recomputed_with_a_warning(corrupt, why, leaderboard_cache, tmp_path, monkeypatch, capsys):
    from teamkf.experiments import leaderboard as L

    src, clean = leaderboard_cache
    cache = tmp_path / "cache"
    shutil.copytree(src, cache)
    part = next(cache.glob("*-base.json"))
    text = part.read_text()
    if getattr(corrupt, "on_text", False):
        bad = corrupt(text)
    else:  # a change of the parsed part
        d = json.loads(text)
        corrupt(d)
        bad = json.dumps(d)
    part.write_text(bad)
    monkeypatch.setenv("TEAMKF_CACHE_DIR", str(cache))
    monkeypatch.setenv("TEAMKF_WORKERS", "1")
    capsys.readouterr()
    again = L._exact_results(True, L.HORIZON, [0])
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("teamkf: warning: leaderboard cache part ") and part.name in err[0], err
    assert why in err[0] and "recomputing it" in err[0], err[0]
    assert not again[0]["cached"] and _rows(again) == _rows(clean)
    # the part was written again, whole: the next run reads it back silently
    assert L._exact_results(True, L.HORIZON, [0])[0]["cached"] and capsys.readouterr().err == ""


def test_a_corrupt_sweep_part_is_recomputed_on_resume_with_a_warning(base, tmp_path, capsys):
    (tmp_path / "tiny.toml").write_text(SCENARIO)
    (tmp_path / "s.toml").write_text('scenario = "tiny.toml"\nruns = 0\nseed = 7\n[grid]\n"cost.lambda" = [1.0, 10.0]\n')
    out = tmp_path / "r.parquet"
    args = ["sweep", str(tmp_path / "s.toml"), "--scheduler", "serial", "--out", str(out)]
    assert main(args) == 0
    ref = pd.read_parquet(out).sort_values(["point_index", "estimator"]).reset_index(drop=True)
    part = sorted(out.glob("part-*.parquet"))[0]
    part.write_bytes(part.read_bytes()[:100])  # cut short
    capsys.readouterr()
    assert main([*args, "--resume"]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("teamkf: warning: sweep part ") and part.name in err[0] and "recomputing" in err[0], err
    got = pd.read_parquet(out).sort_values(["point_index", "estimator"]).reset_index(drop=True)
    assert got.drop(columns=["teamkf_version"]).equals(ref.drop(columns=["teamkf_version"]))
