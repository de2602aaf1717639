"""Deployed agents that a stranger cannot steer: authenticated frames, checked payloads, bounded memory, keys and TLS.

The threat model is in docs/deploy.md ("Security"); each claim there names a test of this file.
"""

from __future__ import annotations

import importlib.util
import json
import os
import secrets
import shutil
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from teamkf.deploy import Frame, FrameError, Mailbox, decode_frame, encode_frame
from teamkf.deploy.agent import REFUSED, AgentCore, windows
from teamkf.deploy.codec import BYE, DATA, DROPPED, HEADER_SIZE, HELLO, TAG_SIZE, encode_payload, open_frame
from teamkf.deploy.payload import learn_payloads
from teamkf.deploy.roster import Roster, read_key, write_key
from teamkf.exceptions import ArgumentError
from teamkf.study import measurements as M
from teamkf.study.scenario import load_packaged

SRC = Path(__file__).resolve().parents[2] / "src"
ENV = {**os.environ, "PYTHONPATH": f"{SRC}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"}
KEY = bytes(range(32))
#: the far-future flood at the target, in 1 MB frames (TEAMKF_FLOOD_MB=1000 for the gigabyte of docs/deploy.md)
FLOOD_MB = int(os.environ.get("TEAMKF_FLOOD_MB", "200"))
live = pytest.mark.skipif(importlib.util.find_spec("zenoh") is None, reason="needs eclipse-zenoh (pip install 'teamkf[deploy]')")


def _teamkf(*args: str, timeout: float = 300) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "teamkf", *args], capture_output=True, text=True, env=ENV, timeout=timeout)


# ---------------------------------------------------------------------------
# the tag: every byte of header and payload is covered
# ---------------------------------------------------------------------------
def test_flipping_any_byte_of_a_frame_refuses_it():
    data = encode_frame(Frame(DATA, 2**62 + 3, 1, 2, 7, 6, [np.arange(3.0)]), KEY)
    assert decode_frame(data, KEY).step == 7
    for pos in range(len(data)):
        for bit in (0x01, 0x80):
            bad = data[:pos] + bytes([data[pos] ^ bit]) + data[pos + 1 :]
            with pytest.raises(FrameError) as exc:
                open_frame(bad, KEY)
            assert exc.value.reason in ("magic", "version", "short", "auth", "unkeyed"), (pos, exc.value.reason)


@pytest.mark.parametrize("field", ["run_id", "sender", "receiver", "step", "origin", "kind", "flags"])
def test_a_captured_frame_restamped_in_any_header_field_fails(field):
    """The attacker keeps the tag and rewrites one header field (another step, receiver, sender, run): refused."""
    import struct

    data = encode_frame(Frame(DATA, 99, 1, 2, 7, 6, [np.arange(3.0)]), KEY)
    magic, ver, kind, flags, run_id, sender, receiver, step, origin, n = struct.unpack_from("<4sHBBQIIIII", data)
    vals = {"kind": kind, "flags": flags, "run_id": run_id, "sender": sender, "receiver": receiver, "step": step, "origin": origin}
    vals[field] = {"kind": HELLO, "flags": DROPPED}.get(field, vals[field] + 5)
    head = struct.pack(
        "<4sHBBQIIIII", magic, ver, vals["kind"], vals["flags"], vals["run_id"], vals["sender"], vals["receiver"], vals["step"], vals["origin"], n
    )
    with pytest.raises(FrameError) as exc:
        open_frame(head + data[HEADER_SIZE:], KEY)
    assert exc.value.reason == "auth"


def test_wrong_key_unkeyed_truncated_and_changed_payload_are_refused():
    f = Frame(DATA, 99, 1, 2, 7, 6, [np.arange(3.0)])
    data = encode_frame(f, KEY)
    reasons = {}
    for what, raw, key in [
        ("wrong key", data, bytes(32)),
        ("unkeyed", encode_frame(f), KEY),
        ("truncated", data[:-1], KEY),
        ("no tag", data[:-TAG_SIZE], KEY),
        ("changed payload", data[:HEADER_SIZE] + encode_payload([np.arange(3.0) * 100]) + data[-TAG_SIZE:], KEY),
        ("keyed, receiver without key", data, None),
    ]:
        with pytest.raises(FrameError) as exc:
            open_frame(raw, key)
        reasons[what] = exc.value.reason
    assert reasons == {
        "wrong key": "auth",
        "unkeyed": "unkeyed",
        "truncated": "short",
        "no tag": "short",
        "changed payload": "auth",
        "keyed, receiver without key": "checksum",
    }
    with pytest.raises(FrameError, match="at least 32 bytes"):
        encode_frame(f, b"short key")


def test_the_payload_is_not_decoded_before_the_tag_matched(monkeypatch):
    import teamkf.deploy.codec as codec

    calls = []
    monkeypatch.setattr(codec, "decode_payload", lambda b: calls.append(b))
    data = encode_frame(Frame(DATA, 99, 1, 2, 7, 6, "x"), bytes(32))
    with pytest.raises(FrameError):
        codec.decode_frame(data, KEY)
    assert calls == []


# ---------------------------------------------------------------------------
# the mailbox: refused frames are counted and change nothing
# ---------------------------------------------------------------------------
@pytest.fixture(scope="module")
def kcf():
    sc = load_packaged("platoon-6")
    design = sc.design("kcf")
    return sc, design, AgentCore(design, 1, graph=sc.graph)


def _box(core: AgentCore, key: bytes | None = KEY) -> Mailbox:
    specs, limits = core.payload_specs()
    return Mailbox(1, 11, core.in_delays, [0, 2, 3, 4, 5], key=key, specs=specs, limits=limits, windows=core.windows)


def _real_payload(design, sender: int):
    """What ``sender``'s design sends at step 0 (the structure the receiver expects)."""
    a = design.graph_agents()[sender]
    from teamkf.deploy.agent import _set_tolerant

    _set_tolerant(a)
    _, _, p = a.step(a.init_state(1), 0, np.zeros((1, int(design.system.dy[sender]))), [])
    return p


def _state(box: Mailbox):
    return (dict(box.data), set(box.notices), set(box.heard), set(box.left), dict(box.last_seen), set(box.failed))


def test_payloads_not_of_the_designs_structure_are_refused_and_never_crash(kcf):
    sc, design, core = kcf
    box = _box(core)
    good = _real_payload(design, 0)
    assert isinstance(good, dict) and set(good) == {"y", "xbar"}
    bad = [
        "a string",
        None,
        {"y": good["y"], "xbar": np.full_like(good["xbar"], np.nan)},  # non-finite
        {"y": good["y"], "xbar": np.full_like(good["xbar"], np.inf)},
        {"y": good["y"], "xbar": good["xbar"][:3]},  # another shape
        {"y": good["y"], "xbar": good["xbar"].astype(np.float32)},  # another dtype
        {"y": good["y"]},  # a key missing
        {"y": good["y"], "xbar": good["xbar"], "extra": 1},
        {"y": "1", "xbar": good["xbar"]},
        [good],
        (good["y"], good["xbar"]),
        np.zeros((2, 2)),
        float("nan"),
    ]
    before = _state(box)
    for p in bad:
        box.put(encode_frame(Frame(DATA, 11, 0, 1, 1, 0, p), KEY))  # the same slot each time: nothing was stored
    assert box.counts["bad_payload"] == len(bad) and _state(box) == before  # nothing stored, no liveness refreshed
    box.put(encode_frame(Frame(DATA, 11, 0, 1, 1, 0, good), KEY))
    assert box.counts["received"] == 1 and (0, 0) in box.data
    # a control frame with an unexpected payload: refused too
    box.put(encode_frame(Frame(HELLO, 11, 0, 1, 0, 1, "hi"), KEY))
    box.put(encode_frame(Frame(BYE, 11, 0, 1, 0, 0, {"x": 1}), KEY))
    assert box.counts["bad_payload"] == len(bad) + 2 and 0 not in box.left and 0 not in box.heard


@pytest.mark.parametrize("family", ["mtmse", "diffusion", "ci"])
def test_learned_structure_accepts_every_payload_of_a_real_run(family):
    """No false refusal: every payload of a 30-step in-process run (with and without losses) matches its sender's spec."""
    from teamkf.deploy.agent import _set_tolerant

    sc = load_packaged("platoon-4") if family == "mtmse" else load_packaged("platoon-6")
    design = sc.design(family)
    graph = design.delivery_graph or sc.graph
    specs, sizes = learn_payloads(design, graph)
    rng = np.random.default_rng(3)
    n = graph.n_agents
    agents = design.graph_agents()
    for a in agents:
        _set_tolerant(a)
    states = [a.init_state(1) for a in agents]
    sent: list[dict] = [{} for _ in range(n)]
    for k in range(30):
        out = []
        for i, a in enumerate(agents):
            inbox = [
                (j, k - graph.delay(j, i), sent[j][k - graph.delay(j, i)])
                for j in graph.in_neighbors(i)
                if k - graph.delay(j, i) >= 0 and rng.random() > 0.2
            ]
            states[i], _, p = a.step(states[i], k, rng.standard_normal((1, int(design.system.dy[i]))), inbox)
            out.append(p)
        for i, p in enumerate(out):
            sent[i][k] = p
            g = decode_frame(encode_frame(Frame(DATA, 1, i, 0, k + 1, k, p), KEY), KEY).payload
            assert specs[i].why(g) is None, (family, i, k, specs[i].why(g))
            assert len(encode_payload(p)) <= 4 * sizes[i] + 4096


def test_far_future_oversize_and_replayed_frames_are_refused_and_memory_stays_bounded(kcf):
    sc, design, core = kcf
    box = _box(core)
    good = _real_payload(design, 0)
    w = core.windows[0]
    assert w == windows(sc.graph, 1)[0] and w <= 2 + 1 + 4  # line graph, unit delays: a neighbour is at most 2 steps ahead
    box.put(encode_frame(Frame(DATA, 11, 0, 1, w + 1, w, good), KEY))  # just past the window
    box.put(encode_frame(Frame(DATA, 11, 0, 1, 10_000, 9_999, good), KEY))
    assert box.counts["future"] == 2 and not box.data
    box.put(encode_frame(Frame(DATA, 11, 0, 1, w - 1, w - 2, good), KEY))  # inside: kept
    assert box.counts["received"] == 1
    big = encode_frame(Frame(DATA, 11, 0, 1, 5, 4, np.zeros(2**17)), KEY)  # 1 MB, correctly signed even
    assert len(big) > box.max_frame
    for _ in range(200):
        box.put(big)
        box.put(os.urandom(1 << 20))
    assert box.counts["oversize"] == 400 and len(box.data) == 1
    # hellos: a counter that does not increase is a replay
    h = encode_frame(Frame(HELLO, 11, 0, 1, 0, 5, {"heard": [1]}), KEY)
    box.put(h)
    box.put(h)
    box.put(encode_frame(Frame(HELLO, 11, 0, 1, 0, 4, {"heard": [1]}), KEY))
    assert box.counts["replayed"] == 2 and box.beats[0] == 5
    assert set(box.counts) <= set(REFUSED) | {"received"}


def test_a_restarted_process_is_heard_again_and_the_old_ones_hellos_stay_replays(kcf):
    """A process restarted with --rejoin counts its hellos from 1 again: its authenticated rejoin announcement resets
    the counter (once per rejoin step); hellos captured from the process before it are then refused, whatever their
    counter, and a replay of the new process's own hellos is refused by its counter."""
    sc, design, core = kcf
    box = _box(core)
    old = [encode_frame(Frame(HELLO, 11, 0, 1, 0, c, {"heard": [1], "step": 40 + c}), KEY) for c in range(1, 301)]
    for f in old:
        box.put(f)
    assert box.beats[0] == 300 and box.counts["replayed"] == 0
    box.put(encode_frame(Frame(HELLO, 11, 0, 1, 0, 3, {"heard": [1], "step": 500, "rejoin": 500}), KEY))  # the restarted process
    assert box.resume[0] == 500 and box.beats[0] == 3 and box.counts["rejoins"] == 1
    box.put(encode_frame(Frame(HELLO, 11, 0, 1, 0, 4, {"heard": [1], "step": 501, "rejoin": 500}), KEY))  # its next hello
    assert box.beats[0] == 4
    before = dict(box.counts)
    for f in old[-50:]:  # a stranger replays the old process's hellos, counters far above the new ones
        box.put(f)
    box.put(encode_frame(Frame(HELLO, 11, 0, 1, 0, 4, {"heard": [1], "step": 501, "rejoin": 500}), KEY))  # and the new one's
    assert box.counts["replayed"] - before.get("replayed", 0) == 51 and box.beats[0] == 4 and box.resume[0] == 500


def test_forged_goodbyes_and_frames_of_strangers_change_nothing(kcf):
    sc, design, core = kcf
    box = _box(core)
    good = _real_payload(design, 0)
    before = _state(box)
    wrong = secrets.token_bytes(32)
    for j in range(6):
        box.put(encode_frame(Frame(BYE, 11, j, 1, 0, 0), wrong))  # forged goodbye
        box.put(encode_frame(Frame(BYE, 11, j, 1, 0, 0)))  # unkeyed goodbye
        box.put(encode_frame(Frame(HELLO, 11, j, 1, 0, 10**6, {"heard": [1]}), wrong))
        box.put(encode_frame(Frame(DATA, 11, 0, 1, 1, 0, good), wrong))
        box.put(encode_frame(Frame(DATA, 11, 0, 1, 1, 0, "boom")))
        box.put(os.urandom(100))
    assert _state(box) == before
    assert box.counts["corrupt_auth"] == 18 and box.counts["corrupt_unkeyed"] == 12 and box.counts["corrupt_magic"] == 6


# ---------------------------------------------------------------------------
# keys, rosters and teamkf roster new
# ---------------------------------------------------------------------------
def _roster_text(port: int, extra: str = "") -> str:
    return f'run_id = 5\nprefix = "teamkf/t"\n{extra}\n[[agents]]\nid = 0\nendpoint = "tcp/127.0.0.1:{port}"\n'


def test_key_file_is_read_relative_to_the_roster_and_refused_with_one_line(tmp_path):
    write_key(tmp_path / "team.key", KEY)
    assert (tmp_path / "team.key").stat().st_mode & 0o777 == 0o600
    (tmp_path / "r.toml").write_text(_roster_text(7447, 'key_file = "team.key"'))
    r = Roster.read(tmp_path / "r.toml")
    assert r.key == KEY and r.key_file == "team.key" and KEY.hex() not in repr(r)
    assert Roster.read(tmp_path / "r.toml") == r
    cases = {
        "missing": ('key_file = "nope.key"', None, "no such key file"),
        "mode": ('key_file = "open.key"', ("open.key", KEY.hex(), 0o644), "mode 0644, readable by other users"),
        "short": ('key_file = "short.key"', ("short.key", "abcd", 0o600), "expected 64 hex digits"),
        "not hex": ('key_file = "txt.key"', ("txt.key", "correct horse battery staple " * 3, 0o600), "not hex digits"),
        "not a string": ("key_file = 3", None, "expected the path of the team key file"),
    }
    for what, (line, file, msg) in cases.items():
        if file is not None:
            (tmp_path / file[0]).write_text(file[1])
            os.chmod(tmp_path / file[0], file[2])
        (tmp_path / "bad.toml").write_text(_roster_text(7447, line))
        with pytest.raises(ArgumentError, match=msg) as exc:
            Roster.read(tmp_path / "bad.toml")
        assert "\n" not in str(exc.value) and "bad.toml" in str(exc.value), what
    with pytest.raises(ArgumentError, match="no such key file"):
        read_key(tmp_path / "absent.key")


def test_agent_refuses_a_roster_without_a_key_unless_insecure(tmp_path):
    from teamkf.deploy import free_ports

    port = free_ports(1)[0]
    (tmp_path / "r.toml").write_text(_roster_text(port) + f'\n[[agents]]\nid = 1\nendpoint = "tcp/127.0.0.1:{port + 1}"\n')
    argv = ["agent", "lqg-2", "--id", "0", "--roster", str(tmp_path / "r.toml"), "--measurements", "-", "--steps", "1"]
    proc = _teamkf(*argv, timeout=120)
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1, proc.stderr
    assert "no key_file" in proc.stderr and "--insecure" in proc.stderr and "teamkf roster new" in proc.stderr


def test_roster_new_writes_a_roster_and_a_private_key_and_never_overwrites(tmp_path, capsys):
    from teamkf.cli import main

    out = tmp_path / "site" / "roster.toml"
    out.parent.mkdir()
    assert main(["roster", "new", "--endpoints", "tcp/10.0.0.1:7447", "tcp/10.0.0.2:7447", "--out", str(out)]) == 0
    key = out.with_suffix(".key")
    assert key.stat().st_mode & 0o777 == 0o600
    r = Roster.read(out)
    assert r.endpoints == {0: "tcp/10.0.0.1:7447", 1: "tcp/10.0.0.2:7447"} and r.key is not None and len(r.key) == 32
    assert r.key_file == "roster.key" and r.run_id > 0
    text = out.read_text()
    assert r.key.hex() not in text  # the key is only in the key file
    before = (out.read_bytes(), key.read_bytes())
    assert main(["roster", "new", "--endpoints", "tcp/10.0.0.3:7447", "--out", str(out)]) == 2
    assert "exists" in capsys.readouterr().err and (out.read_bytes(), key.read_bytes()) == before
    assert main(["roster", "new", "--endpoints", "tls/10.0.0.3:7447", "--out", str(tmp_path / "t.toml")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "[tls] table" in err and not (tmp_path / "t.key").exists()


def test_tls_table_is_checked_with_one_line_per_problem(tmp_path):
    for name in ("ca.pem", "cert.pem", "key.pem"):
        (tmp_path / name).write_text("-----BEGIN CERTIFICATE-----\nAA==\n-----END CERTIFICATE-----\n")
    os.chmod(tmp_path / "key.pem", 0o600)
    write_key(tmp_path / "team.key", KEY)
    ok = '[tls]\nroot_ca = "ca.pem"\ncertificate = "cert.pem"\nprivate_key = "key.pem"\n'
    text = 'run_id = 5\nkey_file = "team.key"\n' + ok + '[[agents]]\nid = 0\nendpoint = "tls/127.0.0.1:7447"\n'
    (tmp_path / "r.toml").write_text(text)
    r = Roster.read(tmp_path / "r.toml")
    assert r.tls is not None and r.tls.mutual and r.tls.root_ca == str((tmp_path / "ca.pem").resolve())
    assert r.tls.zenoh()["enable_mtls"] is True and r.tls.zenoh()["listen_private_key"].endswith("key.pem")
    (tmp_path / "w.toml").write_text(r.to_toml())  # round trip, the paths as written
    (tmp_path / "w.toml").rename(tmp_path / "w2.toml")
    assert Roster.read(tmp_path / "w2.toml") == r
    (tmp_path / "plain.pem").write_text("not pem")
    (tmp_path / "open.pem").write_text("-----BEGIN PRIVATE KEY-----\n")
    os.chmod(tmp_path / "open.pem", 0o644)
    bad = {
        "root_ca": (ok.replace('"ca.pem"', '"missing.pem"'), "tls.root_ca: no such file"),
        "pem": (ok.replace('"cert.pem"', '"plain.pem"'), "not a PEM file"),
        "mode": (ok.replace('"key.pem"', '"open.pem"'), "readable by other users"),
        "mutual": (ok + "mutual = 1\n", "tls.mutual: expected true or false"),
        "unknown": (ok + "cipher = 1\n", "tls.cipher: unknown key"),
    }
    for what, (table, msg) in bad.items():
        (tmp_path / "b.toml").write_text(text.replace(ok, table))
        with pytest.raises(ArgumentError, match=msg) as exc:
            Roster.read(tmp_path / "b.toml")
        assert "\n" not in str(exc.value), what


# ---------------------------------------------------------------------------
# live: a stranger on the network
# ---------------------------------------------------------------------------
@pytest.fixture(scope="module")
def log6(tmp_path_factory):
    from teamkf.simulation.sampling import sample_paths

    sc = load_packaged("platoon-6")
    paths = sample_paths(sc.system, 200, 1, rng=2026)
    d = tmp_path_factory.mktemp("sec")
    M.write_measurements(d / "log.csv", [y[0] for y in paths.y])
    log = M.read_measurements(d / "log.csv", sc.system, sc.horizon)
    ref = M.filter_log(sc, log, estimators=["kcf"], with_innovations=False).estimates["kcf"]
    M.write_estimates(d / "filter.csv", {"kcf": ref}, 6)
    return d


def _rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return 0.0


@live
@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="reads VmRSS from /proc (Linux)")
def test_a_stranger_on_the_network_changes_nothing(log6, tmp_path):
    """Given one agent's port: read the traffic, re-stamp captured frames for future steps with changed payloads,
    replay them, send unusable payloads, forged goodbyes and hellos, random bytes and 200 x 1 MB far-future frames.
    deploy exits 0, writes filter's file byte for byte, the target's memory grows < 100 MB, every refusal is counted."""
    import tomllib

    import zenoh

    out = tmp_path / "deploy.csv"
    proc = subprocess.Popen(
        [sys.executable, "-m", "teamkf", "deploy", "platoon-6", "--measurements", str(log6 / "log.csv"), "--out", str(out)]
        + ["--estimator", "kcf", "--deadline", "10", "--json"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=ENV,
    )
    assert proc.stderr is not None
    line = proc.stderr.readline()
    pids = [int(p) for p in line.split("pids")[1].split()]
    target = pids[0]
    cmd = Path(f"/proc/{target}/cmdline").read_bytes().split(b"\0")
    roster = tomllib.loads(Path(cmd[cmd.index(b"--roster") + 1].decode()).read_text())  # the attacker is given the port (not the key)
    port_ep = roster["agents"][0]["endpoint"]
    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("connect/endpoints", json.dumps([port_ep]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    captured: list[tuple[str, bytes]] = []
    rss = {"base": None, "peak": 0.0}
    stop = threading.Event()

    def watch() -> None:
        while not stop.is_set() and Path(f"/proc/{target}").exists():
            try:
                v = _rss_mb(target)
            except OSError:
                return
            rss["base"] = v if rss["base"] is None else rss["base"]
            rss["peak"] = max(rss["peak"], v)
            time.sleep(0.02)

    deadline = time.monotonic() + 120
    session = None
    while session is None and time.monotonic() < deadline:  # the agent listens once it designed its gains
        try:
            s = zenoh.open(conf)
            if list(s.info.peers_zid()):
                session = s
            else:
                s.close()
                time.sleep(0.2)
        except Exception:  # noqa: BLE001 - not listening yet
            time.sleep(0.2)
    assert session is not None, "could not reach agent 0"
    threading.Thread(target=watch, daemon=True).start()
    sub = session.declare_subscriber("**", lambda s: captured.append((str(s.key_expr), bytes(s.payload.to_bytes()))))
    prefix = None
    wrong = secrets.token_bytes(32)
    big = np.zeros((1, 2**17))  # 1 MB
    flooded = [0]
    flooder: threading.Thread | None = None
    sent = 0
    import struct

    try:
        while proc.poll() is None and time.monotonic() < deadline:
            batch = list(captured[-20:])
            for key, raw in batch:
                prefix = key.rsplit("/", 1)[0]
                if len(raw) < HEADER_SIZE or raw[:4] != b"TKFD":
                    continue
                magic, ver, kind, flags, run_id, snd, rcv, step, origin, n = struct.unpack_from("<4sHBBQIIIII", raw)
                session.put(key, raw)  # verbatim replay
                body = raw[HEADER_SIZE:-TAG_SIZE]
                head = struct.pack("<4sHBBQIIIII", magic, ver, kind, flags, run_id, snd, rcv, step + 3, origin + 3, n)
                session.put(key, head + body + raw[-TAG_SIZE:])  # re-stamped for a future step, the old tag
                if kind == DATA:
                    from teamkf.deploy.codec import decode_payload

                    p = decode_payload(body)  # the traffic is readable without TLS
                    changed = {k: v * 100 for k, v in p.items()} if isinstance(p, dict) else p
                    for k2 in (wrong, None):
                        session.put(key, encode_frame(Frame(DATA, run_id, snd, rcv, step + 2, origin + 2, changed), k2))
                        session.put(key, encode_frame(Frame(DATA, run_id, snd, rcv, step + 2, origin + 2, "a string"), k2))
                        session.put(key, encode_frame(Frame(BYE, run_id, snd, rcv, 0, 0), k2))  # forged goodbye
                        session.put(key, encode_frame(Frame(HELLO, run_id, snd, rcv, 0, 2**31, {"heard": []}), k2))
                    if flooder is None:  # the run is on: FLOOD_MB MB of far-future frames at the target, alongside the rest

                        def flood(run_id: int = run_id, step: int = step, target: str = f"{prefix}/0") -> None:
                            for q in range(FLOOD_MB):
                                session.put(target, encode_frame(Frame(DATA, run_id, 1, 0, step + 10**6 + q, step + 10**6 + q - 1, big), wrong))
                                flooded[0] += 1

                        flooder = threading.Thread(target=flood, daemon=True)
                        flooder.start()
                session.put(key, os.urandom(200))
                sent += 1
            time.sleep(0.005)
        stdout, stderr = proc.communicate(timeout=60)
        if flooder is not None:
            flooder.join(60)
    finally:
        stop.set()
        sub.undeclare()
        session.close()
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert prefix is not None and sent > 0 and flooded[0] > 0, "the stranger saw no traffic"
    assert proc.returncode == 0, stderr
    summary = json.loads(stdout)
    assert summary["failed"] == {} and summary["missed"] == 0
    assert out.read_bytes() == (log6 / "filter.csv").read_bytes()  # nothing of the stranger was fused
    counts = summary["reports"][0]["counts"]
    assert counts.get("corrupt_auth", 0) > 0 and counts.get("corrupt_unkeyed", 0) > 0, counts
    assert counts.get("corrupt_magic", 0) + counts.get("corrupt_short", 0) > 0, counts
    # the flood reached the target during its run and was refused (how much of it arrived before the run ended depends on
    # the machine's load, and a frame can be counted once per matching subscription: a count, not a share)
    assert counts.get("oversize", 0) > 0, counts
    print(f"stranger: {flooded[0]} MB flood, {sent} rounds; target RSS {rss}; counts {counts}")
    assert rss["base"] is not None and rss["peak"] - rss["base"] <= 100, rss


# ---------------------------------------------------------------------------
# live: TLS links on loopback
# ---------------------------------------------------------------------------
def _openssl(*args: str, cwd: Path) -> None:
    subprocess.run(["openssl", *args], cwd=cwd, check=True, capture_output=True)


def _certificates(d: Path) -> None:
    """A CA, and a certificate for 127.0.0.1 / localhost signed by it (server and client use), with openssl."""
    _openssl(
        "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-keyout", "ca-key.pem", "-out", "ca.pem", "-days", "2", "-subj", "/CN=teamkf test CA", cwd=d
    )
    _openssl("req", "-newkey", "rsa:2048", "-nodes", "-keyout", "agent-key.pem", "-out", "agent.csr", "-subj", "/CN=localhost", cwd=d)
    (d / "ext.cnf").write_text("subjectAltName=IP:127.0.0.1,DNS:localhost\nextendedKeyUsage=serverAuth,clientAuth\n")
    _openssl(
        "x509",
        "-req",
        "-in",
        "agent.csr",
        "-CA",
        "ca.pem",
        "-CAkey",
        "ca-key.pem",
        "-CAcreateserial",
        "-out",
        "agent.pem",
        "-days",
        "2",
        "-extfile",
        "ext.cnf",
        cwd=d,
    )
    os.chmod(d / "agent-key.pem", 0o600)


def _tls_roster(d: Path, ports: list[int]) -> Roster:
    write_key(d / "team.key", KEY)
    text = (
        'run_id = 77\nprefix = "teamkf/tls"\nkey_file = "team.key"\n'
        '[tls]\nroot_ca = "ca.pem"\ncertificate = "agent.pem"\nprivate_key = "agent-key.pem"\nmutual = true\n'
        + "".join(f'[[agents]]\nid = {i}\nendpoint = "tls/127.0.0.1:{p}"\n' for i, p in enumerate(ports))
    )
    (d / "roster.toml").write_text(text)
    return Roster.read(d / "roster.toml")


openssl = pytest.mark.skipif(shutil.which("openssl") is None, reason="makes the test certificates with the openssl command")


@live
@openssl
def test_two_agents_over_mutual_tls_equal_the_in_process_runtime(tmp_path):
    """A CA and a certificate for 127.0.0.1 (openssl), a roster with [tls] and tls/ endpoints: the estimates are bit-equal."""
    from teamkf.deploy import ZenohTransport, free_ports, run_agent
    from teamkf.simulation.sampling import sample_paths
    from teamkf.study.deploy import prepare

    d = tmp_path
    _certificates(d)
    roster = _tls_roster(d, free_ports(2))
    roster.check_network(0)
    sc = load_packaged("lqg-2")
    T = 12
    paths = sample_paths(sc.system, T, 1, rng=5)
    M.write_measurements(d / "log.csv", [y[0] for y in paths.y])
    log = M.read_measurements(d / "log.csv", sc.system, sc.horizon)
    prep = prepare(sc, log, "mtmse")
    ref = M.filter_log(sc, log, estimators=["mtmse"], with_innovations=False).estimates["mtmse"]
    results: list = [None, None]
    transports = [ZenohTransport(i, roster.endpoints, prefix=roster.prefix, tls=roster.tls) for i in range(2)]

    def one(i: int) -> None:
        offs = None if prep.offsets is None else prep.offsets[:, i * prep.dz : (i + 1) * prep.dz]
        results[i] = run_agent(
            prep.design,
            i,
            transports[i],
            lambda k, y=prep.ys[i]: y[:, k],
            n_steps=T,
            run_id=roster.run_id,
            offsets=offs,
            join_timeout=60,
            deadline=10,
            graph=prep.graph,
            key=roster.key,
        )

    threads = [threading.Thread(target=one, args=(i,)) for i in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(120)
    assert all(r is not None and r.error is None and r.steps_done == T for r in results), [r and r.error for r in results]
    z = np.concatenate([r.estimates for r in results], axis=1)
    assert z.tobytes() == ref.tobytes()
    assert all(r.counts.get("received", 0) > 0 for r in results)


@live
@openssl
def test_a_tls_listener_refuses_plain_tcp_and_peers_without_a_certificate(tmp_path):
    import zenoh

    from teamkf.deploy import ZenohTransport, free_ports

    _certificates(tmp_path)
    roster = _tls_roster(tmp_path, free_ports(1))
    agent = ZenohTransport(0, roster.endpoints, prefix=roster.prefix, tls=roster.tls)
    agent.open()
    ep = roster.endpoints[0]
    tls = roster.tls.zenoh()

    def peers(endpoint: str, link: dict | None) -> int:
        c = zenoh.Config()
        c.insert_json5("mode", '"peer"')
        c.insert_json5("connect/endpoints", json.dumps([endpoint]))
        c.insert_json5("scouting/multicast/enabled", "false")
        if link is not None:
            c.insert_json5("transport/link/tls", json.dumps(link))
        s = zenoh.open(c)
        try:
            end = time.monotonic() + 2
            while time.monotonic() < end and not list(s.info.peers_zid()):
                time.sleep(0.1)
            return len(list(s.info.peers_zid()))
        finally:
            s.close()

    try:
        assert peers(ep.replace("tls/", "tcp/"), None) == 0  # plain TCP to the TLS port
        assert peers(ep, {"root_ca_certificate": tls["root_ca_certificate"]}) == 0  # TLS without a client certificate (mutual)
        assert peers(ep, tls) == 1  # with the team's certificate
    finally:
        agent.close()
