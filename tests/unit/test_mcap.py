"""ROS 2 recordings (MCAP) in and out of `teamkf filter`, `deploy`, `agent` and `measurements convert`.

The recordings are written here by an independent writer (mcap-ros2-support's `Writer`, with the ROS 2
message definitions as text): two message types with a header (geometry_msgs/msg/PointStamped and a
sensor_msgs/msg/Range-like type) and one without (its log time is used), jittered header stamps and log
times later than the stamps, a gap, and an agent with two topics. The estimates must equal, bit for bit,
those from the same numbers written as a CSV log.
"""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

pytest.importorskip("mcap_ros2")

from mcap_ros2.reader import read_ros2_messages  # noqa: E402
from mcap_ros2.writer import Writer  # noqa: E402

from teamkf.cli import main  # noqa: E402
from teamkf.study import measurements as M  # noqa: E402

SEP = "=" * 80
HEADER = (
    f"{SEP}\nMSG: std_msgs/Header\nbuiltin_interfaces/Time stamp\nstring frame_id\n{SEP}\nMSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec\n"
)
POINT_STAMPED = f"std_msgs/Header header\ngeometry_msgs/Point point\n{SEP}\nMSG: geometry_msgs/Point\nfloat64 x\nfloat64 y\nfloat64 z\n" + HEADER
RANGE = "std_msgs/Header header\nuint8 radiation_type\nfloat32 field_of_view\nfloat32 min_range\nfloat32 max_range\nfloat32 range\n" + HEADER
SCALAR = "float64 value\nstring note\n"

SCENARIO = """
name = "uav-3-ros"
horizon = 20
estimators = ["mtmse", "mmse", "centralized"]
[system]
A = [[0.9, 0.05, 0.0], [0.05, 0.9, 0.05], [0.0, 0.05, 0.9]]
Q = 1.0
Sigma_x = 1.0
[[agents]]
C = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0, -1.0, 0.0]]
R = 0.1
[[agents]]
C = [[0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
R = 0.1
[[agents]]
C = [[0.0, 0.0, 1.0]]
R = 0.1
[graph]
kind = "complete"
delay = 1
[cost]
kind = "average"
lambda = 10.0
"""

MAP = """
period = 0.1
start = 1700000000.0
[[topics]]
topic = "/uav0/gps"
agent = 0
fields = ["point.x", "point.y"]
[[topics]]
topic = "/uav0/range"
agent = 0
fields = ["range"]
[[topics]]
topic = "/uav1/gps"
agent = 1
fields = ["point.y", "point.z"]
[[topics]]
topic = "/uav2/alt"
agent = 2
fields = ["value"]
"""

SRC = str(Path(__file__).resolve().parents[2] / "src")
T = 12
EXACT = {"float_precision": "round_trip"} if int(pd.__version__.split(".")[0]) < 3 else {}
START = 1_700_000_000 * 10**9
P = 100_000_000  # 0.1 s


def _values(seed=0):
    """The numbers of the recording: per agent (T, d_y), NaN at the gaps (the range is float32 on the wire)."""
    rng = np.random.default_rng(seed)
    y0 = rng.standard_normal((T, 3))
    y0[:, 2] = y0[:, 2].astype(np.float32)
    y1 = rng.standard_normal((T, 2))
    y2 = rng.standard_normal((T, 1)) * 1e3
    y1[5] = np.nan  # a gap: /uav1/gps has no message at step 5
    y0[7, 2] = np.nan  # and /uav0/range none at step 7 (agent 0 keeps its gps there)
    return [y0, y1, y2]


def _stamp(t):
    return {"sec": t // 10**9, "nanosec": t % 10**9}


def write_recording(path, ys, *, extra=None, skip=(), jitter_seed=1):
    """Write the recording with mcap-ros2-support's Writer (jittered stamps, log times 45% of a period later)."""
    rng = np.random.default_rng(jitter_seed)
    msgs = []
    for k in range(T):
        for topic, (i, cols) in {"/uav0/gps": (0, [0, 1]), "/uav0/range": (0, [2]), "/uav1/gps": (1, [0, 1]), "/uav2/alt": (2, [0])}.items():
            v = ys[i][k, cols]
            if np.isnan(v).all() or topic in skip:
                continue
            stamp = START + k * P + int(rng.integers(-P * 3 // 10, P * 3 // 10))
            if topic.endswith("gps"):
                point = {"x": v[0], "y": v[1], "z": -1.0} if i == 0 else {"x": 99.0, "y": v[0], "z": v[1]}
                msgs.append((stamp + P * 45 // 100, topic, "gps", {"header": {"stamp": _stamp(stamp), "frame_id": "map"}, "point": point}))
            elif topic == "/uav0/range":
                r = {"radiation_type": 1, "field_of_view": 0.1, "min_range": 0.0, "max_range": 50.0, "range": float(v[0])}
                msgs.append((stamp + P * 45 // 100, topic, "range", {"header": {"stamp": _stamp(stamp), "frame_id": "uav0"}, **r}))
            else:  # no header: its log time is used
                msgs.append((stamp, topic, "scalar", {"value": float(v[0]), "note": "alt"}))
    msgs += extra or []
    msgs.sort(key=lambda m: m[0])
    with open(path, "wb") as fh:
        w = Writer(fh)
        schemas = {
            "gps": w.register_msgdef("geometry_msgs/msg/PointStamped", POINT_STAMPED),
            "range": w.register_msgdef("sensor_msgs/msg/Range", RANGE),
            "scalar": w.register_msgdef("test_msgs/msg/Scalar", SCALAR),
        }
        for t, topic, kind, msg in msgs:
            w.write_message(topic, schemas[kind], msg, log_time=t, publish_time=t)
        w.finish()


@pytest.fixture
def files(tmp_path):
    sc = tmp_path / "uav3.toml"
    sc.write_text(SCENARIO)
    mp = tmp_path / "map.toml"
    mp.write_text(MAP)
    ys = _values()
    rec = tmp_path / "run.mcap"
    write_recording(rec, ys)
    csv = tmp_path / "log.csv"
    M.write_measurements(csv, ys)
    return sc, mp, rec, csv, ys


def _run(capsys, *argv):
    rc = main([*map(str, argv)])
    cap = capsys.readouterr()
    return rc, cap.out, cap.err


def test_recording_filters_bit_for_bit_as_its_csv_log(files, tmp_path, capsys):
    sc, mp, rec, csv, ys = files
    rc, _, err = _run(capsys, "filter", sc, "--measurements", csv, "--out", tmp_path / "ref.csv")
    assert rc == 0, err
    rc, out, err = _run(capsys, "filter", sc, "--measurements", rec, "--map", mp, "--out", tmp_path / "est.mcap")
    assert rc == 0, err
    assert "est.mcap" in out and "tmp" not in out.replace(str(tmp_path), "")
    rc, _, err = _run(capsys, "filter", sc, "--measurements", rec, "--map", mp, "--out", tmp_path / "est.csv")
    assert rc == 0, err
    assert (tmp_path / "est.csv").read_bytes() == (tmp_path / "ref.csv").read_bytes()
    ref = pd.read_csv(tmp_path / "ref.csv", **EXACT)
    got: dict[str, list] = {}
    for m in read_ros2_messages(str(tmp_path / "est.mcap")):
        assert m.schema.name == "std_msgs/msg/Float64MultiArray"
        got.setdefault(m.channel.topic, []).append((m.log_time_ns, list(m.ros_msg.data)))
    assert sorted(got) == sorted(f"/teamkf/{e}/agent{i}" for e in ("mtmse", "mmse", "centralized") for i in range(3))
    for topic, rows in got.items():
        name, agent = topic.split("/")[2], int(topic[-1])
        assert [t for t, _ in rows] == [START + k * P for k in range(T)]
        want = ref[(ref.estimator == name) & (ref.agent == agent)].sort_values("step")["z0"].to_numpy()
        np.testing.assert_array_equal(np.array([v for _, v in rows]).ravel(), want)  # bit for bit


def test_csv_log_to_mcap_estimates_and_truth(files, tmp_path, capsys):
    sc, mp, rec, csv, ys = files
    x = np.random.default_rng(3).standard_normal((T, 3))
    pd.DataFrame({"step": np.arange(T), **{f"x{c}": x[:, c] for c in range(3)}}).to_csv(tmp_path / "x.csv", index=False, float_format="%.17g")
    rc, _, err = _run(capsys, "filter", sc, "--measurements", csv, "--truth", tmp_path / "x.csv", "--out", tmp_path / "ref.csv")
    assert rc == 0, err
    rc, _, err = _run(capsys, "filter", sc, "--measurements", csv, "--truth", tmp_path / "x.csv", "--map", mp, "--out", tmp_path / "e.mcap")
    assert rc == 0, err
    cost = pd.read_csv(tmp_path / "ref-cost.csv", **EXACT)
    by = {}
    for m in read_ros2_messages(str(tmp_path / "e.mcap")):
        by.setdefault(m.channel.topic, []).append(m.ros_msg)
    np.testing.assert_array_equal(np.array([list(m.data) for m in by["/teamkf/truth"]]), x)
    np.testing.assert_array_equal([m.data for m in by["/teamkf/mtmse/cost"]], cost[cost.estimator == "mtmse"]["cost"].to_numpy())
    assert not (tmp_path / "e-cost.mcap").exists()


def test_truth_topics_of_a_recording(files, tmp_path, capsys):
    sc, mp, rec, csv, ys = files
    x = np.random.default_rng(4).standard_normal((T, 3))
    mp.write_text(MAP + '[[truth]]\ntopic = "/sim/x"\nfields = ["value[0]", "value[1]", "value[2]"]\n')
    vec = "float64[] value\n"
    extra = []
    for k in range(T):  # a 3x faster truth: each step takes the nearest message
        for d in (-P // 3, 0, P // 3):
            extra.append((START + k * P + d, "/sim/x", "vec", {"value": list(x[k] + (0 if d == 0 else 50.0))}))
    path = tmp_path / "with-truth.mcap"
    write_recording(path, ys)
    with open(path, "wb") as fh:  # rewrite with the truth topic too
        w = Writer(fh)
        s = w.register_msgdef("test_msgs/msg/Vec", vec)
        for t, topic, _, msg in sorted(extra, key=lambda m: m[0]):
            w.write_message(topic, s, msg, log_time=t, publish_time=t)
        w.finish()
    pd.DataFrame({"step": np.arange(T), **{f"x{c}": x[:, c] for c in range(3)}}).to_csv(tmp_path / "x.csv", index=False, float_format="%.17g")
    rc, _, err = _run(capsys, "filter", sc, "--measurements", csv, "--truth", tmp_path / "x.csv", "--out", tmp_path / "ref.csv")
    assert rc == 0, err
    rc, _, err = _run(capsys, "filter", sc, "--measurements", rec, "--truth", path, "--map", mp, "--out", tmp_path / "est.csv")
    assert rc == 0, err
    assert (tmp_path / "est-cost.csv").read_bytes() == (tmp_path / "ref-cost.csv").read_bytes()


def test_default_start_is_the_first_message(files, tmp_path):
    sc, mp, rec, csv, ys = files
    mp.write_text(MAP.replace("start = 1700000000.0\n", ""))
    tmap = M.mcap_source.read_map(mp)
    got = M.mcap_source.read_recording(rec, tmap)
    first = min(
        m.log_time_ns if not hasattr(m.ros_msg, "header") else m.ros_msg.header.stamp.sec * 10**9 + m.ros_msg.header.stamp.nanosec
        for m in read_ros2_messages(str(rec))
    )
    assert got.start_ns == first and got.n_steps == T
    for a, b in zip(got.y, ys):
        np.testing.assert_array_equal(a, b)


def _extra_msg(topic, k, kind="gps", dt=0):
    t = START + k * P + dt
    if kind == "gps":
        return (t, topic, "gps", {"header": {"stamp": _stamp(t), "frame_id": ""}, "point": {"x": 0.0, "y": 0.0, "z": 0.0}})
    return (t, topic, "scalar", {"value": 1.0, "note": ""})


@pytest.mark.parametrize(
    "map_text, extra, skip, words",
    [
        (MAP, [_extra_msg("/uav1/gps", 3, dt=P // 5)], (), ["/uav1/gps", "step 3", "two messages"]),
        (MAP.replace('["range"]', '["header.frame_id"]'), [], (), ["/uav0/range", "header.frame_id", "expected a number"]),
        (MAP.replace('["range"]', '["radius"]'), [], (), ["/uav0/range", "radius", "absent"]),
        (MAP.replace('"point.y", "point.z"', '"point.y", "point.w"'), [], (), ["/uav1/gps", "point.w", "absent"]),
        (MAP.replace('["value"]', '["value[0]"]'), [], (), ["/uav2/alt", "value[0]", "not an array"]),
        (MAP, [], ("/uav2/alt",), ["/uav2/alt", "no message in the recording"]),
        (MAP.replace('"/uav2/alt"', '"/uav2/altitude"'), [], (), ["/uav2/altitude", "its topics"]),
        (MAP.replace('["range"]', '["range", "min_range"]'), [], (), ["agent 0", "add up to 4", "d_y^0 = 3"]),
        (MAP.replace("agent = 2", "agent = 3"), [], (), ["agent 2", "no [[topics]] entry"]),
        (MAP.replace("period = 0.1", "period = -1"), [], (), ["period", "> 0"]),
        (MAP.replace("period = 0.1", "perod = 0.1"), [], (), ["perod", "unknown key"]),
        (MAP.replace('fields = ["value"]', 'fileds = ["value"]'), [], (), ["topics[3]", "fileds", "unknown key"]),
        (MAP.replace('["value"]', '["value..x"]'), [], (), ["topics[3]", "value..x", "not a field path"]),
        (MAP.replace("start = 1700000000.0", "start = 1800000000.0"), [], (), ["every message lies before step 0"]),
        (MAP, [_extra_msg("/uav2/alt", 30, kind="scalar")], (), ["/uav2/alt", "step 30", "horizon of 20"]),
    ],
)
def test_map_mistakes_are_one_line(files, tmp_path, capsys, map_text, extra, skip, words):
    sc, mp, rec, csv, ys = files
    mp.write_text(map_text)
    write_recording(rec, ys, extra=extra, skip=skip)
    out = tmp_path / "est.mcap"
    rc, _, err = _run(capsys, "filter", sc, "--measurements", rec, "--map", mp, "--out", out)
    assert rc == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("teamkf: error: "), err
    for w in words:
        assert w in lines[0], (w, lines[0])
    assert not out.exists()


def test_other_encodings_are_refused(files, tmp_path, capsys):
    from mcap.writer import Writer as RawWriter

    sc, mp, rec, csv, ys = files
    with open(rec, "wb") as fh:
        w = RawWriter(fh)
        w.start()
        sid = w.register_schema("Point", "jsonschema", b"{}")
        for topic in ("/uav0/gps", "/uav0/range", "/uav1/gps", "/uav2/alt"):
            ch = w.register_channel(topic, "json", sid)
            w.add_message(ch, log_time=START, publish_time=START, data=b'{"x": 1}')
        w.finish()
    rc, _, err = _run(capsys, "filter", sc, "--measurements", rec, "--map", mp, "--out", tmp_path / "e.csv")
    assert rc == 2 and len(err.strip().splitlines()) == 1
    assert "'json'" in err and "ROS 2" in err
    (tmp_path / "junk.mcap").write_bytes(b"not an mcap file at all")
    rc, _, err = _run(capsys, "filter", sc, "--measurements", tmp_path / "junk.mcap", "--map", mp, "--out", tmp_path / "e.csv")
    assert rc == 2 and "not a readable MCAP file" in err and len(err.strip().splitlines()) == 1


def test_recording_needs_a_map_and_a_table_refuses_one(files, tmp_path, capsys):
    sc, mp, rec, csv, ys = files
    rc, _, err = _run(capsys, "filter", sc, "--measurements", rec, "--out", tmp_path / "e.csv")
    assert rc == 2 and "--map" in err
    rc, _, err = _run(capsys, "filter", sc, "--measurements", csv, "--map", mp, "--out", tmp_path / "e.csv")
    assert rc == 2 and "--map" in err and "drop it" in err


@pytest.mark.parametrize(
    "argv",
    [["filter", "SC", "--measurements", "REC", "--map", "MAP", "--out", "OUT"], ["measurements", "convert", "REC", "--map", "MAP", "--out", "OUT"]],
)
def test_without_the_extra_one_line_names_it(files, tmp_path, capsys, monkeypatch, argv):
    sc, mp, rec, csv, ys = files
    for mod in [m for m in sys.modules if m == "mcap" or m.startswith(("mcap.", "mcap_ros2"))]:
        monkeypatch.delitem(sys.modules, mod)
    monkeypatch.setitem(sys.modules, "mcap", None)
    monkeypatch.setitem(sys.modules, "mcap_ros2", None)
    subst = {"SC": sc, "REC": rec, "MAP": mp, "OUT": tmp_path / "out.csv"}
    rc, _, err = _run(capsys, *[subst.get(a, a) for a in argv])
    assert rc == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "pip install 'teamkf[ros]'" in lines[0], err


def test_convert_both_ways(files, tmp_path, capsys):
    sc, mp, rec, csv, ys = files
    rc, out, err = _run(capsys, "measurements", "convert", rec, "--map", mp, "--out", tmp_path / "a.csv")
    assert rc == 0, err
    assert (tmp_path / "a.csv").read_bytes() == csv.read_bytes()
    rc, out, err = _run(capsys, "measurements", "convert", tmp_path / "a.csv", "--map", mp, "--out", tmp_path / "b.mcap")
    assert rc == 0, err
    rc, out, err = _run(capsys, "measurements", "convert", tmp_path / "b.mcap", "--map", mp, "--out", tmp_path / "c.npz")
    assert rc == 0, err
    with np.load(tmp_path / "c.npz") as z:
        for i, y in enumerate(ys):
            np.testing.assert_array_equal(z[f"agent{i}"], y)
    rc, _, err = _run(capsys, "measurements", "convert", csv, "--map", mp, "--out", tmp_path / "d.csv")
    assert rc == 2 and "both table files" in err


def test_deploy_and_agent_read_the_recording(files, tmp_path, capsys):
    sc, mp, rec, csv, ys = files
    ys = [np.where(np.isnan(y), 0.5, y) for y in ys]  # deployed agents take no gaps
    write_recording(rec, ys)
    M.write_measurements(csv, ys)
    rc, _, err = _run(capsys, "deploy", sc, "--measurements", csv, "--transport", "queue", "--out", tmp_path / "ref.csv")
    assert rc == 0, err
    rc, _, err = _run(capsys, "deploy", sc, "--measurements", rec, "--map", mp, "--transport", "queue", "--out", tmp_path / "got.csv")
    assert rc == 0, err
    assert (tmp_path / "got.csv").read_bytes() == (tmp_path / "ref.csv").read_bytes()
    # the deployment's estimates as a recording: one topic per agent, the CSV's numbers bit for bit, stamped like filter's
    rc, _, err = _run(capsys, "deploy", sc, "--measurements", rec, "--map", mp, "--transport", "queue", "--out", tmp_path / "got.mcap")
    assert rc == 0, err
    import pandas as pd
    from mcap_ros2.reader import read_ros2_messages

    ref = pd.read_csv(tmp_path / "ref.csv")
    got: dict[str, list[tuple[int, list[float]]]] = {}
    for m in read_ros2_messages(str(tmp_path / "got.mcap")):
        got.setdefault(m.channel.topic, []).append((m.log_time_ns, list(m.ros_msg.data)))
    n = len(ys)
    assert sorted(got) == [f"/teamkf/{ref.estimator[0]}/agent{i}" for i in range(n)]
    zc = [c for c in ref.columns if c.startswith("z")]
    for i in range(n):
        want = ref[ref.agent == i][zc].to_numpy()
        have = np.array([v for _, v in got[f"/teamkf/{ref.estimator[0]}/agent{i}"]])
        assert have.tobytes() == want.tobytes()
    rc, _, err = _run(capsys, "deploy", sc, "--measurements", csv, "--transport", "queue", "--out", tmp_path / "nomap.mcap")
    assert rc == 2 and "--out" in err and "--map" in err  # a recording out needs the map's period, refused before the run
    # agent i reads only its own topics: a mistake in another agent's field does not stop it
    mp.write_text(MAP.replace('"point.y", "point.z"', '"point.y", "point.w"'))
    log = M.read_log(rec, _system(sc), 20, mp, agents=[0])
    np.testing.assert_array_equal(log.y[0], ys[0])
    assert not log.y[1].any() and log.n_steps == T  # not read: zeros


def _system(path):
    from teamkf.study.scenario import load_scenario

    return load_scenario(str(path)).system


@pytest.mark.slow  # ~6 s: three agent processes over Zenoh
@pytest.mark.skipif(importlib.util.find_spec("zenoh") is None, reason="needs eclipse-zenoh (pip install 'teamkf[deploy]')")
def test_deployed_agent_processes_read_their_own_topics(files, tmp_path, capsys):
    """teamkf deploy over Zenoh: each `teamkf agent --map` process reads its own topics of the recording; the same file as the CSV log."""
    sc, mp, rec, csv, ys = files
    ys = [np.where(np.isnan(y), 0.5, y) for y in ys]
    write_recording(rec, ys)
    M.write_measurements(csv, ys)
    rc, _, err = _run(
        capsys, "deploy", sc, "--measurements", csv, "--transport", "queue", "--out", tmp_path / "ref.csv"
    )  # the same numbers as Zenoh's
    assert rc == 0, err
    env = {**os.environ, "PYTHONPATH": f"{SRC}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"}
    argv = [sys.executable, "-m", "teamkf", "deploy", str(sc), "--measurements", str(rec), "--map", str(mp), "--out", str(tmp_path / "got.csv")]
    proc = subprocess.run([*argv, "--deadline", "10"], capture_output=True, text=True, env=env, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert (tmp_path / "got.csv").read_bytes() == (tmp_path / "ref.csv").read_bytes()
