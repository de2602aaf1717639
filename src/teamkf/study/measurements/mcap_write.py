r"""Writing MCAP: estimates beside a recording (``teamkf filter --out est.mcap``), measurements (the converter).

Estimates: one topic per estimator and agent, ``/teamkf/<estimator>/agent<i>``, of type
``std_msgs/msg/Float64MultiArray`` (``data`` = z_i(k), d_z values), log time = start + k·period; with a truth,
``/teamkf/truth`` (x(k), the same type) and the realized team cost of each estimator,
``/teamkf/<estimator>/cost`` (``std_msgs/msg/Float64``). The values are the float64 numbers of the CSV output,
bit for bit. Foxglove and ``ros2 bag play`` open the file beside the recording.

Measurements (``teamkf measurements convert log.csv --map MAP --out rec.mcap``): one topic per ``[[topics]]``
entry of the map, of a message type made from its fields (``teamkf_msgs/msg/Topic<j>``: a ``std_msgs/Header``
whose stamp is start + k·period, and the fields as float64, nested as their dotted paths say), so the same map
reads the file back; a step where all the topic's fields are missing has no message.
"""

from __future__ import annotations

import re
from typing import Any, Mapping, Sequence

import numpy as np

from ..._validation import FloatArray
from .format import MeasurementFileError
from .mcap_source import TopicMap, require_ros

__all__ = ["FLOAT64_MULTI_ARRAY", "write_estimates_mcap", "write_measurements_mcap", "estimate_topic"]

_SEP = "=" * 80
FLOAT64_MULTI_ARRAY = "\n".join(
    [
        "MultiArrayLayout layout",
        "float64[] data",
        _SEP,
        "MSG: std_msgs/MultiArrayLayout",
        "MultiArrayDimension[] dim",
        "uint32 data_offset",
        _SEP,
        "MSG: std_msgs/MultiArrayDimension",
        "string label",
        "uint32 size",
        "uint32 stride",
    ]
)
_FLOAT64 = "float64 data"
_HEADER = "\n".join(
    [
        _SEP,
        "MSG: std_msgs/Header",
        "builtin_interfaces/Time stamp",
        "string frame_id",
        _SEP,
        "MSG: builtin_interfaces/Time",
        "int32 sec",
        "uint32 nanosec",
    ]
)


def estimate_topic(estimator: str, i: int) -> str:
    """The topic of estimator ``estimator``'s estimates of agent ``i``."""
    return f"/teamkf/{estimator}/agent{i}"


def _array(values: FloatArray, label: str) -> dict[str, Any]:
    n = len(values)
    return {"layout": {"dim": [{"label": label, "size": n, "stride": n}], "data_offset": 0}, "data": [float(v) for v in values]}


def _writer(fh: Any) -> Any:
    require_ros()
    from mcap_ros2.writer import Writer

    return Writer(fh)


def write_estimates_mcap(
    fh: Any,
    estimates: Mapping[str, FloatArray],
    n_agents: int,
    *,
    start_ns: int,
    period_ns: int,
    truth: FloatArray | None = None,
    costs: Mapping[str, FloatArray] | None = None,
) -> None:
    """Write estimates name -> (n_steps, n_agents d_z) into the binary file ``fh`` as MCAP (see the module docstring)."""
    w = _writer(fh)
    arr = w.register_msgdef("std_msgs/msg/Float64MultiArray", FLOAT64_MULTI_ARRAY)
    one = w.register_msgdef("std_msgs/msg/Float64", _FLOAT64) if costs else None
    T = next(iter(estimates.values())).shape[0]
    for k in range(T):  # in time order, as a recorder writes
        t = start_ns + k * period_ns
        for name, z in estimates.items():
            dz = z.shape[1] // n_agents
            for i in range(n_agents):
                w.write_message(estimate_topic(name, i), arr, _array(z[k, i * dz : (i + 1) * dz], "z"), log_time=t, publish_time=t, sequence=k)
        if truth is not None:
            w.write_message("/teamkf/truth", arr, _array(truth[k], "x"), log_time=t, publish_time=t, sequence=k)
        for name, c in (costs or {}).items():
            w.write_message(f"/teamkf/{name}/cost", one, {"data": float(c[k])}, log_time=t, publish_time=t, sequence=k)
    w.finish()


def _msgdef(j: int, fields: Sequence[str]) -> tuple[str, str]:
    """(type name, definition text) of a message holding ``fields`` (dotted paths, [i] for array elements) and a header."""
    tree: dict[str, Any] = {}
    for f in fields:
        node = tree
        parts = f.split(".")
        for q, part in enumerate(parts):
            m = re.match(r"^([A-Za-z_][A-Za-z0-9_]*)((?:\[\d+\])*)$", part)
            assert m is not None
            name, idx = m.group(1), [int(v) for v in re.findall(r"\d+", m.group(2))]
            if len(idx) > 1 or (q == 0 and name == "header"):
                raise MeasurementFileError(
                    f"field {f!r}: cannot be written as a ROS 2 message (nested arrays, or a field of the header)", argument="--map"
                )
            leaf = q == len(parts) - 1
            slot = node.setdefault(name, {"leaf": leaf, "array": bool(idx), "len": 0, "children": {}})
            if slot["leaf"] != leaf or slot["array"] != bool(idx):
                raise MeasurementFileError(f"field {f!r}: {name!r} is used both as a number and as a message (or array) in the map", argument="--map")
            if idx:
                slot["len"] = max(slot["len"], idx[0] + 1)
            node = slot["children"]
    root = f"Topic{j}"
    defs: list[tuple[str, list[str]]] = []

    def emit(type_name: str, node: dict[str, Any]) -> None:
        lines = []
        for name, slot in node.items():
            if slot["leaf"]:
                lines.append(f"float64{'[]' if slot['array'] else ''} {name}")
            else:
                sub = f"{type_name}{name.title().replace('_', '')}"
                lines.append(f"teamkf_msgs/{sub}{'[]' if slot['array'] else ''} {name}")
                emit(sub, slot["children"])
        defs.append((type_name, lines))

    emit(root, tree)
    main = ["std_msgs/Header header", *defs[-1][1]]
    text = "\n".join(main + [line for name, lines in defs[:-1] for line in [_SEP, f"MSG: teamkf_msgs/{name}", *lines]]) + "\n" + _HEADER
    return f"teamkf_msgs/msg/{root}", text


def _message(fields: Sequence[str], values: Any, stamp_ns: int) -> dict[str, Any]:
    msg: dict[str, Any] = {"header": {"stamp": {"sec": stamp_ns // 1_000_000_000, "nanosec": stamp_ns % 1_000_000_000}, "frame_id": ""}}
    for f, v in zip(fields, values):
        node: Any = msg
        parts = f.split(".")
        for q, part in enumerate(parts):
            name = part.split("[")[0]
            idx = [int(x) for x in re.findall(r"\d+", part[len(name) :])]
            leaf = q == len(parts) - 1
            if idx:
                arr = node.setdefault(name, [])
                while len(arr) <= idx[0]:
                    arr.append(float("nan") if leaf else {})
                if leaf:
                    arr[idx[0]] = float(v)
                else:
                    node = arr[idx[0]]
            elif leaf:
                node[name] = float(v)
            else:
                node = node.setdefault(name, {})
    return msg


def write_measurements_mcap(fh: Any, ys: Sequence[FloatArray], tmap: TopicMap, start_ns: int) -> None:
    """Write per-agent measurements (n_steps, d_y^i) (NaN = missing) as a ROS 2 recording with the map's topics."""
    w = _writer(fh)
    schemas = []
    for j, e in enumerate(tmap.topics):
        name, text = _msgdef(j, e.fields)
        schemas.append(w.register_msgdef(name, text))
    col = [0] * len(ys)
    spans = []
    for e in tmap.topics:
        i = e.agent
        assert i is not None
        spans.append((i, col[i], col[i] + len(e.fields)))
        col[i] += len(e.fields)
    T = ys[0].shape[0]
    for k in range(T):
        t = start_ns + k * tmap.period_ns
        for j, e in enumerate(tmap.topics):
            i, a, b = spans[j]
            vals = ys[i][k, a:b]
            if np.isnan(vals).all():
                continue  # a missing measurement: no message
            w.write_message(e.topic, schemas[j], _message(e.fields, vals, t), log_time=t, publish_time=t, sequence=k)
    w.finish()
