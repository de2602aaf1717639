"""The leaderboard's cache of computed parts: fingerprints, read-back checks, atomic writes.

A part is one network's rows (:func:`teamkf.experiments.leaderboard.network_part`, the lossy rows, a plug-in's
rows), stored as ``<TEAMKF_CACHE_DIR>/<key>.json`` under a key that hashes every array of the network, the
source of every estimator and of the leaderboard (:func:`_fingerprint`). A part that does not read back as what
it claims to be (unreadable JSON, another format or version, a field of the wrong type) is recomputed with one
warning line, never used.
"""

from __future__ import annotations

import hashlib
import json
import os
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from ..exceptions import TeamkfError
from ..models import LinearGaussianSystem, TeamCost
from ..network import CommGraph

#: bump when :func:`network_rows` or :func:`lossy_network_rows` compute something else (part of the cache key)
ROWS_VERSION = 7


def _fingerprint(system: LinearGaussianSystem, cost: TeamCost, graph: CommGraph) -> str:
    """A hash of everything a network's rows depend on: its arrays, :data:`ROWS_VERSION` and the source of the estimators and the tuning."""
    h = hashlib.sha256(f"rows-v{ROWS_VERSION}".encode())
    for arr in (system.A, system.Q, system.Sigma_x, *system.C, *system.R, cost.S, cost.L):
        a = np.ascontiguousarray(np.asarray(arr, dtype=float))
        h.update(str(a.shape).encode())
        h.update(a.tobytes())
    h.update(repr(sorted(graph.edges)).encode())
    root = Path(__file__).resolve().parent.parent
    for src in sorted(
        [
            *(root / "estimators").rglob("*.py"),
            root / "simulation" / "links.py",
            root / "experiments" / "tuning.py",
            root / "experiments" / "divergence.py",
            root / "_linalg.py",
            Path(__file__).resolve().with_name("leaderboard.py"),
            Path(__file__).resolve(),
        ]
    ):
        h.update(src.name.encode())
        h.update(src.read_bytes())
    return h.hexdigest()[:24]


def _cache_dir() -> Path | None:
    from .._validation import env_folder

    where = env_folder("TEAMKF_CACHE_DIR")  # a file's path is one ArgumentError naming the variable
    if where is None:
        return None
    return Path(where) if where else Path.home() / ".cache" / "teamkf"


def _check_cache_dir() -> None:
    """Refuse, before any work, a ``TEAMKF_CACHE_DIR`` that is a file, an input, or lies in a missing folder (the output guard)."""
    where = os.environ.get("TEAMKF_CACHE_DIR", "")
    if where and _cache_dir() is not None:
        from ..study.outputs import check_output_dir

        check_output_dir(where, "TEAMKF_CACHE_DIR")


def _make_cache_dir(cache: Path) -> None:
    """The cache folder: a named one (``TEAMKF_CACHE_DIR``) only itself, never a missing parent; the default
    ``~/.cache/teamkf`` with ``~/.cache`` when missing (the XDG base-directory rule for a cache no one named)."""
    cache.mkdir(parents=not os.environ.get("TEAMKF_CACHE_DIR"), exist_ok=True)


#: what a cache part says it is (``format``, ``version``: :data:`ROWS_VERSION`)
CACHE_FORMAT = "teamkf-leaderboard-part"


def _cached(key: str, compute: Any, problem: Any = None) -> dict[str, Any]:
    """``compute()`` (a JSON-ready dict), stored as ``<cache>/<key>.json`` and read back from there when present.

    A part that does not read back as one (unreadable or truncated JSON, another format or version, or what
    ``problem(out)`` finds wrong: a string, else None) is recomputed and overwritten, with one warning line.
    """
    cache = _cache_dir()
    path = cache / f"{key}.json" if cache is not None else None
    if path is not None and path.is_file():
        why: str | None
        try:
            out: dict[str, Any] = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError) as exc:  # truncated, not UTF-8, unreadable
            why = f"not readable JSON ({type(exc).__name__}: {' '.join(str(exc).split())[:120]})"
        else:
            why = _common_problem(out) or (problem(out) if problem is not None else None)
        if why is None:
            out["cached"] = True
            return out
        print(f"teamkf: warning: leaderboard cache part {path}: {why}; recomputing it", file=sys.stderr, flush=True)
    t0 = time.perf_counter()
    out = compute()
    out["network seconds"] = time.perf_counter() - t0
    out["format"], out["version"] = CACHE_FORMAT, ROWS_VERSION
    if path is not None and cache is not None:
        from ..study.outputs import write_atomic

        try:  # best effort: a cache that cannot be written costs time, never a result
            _make_cache_dir(cache)
            text = json.dumps(out)
            write_atomic(path, lambda fh: fh.write(text), text=True)
        except (OSError, TeamkfError):
            pass
    out["cached"] = False
    return out


def _kind(v: Any) -> str:
    return "null" if v is None else type(v).__name__


def _is(v: Any, t: str) -> bool:
    """``v`` is of schema type ``t``: str, num (int or float, not bool), int, bool, list, dict; ``?`` allows null."""
    if t.endswith("?"):
        return v is None or _is(v, t[:-1])
    if t == "num":
        return isinstance(v, (int, float)) and not isinstance(v, bool)
    if t == "int":
        return isinstance(v, int) and not isinstance(v, bool)
    return isinstance(v, {"str": str, "bool": bool, "list": list, "dict": dict}[t])


def _fields(d: Any, schema: dict[str, str], where: str) -> str | None:
    """What is wrong with the dict ``d`` against ``schema`` (key -> type), or None."""
    if not isinstance(d, dict):
        return f"{where}: expected an object, found {_kind(d)}"
    for k, t in schema.items():
        if k not in d:
            return f"{where}: missing {k!r}"
        if not _is(d[k], t):
            return f"{where}.{k}: expected {t.rstrip('?')}{' or null' if t.endswith('?') else ''}, found {_kind(d[k])}"
    return None


def _common_problem(out: Any) -> str | None:
    if not isinstance(out, dict):
        return f"expected an object, found {_kind(out)}"
    if out.get("format") != CACHE_FORMAT or out.get("version") != ROWS_VERSION:
        return f"expected format {CACHE_FORMAT!r} version {ROWS_VERSION}, found {out.get('format')!r} version {out.get('version')!r}"
    return _fields(out, {"network seconds": "num"}, "part")


_RAW = {"estimator": "str", "variant": "str", "form": "str", "options": "str", "stage_costs": "list", "realizable": "bool", "seconds": "num?"}
_TRIED = {"options": "str", "J_T": "num", "diverging": "bool", "error": "str?"}
_LOSSY_ROW = {
    **{k: "str" for k in ("network", "estimator", "variant", "form", "options", "ci95 (MC)")},
    **{k: "num" for k in ("p_drop", "J_T", "J / J*")},
    **{k: "num?" for k in ("J_T exact", "last / last*", "J*_avg (steady)", "seconds")},
    **{"n_agents": "int", "d_x": "int", "diverging": "bool", "realizable": "bool", "beats MTMSE at some step": "bool?", "why diverging": "str?"},
}


def _part_problem(out: dict[str, Any], part: str, T: int, n_agents: int) -> str | None:
    """What is wrong with an exact part read from the cache (see :func:`network_part`), or None."""
    schema = {"raw": "list", "steady": "num?", "n_agents": "int", "d_x": "int"} if part == "base" else {"raw": "list", "tried": "list?"}
    why = _fields(out, schema, "part")
    if why:
        return why
    if part == "base" and (out["n_agents"] != n_agents or not out["raw"] or out["raw"][0].get("estimator") != "mtmse"):
        return f"part: expected the base rows of a network of {n_agents} agents, MTMSE first"
    for q, r in enumerate(out["raw"]):
        why = _fields(r, {**_RAW, "why diverging": "str?"}, f"raw[{q}]")
        if why:
            return why
        sc = r["stage_costs"]
        if len(sc) != T or not all(_is(v, "num") for v in sc):
            return f"raw[{q}].stage_costs: expected {T} numbers, found {len(sc)} entries"
    for q, c in enumerate(out.get("tried") or []):
        why = _fields(c, _TRIED, f"tried[{q}]")
        if why:
            return why
    return None


def _lossy_problem(out: dict[str, Any]) -> str | None:
    """What is wrong with a lossy part read from the cache (see :func:`lossy_network_rows`), or None."""
    why = _fields(out, {"rows": "list"}, "part")
    for q, r in enumerate(out["rows"] if why is None else []):
        why = _fields(r, _LOSSY_ROW, f"rows[{q}]")
        if why:
            break
    return why
