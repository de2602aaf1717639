"""Dotted keys into scenario data: ``set_dotted(raw, "cost.lambda", 10.0)`` (sweeps, ``Scenario.updated``, CLI flags).

A leaf of the study layer: every scenario kind uses it, so it imports none of them.
"""

from __future__ import annotations

import copy
import re
from typing import Any, Mapping, Sequence

from .._validation import describe as _describe
from ..exceptions import ScenarioError
from .protocol import ScenarioBase

__all__ = ["set_dotted"]


_PART = re.compile(r"([^.\[\]]+)|\[(\d+)\]")


def _parse_path(key: str) -> list[str | int]:
    if not isinstance(key, str) or not key:
        raise ScenarioError(f"{key!r}: expected a dotted key such as 'cost.lambda'")
    parts: list[str | int] = []
    for seg in key.split("."):
        if not seg:
            raise ScenarioError(f"{key}: empty part in dotted key; write keys like 'cost.lambda' or 'agents[2].R'")
        got = "".join(m.group(0) for m in _PART.finditer(seg))
        if got != seg:
            raise ScenarioError(f"{key}: cannot parse the part {seg!r}; write keys like 'cost.lambda' or 'agents[2].R'")
        for m in _PART.finditer(seg):
            if m.group(1) is not None:
                parts.append(int(m.group(1)) if m.group(1).isdigit() else m.group(1))
            else:
                parts.append(int(m.group(2)))
    return parts


def set_dotted(d: Mapping[str, Any], key: str, value: Any) -> dict[str, Any]:
    """A deep copy of the scenario data ``d`` with the dotted ``key`` set to ``value``.

    ``key`` is a path of table keys separated by dots; list items are written
    ``agents[2].R`` (or ``agents.2.R``). Missing tables are created. The
    original is not modified, and the result is not validated (pass it to
    :func:`scenario_from_dict`).

    ``"graph.delay"`` on a graph given by explicit ``edges`` that share one delay
    sets the delay of every edge (a builder graph just gets its ``delay`` key).
    On edges with different delays it is refused: one delay would silently
    replace them (a scenario file refuses ``delay`` beside ``edges`` too); set
    ``graph.edges`` instead, or give the graph as a builder (``kind = "line"``, ...).

    Raises
    ------
    ScenarioError
        If the key cannot be set (no such list item, a key inside a number, ...),
        or is ``graph.delay`` on explicit edges with different delays.

    Examples
    --------
    >>> d = {"graph": {"kind": "line", "delay": 1}, "cost": {"kind": "platoon", "lambda": 1.0}}
    >>> set_dotted(d, "cost.lambda", 10.0)["cost"]
    {'kind': 'platoon', 'lambda': 10.0}
    >>> set_dotted({"graph": {"edges": [[0, 1, 1], [1, 0, 1]]}}, "graph.delay", 2)["graph"]
    {'edges': [[0, 1, 2], [1, 0, 2]]}
    """
    if isinstance(d, ScenarioBase):
        d = d.raw
    if not isinstance(d, Mapping):
        raise ScenarioError(f"{key}: expected scenario data (a table of keys), found {type(d).__name__}")
    out = copy.deepcopy(dict(d))
    parts = _parse_path(key)
    value = copy.deepcopy(value)
    graph = out.get("graph")
    if parts == ["graph", "delay"] and isinstance(graph, Mapping) and "edges" in graph and "kind" not in graph:
        edges = graph["edges"]
        if not isinstance(edges, list):
            raise ScenarioError(f"graph.edges: expected a list of [from, to, delay] triples, found {_describe(edges)}")
        delays = {repr(e[2]) for e in edges if isinstance(e, (list, tuple)) and len(e) == 3}
        if len(delays) > 1:
            raise ScenarioError(
                f"graph.delay: the graph has explicit edges with different delays ({', '.join(sorted(delays))}), which one delay "
                "would silently replace (a scenario file refuses delay beside edges); set graph.edges instead (a list of "
                '[from, to, delay]), or give the graph as a builder (kind = "line", ..., with delay)'
            )
        new_graph = dict(graph)
        new_graph["edges"] = [[*e[:2], value] if isinstance(e, (list, tuple)) and len(e) == 3 else e for e in edges]
        out["graph"] = new_graph
        return out
    node: Any = out
    for depth, p in enumerate(parts[:-1]):
        here = _path_str(parts[: depth + 1])
        nxt = parts[depth + 1]
        if isinstance(p, int):
            if not isinstance(node, list) or not -len(node) <= p < len(node):
                raise ScenarioError(f"{here}: no such item (found {_describe(node)})")
            child = node[p]
        else:
            if not isinstance(node, dict):
                raise ScenarioError(f"{here}: cannot set a key inside {_describe(node)}")
            if p not in node:
                node[p] = [] if isinstance(nxt, int) else {}
            child = node[p]
        if not isinstance(child, (dict, list)):
            raise ScenarioError(f"{here}: cannot set {key!r} inside {_describe(child)}")
        node = child
    last = parts[-1]
    if isinstance(last, int):
        if not isinstance(node, list) or not -len(node) <= last < len(node):
            raise ScenarioError(f"{key}: no such item (found {_describe(node)})")
        node[last] = value
    else:
        if not isinstance(node, dict):
            raise ScenarioError(f"{key}: cannot set a key inside {_describe(node)}")
        node[last] = value
    return out


def _path_str(parts: Sequence[str | int]) -> str:
    s = ""
    for p in parts:
        s += f"[{p}]" if isinstance(p, int) else (f".{p}" if s else p)
    return s
