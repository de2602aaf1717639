"""What an in-neighbour's payload may look like: a structure learned offline from the design, checked on every frame.

An agent fuses only payloads of the structure its in-neighbour's own design sends. Every agent
holds the team's design (the same on every machine), so before the run it steps the whole team
in-process for a few steps on zero measurements (once with every message delivered, once with
every other message lost, so that the loss-tolerant step's payloads are seen too) and records,
per sender, the structure of every payload it sent: :class:`PayloadSpec`. A frame whose
payload (authenticated, decoded) does not match — another type, an array of another dtype or
shape, a non-finite value, a record of another class, a dict with other keys — is refused and
counted (``bad_payload``); it never reaches the family's step, so it cannot crash the agent.
The learned byte size of the payloads also bounds the size of a frame (:func:`frame_limit`).

The structure is a union of alternatives at every level: arrays by (dtype, shape), scalars by
type, tuples and records position by position, dicts key by key, lists by the union of their
items (a relay's list of packets (j, s, y_j(s)) varies in length, never in item structure).
"""

from __future__ import annotations

import dataclasses
from typing import Any, Sequence

import numpy as np

from .codec import decode_payload, encode_payload

__all__ = ["PayloadSpec", "learn_payloads", "frame_limit", "CONTROL_LIMIT", "specs_to_json", "specs_from_json"]

#: the largest hello or goodbye frame an agent accepts (its payload lists at most the team's agent ids)
CONTROL_LIMIT = 64 * 1024
#: a data frame may be this many times the largest payload the sender's design produced, plus SLACK bytes
FACTOR, SLACK = 4, 4096
#: no frame is ever larger than this, whatever the design
HARD_LIMIT = 16 * 1024 * 1024


def _leaf(x: Any) -> str | None:
    if x is None:
        return "None"
    if isinstance(x, bool):
        return "bool"
    if isinstance(x, int):
        return "int"
    if isinstance(x, float):
        return "float"
    if isinstance(x, str):
        return "str"
    if isinstance(x, np.generic):
        return f"numpy {x.dtype}"
    return None


def _record_class(x: Any) -> type | None:
    if isinstance(x, tuple) and hasattr(x, "_fields"):
        return type(x)
    if dataclasses.is_dataclass(x) and not isinstance(x, type):
        return type(x)
    return None


def _fields(x: Any) -> tuple:
    if isinstance(x, tuple):
        return tuple(x)
    return tuple(getattr(x, f.name) for f in dataclasses.fields(x))


def _finite(x: Any) -> bool:
    if isinstance(x, float):
        return x == x and x not in (float("inf"), float("-inf"))
    a = np.asarray(x)
    return a.dtype.kind not in "fc" or bool(np.isfinite(a).all())


class PayloadSpec:
    """A union of payload structures (see the module docstring): :meth:`add` an example, :meth:`why` a payload."""

    def __init__(self) -> None:
        self.leaves: set[str] = set()
        self.arrays: set[tuple[str, tuple[int, ...]]] = set()
        self.tuples: dict[int, list[PayloadSpec]] = {}
        self.records: dict[type, list[PayloadSpec]] = {}
        self.dicts: dict[frozenset, dict[Any, PayloadSpec]] = {}
        self.items: PayloadSpec | None = None  # a list: the union of its items

    def add(self, x: Any) -> None:
        """Widen the union with the structure of ``x`` (a payload the design sent)."""
        leaf = _leaf(x)
        if leaf is not None:
            self.leaves.add(leaf)
        elif isinstance(x, np.ndarray):
            self.arrays.add((x.dtype.str, tuple(x.shape)))
        elif (cls := _record_class(x)) is not None:
            self._positions(self.records.setdefault(cls, []), _fields(x))
        elif isinstance(x, tuple):
            self._positions(self.tuples.setdefault(len(x), []), x)
        elif isinstance(x, list):
            self.items = self.items or PayloadSpec()
            for v in x:
                self.items.add(v)
        elif isinstance(x, dict):
            slots = self.dicts.setdefault(frozenset(x), {})
            for k, v in x.items():
                slots.setdefault(k, PayloadSpec()).add(v)
        else:  # nothing the codec decodes; keep the spec closed
            self.leaves.add(f"object {type(x).__name__}")

    @staticmethod
    def _positions(slots: list["PayloadSpec"], values: Sequence[Any]) -> None:
        while len(slots) < len(values):
            slots.append(PayloadSpec())
        for s, v in zip(slots, values):
            s.add(v)

    def why(self, x: Any, where: str = "payload") -> str | None:
        """None when ``x`` matches, else what does not (one phrase, naming the position)."""
        leaf = _leaf(x)
        if leaf is not None:
            if leaf not in self.leaves:
                return f"{where}: a {leaf} where the design sends {self._expected()}"
            if not _finite(x):
                return f"{where}: a non-finite value ({x})"
            return None
        if isinstance(x, np.ndarray):
            if (x.dtype.str, tuple(x.shape)) not in self.arrays:
                return f"{where}: an array {x.dtype} of shape {tuple(x.shape)} where the design sends {self._expected()}"
            if not _finite(x):
                return f"{where}: an array with non-finite values"
            return None
        cls = _record_class(x)
        if cls is not None:
            slots = self.records.get(cls)
            vals = _fields(x)
            if slots is None or len(slots) != len(vals):
                return f"{where}: a {cls.__qualname__} where the design sends {self._expected()}"
            return self._check_positions(slots, vals, where)
        if isinstance(x, tuple):
            slots = self.tuples.get(len(x))
            if slots is None:
                return f"{where}: a tuple of {len(x)} where the design sends {self._expected()}"
            return self._check_positions(slots, x, where)
        if isinstance(x, list):
            if self.items is None:
                return f"{where}: a list where the design sends {self._expected()}"
            for q, v in enumerate(x):
                why = self.items.why(v, f"{where}[{q}]")
                if why:
                    return why
            return None
        if isinstance(x, dict):
            slots_d = self.dicts.get(frozenset(x)) if all(_hashable(k) for k in x) else None
            if slots_d is None:
                return f"{where}: a dict with keys {sorted(map(repr, x))[:6]} where the design sends {self._expected()}"
            for k, v in x.items():
                why = slots_d[k].why(v, f"{where}[{k!r}]")
                if why:
                    return why
            return None
        return f"{where}: a {type(x).__name__}"

    @staticmethod
    def _check_positions(slots: Sequence["PayloadSpec"], values: Sequence[Any], where: str) -> str | None:
        for q, (s, v) in enumerate(zip(slots, values)):
            why = s.why(v, f"{where}[{q}]")
            if why:
                return why
        return None

    def _expected(self) -> str:
        kinds = sorted(self.leaves) + [f"array {np.dtype(d)} {s}" for d, s in sorted(self.arrays)]
        kinds += [f"tuple of {n}" for n in sorted(self.tuples)] + [c.__qualname__ for c in self.records]
        kinds += ["a list"] * (self.items is not None) + [f"dict {sorted(map(repr, k))[:6]}" for k in self.dicts]
        return " or ".join(kinds[:4]) or "nothing"


def _spec_json(spec: PayloadSpec) -> dict[str, Any]:
    out: dict[str, Any] = {"leaves": sorted(spec.leaves), "arrays": [[d, list(shape)] for d, shape in sorted(spec.arrays)]}
    out["tuples"] = [[n, [_spec_json(x) for x in slots]] for n, slots in sorted(spec.tuples.items())]
    out["records"] = [[f"{c.__module__}:{c.__qualname__}", [_spec_json(x) for x in slots]] for c, slots in spec.records.items()]
    out["dicts"] = [[[k, _spec_json(v)] for k, v in slots.items()] for slots in spec.dicts.values()]
    out["items"] = None if spec.items is None else _spec_json(spec.items)
    return out


def _record_type(name: str) -> type:
    """A NamedTuple or dataclass named ``module:QualName`` of a loaded module (a teamkf module is imported; nothing else is)."""
    import importlib
    import sys

    mod_name, _, qual = name.partition(":")
    obj: Any = sys.modules.get(mod_name)
    if obj is None and (mod_name == "teamkf" or mod_name.startswith("teamkf.")):
        obj = importlib.import_module(mod_name)
    for part in qual.split("."):
        obj = getattr(obj, part, None)
    if not isinstance(obj, type) or not ((issubclass(obj, tuple) and hasattr(obj, "_fields")) or dataclasses.is_dataclass(obj)):
        raise ValueError(f"record type {name} is not a NamedTuple or a dataclass of a loaded module")
    return obj


def _spec_from(d: Any) -> PayloadSpec:
    spec = PayloadSpec()
    spec.leaves = {str(x) for x in d["leaves"]}
    spec.arrays = {(str(dt), tuple(int(v) for v in shape)) for dt, shape in d["arrays"]}
    spec.tuples = {int(n): [_spec_from(x) for x in slots] for n, slots in d["tuples"]}
    spec.records = {_record_type(str(name)): [_spec_from(x) for x in slots] for name, slots in d["records"]}
    for slots in d["dicts"]:
        keys = [k for k, _ in slots]
        spec.dicts[frozenset(keys)] = {k: _spec_from(v) for k, v in slots}
    spec.items = None if d["items"] is None else _spec_from(d["items"])
    return spec


def specs_to_json(specs: dict[int, PayloadSpec], sizes: dict[int, int]) -> dict[str, Any]:
    """The payload structures and largest sizes per sender (:func:`learn_payloads`) as JSON data, for an agent's slice file."""
    return {str(j): {"spec": _spec_json(specs[j]), "size": int(sizes[j])} for j in specs}


def specs_from_json(data: Any) -> tuple[dict[int, PayloadSpec], dict[int, int]]:
    """The inverse of :func:`specs_to_json`; raises ValueError (or KeyError, TypeError) on anything else."""
    specs = {int(j): _spec_from(v["spec"]) for j, v in data.items()}
    sizes = {int(j): int(v["size"]) for j, v in data.items()}
    return specs, sizes


def _hashable(k: Any) -> bool:
    try:
        hash(k)
    except TypeError:
        return False
    return True


def set_tolerant(agent: Any) -> bool:
    """Switch an online agent (or the agent it wraps) to its loss-tolerant step; False when it has none."""
    ok = False
    for obj in (agent, getattr(agent, "inner", None)):
        if obj is not None and hasattr(obj, "tolerant"):
            obj.tolerant = True
            ok = True
    return ok


def learn_payloads(design: Any, graph: Any, n_steps: int | None = None) -> tuple[dict[int, PayloadSpec], dict[int, int]]:
    """Per sender: the structure of its payloads and their largest encoded size (bytes), from an offline team run.

    The team is stepped in-process on zero measurements for ``n_steps`` steps (default: enough for every
    measurement to reach every agent, n x the largest delay + 3), once with every message delivered and once
    with every other message lost (the loss-tolerant step's payloads). Raises what the family's step raises.
    """
    n = graph.n_agents
    max_delay = max((d for (_, _, d) in graph.edges), default=1)
    m = n_steps if n_steps is not None else n * max_delay + 3
    if design.horizon is not None:
        m = min(m, int(design.horizon))
    dy = [int(v) for v in design.system.dy]
    ins = [[(j, graph.delay(j, i)) for j in graph.in_neighbors(i)] for i in range(n)]
    specs = {j: PayloadSpec() for j in range(n)}
    sizes = dict.fromkeys(range(n), 0)
    for lossy in (False, True):
        agents = design.graph_agents()
        for a in agents:
            set_tolerant(a)
        states = [a.init_state(1) for a in agents]
        sent: list[dict[int, Any]] = [{} for _ in range(n)]
        for k in range(m):
            out = []
            for i, a in enumerate(agents):
                inbox = [
                    (j, k - d, sent[j][k - d])
                    for (j, d) in ins[i]
                    if k - d >= 0 and sent[j].get(k - d) is not None and not (lossy and (k + i + j) % 2)
                ]
                states[i], _, payload = a.step(states[i], k, np.zeros((1, dy[i])), inbox)
                out.append(payload)
            for i, p in enumerate(out):
                sent[i][k] = p
                if p is not None:
                    raw = encode_payload(p)
                    specs[i].add(decode_payload(raw))  # as a receiver sees it (a 0-d array comes back a numpy scalar)
                    sizes[i] = max(sizes[i], len(raw))
    return specs, sizes


def frame_limit(payload_bytes: int) -> int:
    """The largest data frame accepted from a sender whose design's payloads take at most ``payload_bytes``."""
    return min(HARD_LIMIT, FACTOR * payload_bytes + SLACK)
