r"""Measurements from a ROS 2 recording (MCAP): the topic map, and the reader.

A ROS 2 recording (``ros2 bag record``, whose default format is MCAP) holds many topics, each message with
its type's definition and its time. The **topic map** (a small TOML file, ``--map``) says which message fields
are whose measurement and how time becomes steps::

    period = 0.1              # seconds per step
    start = 1700000000.0      # time of step 0 in seconds (default: the first message used)

    [[topics]]
    topic = "/uav0/gps"       # a topic of the recording
    agent = 0                 # whose measurement it is
    fields = ["point.x", "point.y"]   # message fields, in order: y0, y1 of that agent

    [[truth]]                 # optional: the true state x(k), for --truth REC.mcap
    topic = "/sim/state"
    fields = ["data[0]", "data[1]"]

An agent may have several topics: their fields are concatenated in the map's order. A field is a dotted path
into the message (``pose.position.x``), with ``[i]`` for an element of an array (``data[2]``). The time t of a
message is its ``header.stamp`` where it has one, else its log time; it belongs to step
k = round((t - start) / period) (exactly half-way: the later step), computed in integer nanoseconds. A step
without a message is a missing measurement (NaN), as a gap in a CSV log; a NaN value is missing too. A
message before step 0 (earlier than start - period / 2) is not used. Each truth step takes the truth message
nearest to its time (within half a period); every step needs one.

Refused in one line (:class:`~teamkf.study.measurements.format.MeasurementFileError`): a map mistake (naming
the key or entry), two messages of a topic on one step, a field that is absent or not numeric, a topic not in
the recording, an agent whose fields do not add up to its d_y^i, a message encoding other than ROS 2 CDR with
a ``ros2msg`` schema. The libraries ``mcap`` and ``mcap-ros2-support`` (``pip install 'teamkf[ros]'``) are
imported only when an MCAP file is read or written.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from decimal import ROUND_HALF_EVEN, Decimal
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from ... import _validation as V
from ..._validation import FloatArray
from .format import MeasurementFileError, MeasurementLog, file_error

__all__ = [
    "TopicEntry",
    "TopicMap",
    "Recording",
    "read_map",
    "read_recording",
    "read_recorded_truth",
    "check_sizes",
    "read_log",
    "is_mcap",
    "require_ros",
    "ns_of_seconds",
]

_SEGMENT = re.compile(r"^([A-Za-z_][A-Za-z0-9_]*)((?:\[\d+\])*)$")


def require_ros() -> tuple[Any, Any]:
    """``(mcap, mcap_ros2)``, or one line naming the extra to install."""
    mcap = V.require("mcap", "ros")
    V.require("mcap.reader", "ros")
    ros2 = V.require("mcap_ros2", "ros")
    V.require("mcap_ros2.decoder", "ros")
    return mcap, ros2


def is_mcap(path: Any) -> bool:
    """Whether ``path`` names an MCAP file (by its ``.mcap`` extension)."""
    return isinstance(path, (str, Path)) and Path(path).suffix.lower() == ".mcap"


def ns_of_seconds(v: float) -> int:
    """Seconds (as written in the map) to integer nanoseconds, exactly for a decimal literal."""
    return int((Decimal(repr(float(v))) * 10**9).to_integral_value(ROUND_HALF_EVEN))


@dataclass(frozen=True)
class TopicEntry:
    """One ``[[topics]]`` (or ``[[truth]]``) entry of a map: a topic, whose it is, and its fields."""

    topic: str
    agent: int | None
    fields: tuple[str, ...]
    where: str  # "topics[2]": named in messages

    @property
    def paths(self) -> list[list[tuple[str, tuple[int, ...]]]]:
        """Each field as [(attribute, (index, ...)), ...]."""
        out = []
        for f in self.fields:
            segs = []
            for part in f.split("."):
                m = _SEGMENT.match(part)
                assert m is not None  # checked by read_map
                segs.append((m.group(1), tuple(int(v) for v in re.findall(r"\d+", m.group(2)))))
            out.append(segs)
        return out


@dataclass(frozen=True)
class TopicMap:
    """A validated topic map (see the module docstring)."""

    source: str
    period: float
    period_ns: int
    start: float | None
    start_ns: int | None
    topics: tuple[TopicEntry, ...]
    truth: tuple[TopicEntry, ...] = ()

    @property
    def n_agents(self) -> int:
        return max(e.agent for e in self.topics if e.agent is not None) + 1

    def sizes(self) -> list[int]:
        """The measurement size of each agent (the number of its fields, all its topics together)."""
        dy = [0] * self.n_agents
        for e in self.topics:
            dy[e.agent] += len(e.fields)  # type: ignore[index]
        return dy

    def of_agent(self, i: int) -> list[TopicEntry]:
        return [e for e in self.topics if e.agent == i]

    def time_of_step(self, start_ns: int, k: int) -> int:
        return start_ns + k * self.period_ns


def _map_error(path: Any, where: str, message: str) -> MeasurementFileError:
    e = file_error(path, where, message)
    e.argument = "--map"
    return e


def _entries(path: str, data: dict[str, Any], key: str, with_agent: bool) -> tuple[TopicEntry, ...]:
    raw = data.get(key, [])
    if not isinstance(raw, list) or not all(isinstance(t, dict) for t in raw):
        raise _map_error(path, key, f"expected [[{key}]] tables (topic, {'agent, ' if with_agent else ''}fields), found {V.describe(raw)}")
    allowed = ("topic", "agent", "fields") if with_agent else ("topic", "fields")
    out = []
    for j, t in enumerate(raw):
        where = f"{key}[{j}]"
        for k in t:
            if k not in allowed:
                raise _map_error(path, f"{where}.{k}", f"unknown key; expected {', '.join(allowed)}")
        for k in allowed:
            if k not in t:
                raise _map_error(path, where, f"missing key {k!r}; each [[{key}]] entry needs {', '.join(allowed)}")
        topic = t["topic"]
        if not isinstance(topic, str) or not topic.strip():
            raise _map_error(path, f"{where}.topic", f"expected a topic name like '/uav0/gps', found {V.describe(topic)}")
        where = f"{where} ({topic})"
        agent = None
        if with_agent:
            agent = t["agent"]
            if isinstance(agent, bool) or not isinstance(agent, int) or agent < 0:
                raise _map_error(path, f"{where}.agent", f"expected an agent id, an integer >= 0, found {V.describe(agent)}")
        fields = t["fields"]
        if not isinstance(fields, list) or not fields or not all(isinstance(f, str) for f in fields):
            raise _map_error(
                path, f"{where}.fields", f"expected a non-empty list of message fields like ['point.x', 'point.y'], found {V.describe(fields)}"
            )
        for f in fields:
            if not all(_SEGMENT.match(p) for p in f.split(".")):
                raise _map_error(
                    path,
                    f"{where}.fields",
                    f"{f!r} is not a field path; expected names joined by '.', with [i] for an array element (pose.position.x, data[2])",
                )
        out.append(TopicEntry(topic, agent, tuple(fields), where))
    return tuple(out)


def read_map(path: str | Path, flag: str = "--map") -> TopicMap:
    """Read and validate a topic map (TOML; see the module docstring).

    Raises
    ------
    MeasurementFileError
        One line naming the file and the key or entry that is wrong.
    FileNotFoundError
    """
    import tomllib

    p = Path(path)
    if not p.exists():
        raise FileNotFoundError(2, "No such file or directory", str(p))
    try:
        data = tomllib.loads(p.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise _map_error(p, "", f"not a valid TOML file ({exc})") from None
    src = str(p)
    for k in data:
        if k not in ("period", "start", "topics", "truth"):
            raise _map_error(src, k, "unknown key; expected period, start, [[topics]] and optionally [[truth]]")
    period = data.get("period")
    if period is None:
        raise _map_error(src, "period", "missing; give the seconds per step (period = 0.1)")
    if isinstance(period, bool) or not isinstance(period, (int, float)) or not math.isfinite(period) or period <= 0:
        raise _map_error(src, "period", f"expected a number of seconds > 0, found {V.describe(period)}")
    period_ns = ns_of_seconds(period)
    if period_ns < 1:
        raise _map_error(src, "period", f"expected at least one nanosecond, found {period!r}")
    start = data.get("start")
    if start is not None and (isinstance(start, bool) or not isinstance(start, (int, float)) or not math.isfinite(start)):
        raise _map_error(src, "start", f"expected the time of step 0 in seconds (a number), found {V.describe(start)}")
    topics = _entries(src, data, "topics", True)
    if not topics:
        raise _map_error(src, "topics", "no [[topics]] entry; give at least one (topic, agent, fields)")
    truth = _entries(src, data, "truth", False)
    tm = TopicMap(
        src, float(period), period_ns, None if start is None else float(start), None if start is None else ns_of_seconds(start), topics, truth
    )
    for i, size in enumerate(tm.sizes()):
        if size == 0:
            raise _map_error(src, "topics", f"agent {i} has no [[topics]] entry (agents are numbered 0..{tm.n_agents - 1}); give its topics")
    return tm


@dataclass(frozen=True, eq=False)
class Recording:
    """What a recording gives through a map: per-agent measurements (NaN = missing) and the time of step 0 (ns)."""

    y: list[FloatArray]
    start_ns: int
    period_ns: int

    @property
    def n_steps(self) -> int:
        return int(self.y[0].shape[0])


def _stamp(msg: Any) -> int | None:
    h = getattr(msg, "header", None)
    s = getattr(h, "stamp", None)
    if s is None:
        return None
    sec, nsec = getattr(s, "sec", None), getattr(s, "nanosec", None)
    if isinstance(sec, int) and isinstance(nsec, int):
        return sec * 1_000_000_000 + nsec
    return None


class _Absent(Exception):
    """A field path that does not lead to a value (the message says what is missing)."""


def _field(msg: Any, segs: list[tuple[str, tuple[int, ...]]]) -> Any:
    v = msg
    for name, idx in segs:
        if isinstance(v, dict) and name in v:
            v = v[name]
        elif not isinstance(v, dict) and hasattr(v, "__dict__") and hasattr(v, name):
            v = getattr(v, name)
        else:
            raise _Absent(f"no {name!r}; its fields: {_fields_of(v)}")
        for i in idx:
            if isinstance(v, (str, bytes)) or not hasattr(v, "__len__"):
                raise _Absent(f"{name!r} is {_kind(v)}, not an array; drop the [{i}]")
            if i >= len(v):
                raise _Absent(f"no element [{i}] of {name!r} (it has {len(v)})")
            v = v[i]
    return v


def _kind(v: Any) -> str:
    if hasattr(v, "__dict__"):
        return f"a message ({type(v).__name__})"
    if isinstance(v, (bool, np.bool_)):
        return "a boolean"
    if isinstance(v, (int, float, np.integer, np.floating)):
        return "a number"
    if isinstance(v, str):
        return f"the text {v[:40]!r}"
    if hasattr(v, "__len__"):
        return f"an array of {len(v)} values"
    return type(v).__name__


def _fields_of(v: Any) -> str:
    names = list(v) if isinstance(v, dict) else [k for k in vars(v) if not k.startswith("_")] if hasattr(v, "__dict__") else []
    return ", ".join(names) or "none (it is not a message)"


def _value(src: str, e: TopicEntry, f: str, segs: Any, msg: Any, k: int, type_name: str) -> float:
    try:
        v = _field(msg, segs)
    except _Absent as exc:
        raise _map_error(src, f"{e.where}, field {f!r}", f"absent in {type_name} (at step {k}): {exc}") from None
    if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, float, np.integer, np.floating)):
        raise _map_error(src, f"{e.where}, field {f!r}", f"expected a number, found {_kind(v)} in {type_name} at step {k}; name a numeric field")
    x = float(v)
    if math.isinf(x):
        raise _map_error(src, f"{e.where}, field {f!r}", f"expected a finite number or NaN (missing), found {x} at step {k}")
    return x


def _scan(path: Path, wanted: set[str]) -> tuple[dict[str, list[tuple[int, Any]]], dict[str, str]]:
    """Every message of the wanted topics, decoded: topic -> [(time ns, message)], and topic -> type name."""
    require_ros()
    from mcap.exceptions import McapError
    from mcap.reader import NonSeekingReader
    from mcap_ros2.decoder import DecoderFactory

    factory = DecoderFactory()
    msgs: dict[str, list[tuple[int, Any]]] = {t: [] for t in wanted}
    types: dict[str, str] = {}
    decoders: dict[int, Any] = {}
    try:
        with open(path, "rb") as fh:
            for schema, channel, message in NonSeekingReader(fh).iter_messages():
                topic = channel.topic
                if topic not in wanted:
                    continue
                if channel.id not in decoders:
                    enc = schema.encoding if schema is not None else "no schema"
                    if channel.message_encoding != "cdr" or schema is None or schema.encoding != "ros2msg":
                        raise file_error(
                            path,
                            f"topic {topic!r}",
                            f"message encoding {channel.message_encoding!r} with schema encoding {enc!r} is not read; "
                            "teamkf reads ROS 2 messages (CDR with a ros2msg schema, as ros2 bag record writes)",
                        )
                    try:
                        decoders[channel.id] = factory.decoder_for(channel.message_encoding, schema)
                    except Exception as exc:  # a definition the vendored ROS parser refuses
                        raise file_error(
                            path, f"topic {topic!r}", f"cannot read the definition of {schema.name!r} ({' '.join(str(exc).split())})"
                        ) from None
                    types[topic] = schema.name
                try:
                    msg = decoders[channel.id](message.data)
                except Exception as exc:
                    raise file_error(
                        path,
                        f"topic {topic!r}",
                        f"a message at log time {message.log_time} ns does not decode as {types[topic]} ({type(exc).__name__})",
                    ) from None
                t = _stamp(msg)
                msgs[topic].append((message.log_time if t is None else t, msg))
    except McapError as exc:
        raise file_error(path, "", f"not a readable MCAP file ({type(exc).__name__}: {' '.join(str(exc).split())[:200]})") from None
    except (EOFError, ValueError, OSError) as exc:
        if isinstance(exc, MeasurementFileError):
            raise
        raise file_error(path, "", f"not a readable MCAP file ({type(exc).__name__}: {' '.join(str(exc).split())[:200]})") from None
    return msgs, types


def _step(t: int, start_ns: int, period_ns: int) -> int:
    """round((t - start) / period), exactly half-way to the later step, in integers."""
    return (2 * (t - start_ns) + period_ns) // (2 * period_ns)


def read_recording(path: str | Path, tmap: TopicMap, *, agents: Sequence[int] | None = None, horizon: int | None = None) -> Recording:
    """The per-agent measurements (and, with ``truth``, the true states) of an MCAP recording through ``tmap``.

    Parameters
    ----------
    path : the recording (.mcap)
    tmap : the topic map (:func:`read_map`)
    agents : read the values of these agents' topics only (the others' are NaN); the times of every
        measurement topic still set step 0 (when the map has no ``start``) and the number of steps, so
        every agent agrees on them
    horizon : steps must be < horizon (None: any)
    """
    p = Path(path)
    if not p.exists():
        raise FileNotFoundError(2, "No such file or directory", str(p))
    wanted = {e.topic for e in tmap.topics}
    msgs, types = _scan(p, wanted)
    for e in tmap.topics:
        if not msgs[e.topic]:
            raise _map_error(
                tmap.source,
                e.where,
                f"topic {e.topic!r} has no message in the recording {str(p)!r}; its topics: {', '.join(sorted(_topics(p))) or 'none'}",
            )
    times = [t for e in tmap.topics for t, _ in msgs[e.topic]]
    start = tmap.start_ns if tmap.start_ns is not None else min(times)
    P = tmap.period_ns
    steps = {e.topic: [_step(t, start, P) for t, _ in msgs[e.topic]] for e in tmap.topics}
    last = max(max(s) for s in steps.values())
    if last < 0:
        raise _map_error(
            tmap.source, "start", f"every message lies before step 0 (start = {tmap.start}); set start to the recording's time or omit it"
        )
    T = last + 1
    if horizon is not None and T > horizon:
        e = next(e for e in tmap.topics if max(steps[e.topic]) == last)
        raise file_error(
            p,
            f"topic {e.topic!r}, step {last}",
            f"beyond the scenario's horizon of {horizon} steps (steps 0..{horizon - 1}); raise horizon or crop the recording",
        )
    keep = None if agents is None else set(agents)
    dy = tmap.sizes()
    ys = [np.full((T, dy[i]), np.nan) for i in range(len(dy))]
    col = [0] * len(dy)
    for e in tmap.topics:
        i = e.agent
        assert i is not None
        c0 = col[i]
        col[i] += len(e.fields)
        if keep is not None and i not in keep:
            continue
        seen: dict[int, int] = {}
        paths = e.paths
        for (t, msg), k in zip(msgs[e.topic], steps[e.topic]):
            if k < 0:
                continue
            if k in seen:
                raise file_error(
                    p,
                    f"topic {e.topic!r}, step {k}",
                    f"two messages on one step (times {seen[k]} and {t} ns, period {P} ns); keep one, or shorten period",
                )
            seen[k] = t
            ys[i][k, c0 : c0 + len(e.fields)] = [_value(tmap.source, e, f, segs, msg, k, types[e.topic]) for f, segs in zip(e.fields, paths)]
    return Recording(ys, start, P)


def read_recorded_truth(path: str | Path, tmap: TopicMap, start_ns: int, n_steps: int) -> FloatArray:
    """The true states x(0..n_steps-1) from the map's ``[[truth]]`` topics of a recording (step 0 at ``start_ns``)."""
    p = Path(path)
    if not p.exists():
        raise FileNotFoundError(2, "No such file or directory", str(p))
    if not tmap.truth:
        raise _map_error(tmap.source, "truth", "no [[truth]] entry; --truth with a recording needs the truth topics (topic, fields) in the map")
    msgs, types = _scan(p, {e.topic for e in tmap.truth})
    for e in tmap.truth:
        if not msgs[e.topic]:
            raise _map_error(
                tmap.source,
                e.where,
                f"topic {e.topic!r} has no message in the recording {str(p)!r}; its topics: {', '.join(sorted(_topics(p))) or 'none'}",
            )
    return _truth(p, tmap, msgs, types, start_ns, n_steps)


def _topics(path: Path) -> set[str]:
    from mcap.reader import make_reader

    try:
        with open(path, "rb") as fh:
            summary = make_reader(fh).get_summary()
        if summary is not None:
            return {c.topic for c in summary.channels.values()}
        from mcap.reader import NonSeekingReader

        with open(path, "rb") as fh:
            return {ch.topic for _, ch, _ in NonSeekingReader(fh).iter_messages()}
    except Exception:  # only for the message
        return set()


def _truth(p: Path, tmap: TopicMap, msgs: dict[str, Any], types: dict[str, str], start: int, T: int) -> FloatArray:
    """Per step, the truth message nearest in time (within half a period); every step needs one."""
    cols = []
    P = tmap.period_ns
    for e in tmap.truth:
        best: list[tuple[int, Any] | None] = [None] * T
        for t, msg in msgs[e.topic]:
            k = _step(t, start, P)
            if 0 <= k < T:
                d = abs(t - (start + k * P))
                if best[k] is None or d < best[k][0]:  # type: ignore[index]
                    best[k] = (d, msg)
        gone = [k for k in range(T) if best[k] is None]
        if gone:
            raise file_error(
                p,
                f"topic {e.topic!r}, step {gone[0]}",
                f"no truth message within half a period of step {gone[0]}; the truth needs every step 0..{T - 1}",
            )
        paths = e.paths
        cols.append(np.array([[_value(tmap.source, e, f, s, b[1], k, types[e.topic]) for f, s in zip(e.fields, paths)] for k, b in enumerate(best)]))  # type: ignore[index]
    x = np.concatenate(cols, axis=1)
    bad = np.argwhere(np.isnan(x))
    if bad.size:
        raise file_error(p, f"truth step {int(bad[0][0])}", "expected a number, found NaN; the truth cannot be missing")
    return x


def check_sizes(tmap: TopicMap, system: Any) -> None:
    """The map gives every agent of the scenario exactly d_y^i fields."""
    n = system.n_agents
    if tmap.n_agents > n:
        e = next(e for e in tmap.topics if e.agent is not None and e.agent >= n)
        raise _map_error(tmap.source, f"{e.where}.agent", f"agent {e.agent} is out of range: the scenario has {n} agents (0..{n - 1})")
    sizes = tmap.sizes() + [0] * (n - tmap.n_agents)
    for i, (got, want) in enumerate(zip(sizes, system.dy)):
        if got != want:
            names = ", ".join(f"{e.topic} ({len(e.fields)})" for e in tmap.of_agent(i)) or "no topic"
            raise _map_error(
                tmap.source,
                f"agent {i}",
                f"its fields add up to {got} ({names}) but its measurement has d_y^{i} = {want} values; list {want} fields over its topics",
            )


def read_log(
    path: str | Path,
    system: Any,
    horizon: int | None,
    map_path: str | Path | None,
    *,
    agents: Sequence[int] | None = None,
    flag: str = "--measurements",
) -> MeasurementLog:
    """A recorded log: an MCAP recording through the map ``map_path``, or any file :func:`read_measurements` reads.

    ``agents``: with a recording, read the values of these agents' topics only (``teamkf agent``); the others'
    measurements are zeros in the log returned (placeholders: an agent uses only its own)."""
    from .format import read_measurements

    if not is_mcap(path):
        if map_path is not None:
            raise MeasurementFileError(
                f"--map: a topic map is for a ROS 2 recording (.mcap), found --measurements {path}; drop --map", argument="--map"
            )
        return read_measurements(path, system, horizon)
    require_ros()
    if map_path is None:
        raise MeasurementFileError(
            f"--map: {path} is an MCAP recording; give a topic map (--map MAP.toml: period, [[topics]] topic, agent, fields)", argument="--map"
        )
    tmap = read_map(map_path)
    check_sizes(tmap, system)
    rec = read_recording(path, tmap, agents=agents, horizon=horizon)
    ys = rec.y if agents is None else [y if i in agents else np.zeros_like(y) for i, y in enumerate(rec.y)]  # not read: placeholders, never used
    import dataclasses

    return dataclasses.replace(MeasurementLog.from_arrays(ys, system, horizon, source=str(path)), start_ns=rec.start_ns)
