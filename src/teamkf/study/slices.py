"""Design once, ship each agent its slice: the agent-slice file of ``teamkf deploy``, ``teamkf design --out`` and ``teamkf agent --design``.

A slice is agent i's own gains (:meth:`teamkf.estimators.base.Design.agent_slice`); the agent
process rebuilds its graph agent from it and the scenario's model
(:func:`teamkf.estimators._slices.agent_from_slice`) and never builds the team design, so its
memory is its runtime plus its slice.

The file is an ``.npz`` (a zip of ``.npy`` arrays, read with ``allow_pickle=False``: no object
arrays, nothing in it is executed). Per estimator ``E`` it holds

``slices/E/meta``
    a JSON text (a 0-d string array): ``format`` (``"teamkf-agent-slices"``), ``format_version``,
    ``teamkf_version``, ``estimator``, ``options``, ``horizon``, ``n_agents``, ``content_hash``
    (:func:`content_hash`), ``run_id`` (the deployment's roster, or null for ``teamkf design --out``)
    and ``agents``: per agent id its ``kind``, its ``meta`` and the SHA-256 ``digest`` of its arrays;
``slices/E/<i>/<name>``
    agent i's arrays. ``np.load`` reads an array of an ``.npz`` only when asked, so an agent reads
    the meta and its own section, not the rest of a team file.

``teamkf deploy`` writes one file per agent (its section only) into the agent's run folder;
``teamkf design --out GAINS.npz`` adds every agent's section of every estimator that ships slices.
"""

from __future__ import annotations

import hashlib
import json
import zipfile
from pathlib import Path
from typing import Any, Iterable

import numpy as np

from ..exceptions import ArgumentError, UnsupportedOperationError

__all__ = ["FORMAT", "FORMAT_VERSION", "content_hash", "slice_sections", "write_slices", "read_slice", "agent_design", "design_out_arrays"]

FORMAT = "teamkf-agent-slices"
FORMAT_VERSION = 1


def content_hash(scenario: Any, estimator: str) -> str:
    """SHA-256 (hex) of the scenario's tables, the estimator, its options and the horizon (sorted, compact JSON).

    A slice designed for another scenario, family, option or horizon has another hash.
    """
    opts = (getattr(scenario, "options", None) or {}).get(estimator) or {}
    doc = {"scenario": getattr(scenario, "raw", None), "estimator": estimator, "options": opts, "horizon": scenario.horizon}
    text = json.dumps(doc, sort_keys=True, separators=(",", ":"), allow_nan=True, default=str)
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


def _digest(arrays: dict[str, np.ndarray]) -> str:
    h = hashlib.sha256()
    for name in sorted(arrays):
        a = np.ascontiguousarray(arrays[name])
        h.update(f"{name}|{a.dtype.str}|{a.shape}|".encode())
        h.update(a.tobytes())
    return h.hexdigest()


def _plain(x: Any) -> Any:
    """JSON-able options (numpy scalars and arrays as numbers and lists)."""
    return json.loads(json.dumps(x, default=lambda v: v.tolist() if hasattr(v, "tolist") else str(v)))


def payloads(scenario: Any, design: Any) -> dict[str, Any]:
    """What every agent's payloads look like (:func:`teamkf.deploy.payload.learn_payloads`, from the team's design), as JSON data:
    an agent rebuilt from its slice checks its in-neighbours' frames against it without the team design."""
    from ..deploy import check_deployable
    from ..deploy.payload import learn_payloads, specs_to_json

    return specs_to_json(*learn_payloads(design, check_deployable(design, scenario.graph)))


def slice_sections(
    scenario: Any, design: Any, agents: Iterable[int] | None = None, *, run_id: int | None = None, shapes: dict[str, Any] | None = None
) -> dict[str, np.ndarray]:
    """The file's arrays for ``agents`` (default: all) of ``design``: ``slices/E/meta`` and ``slices/E/<i>/...``.

    ``shapes``: :func:`payloads` of the design (computed here when not given). Raises
    :class:`~teamkf.exceptions.UnsupportedOperationError` when the family ships no slice.
    """
    from .. import __version__

    name = str(design.estimator)
    ids = list(range(int(design.n_agents))) if agents is None else [int(i) for i in agents]
    out: dict[str, np.ndarray] = {}
    per: dict[str, Any] = {}
    for i in ids:
        kind, arrays, meta = design.agent_slice(i)
        arrays = {k: np.asarray(v) for k, v in arrays.items()}
        for k, v in arrays.items():
            if v.dtype.kind not in "biuf":
                raise UnsupportedOperationError(name, "agent_slice()", f"its array {k!r} is of dtype {v.dtype}; a slice holds numbers only")
            out[f"slices/{name}/{i}/{k}"] = v
        per[str(i)] = {"kind": kind, "meta": _plain(meta), "digest": _digest(arrays)}
    head = {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "teamkf_version": __version__,
        "estimator": name,
        "options": _plain((getattr(scenario, "options", None) or {}).get(name) or {}),
        "horizon": design.horizon,
        "n_agents": int(design.n_agents),
        "content_hash": content_hash(scenario, name),
        "run_id": None if run_id is None else int(run_id),
        "agents": per,
        "payloads": shapes if shapes is not None else payloads(scenario, design),
    }
    out[f"slices/{name}/meta"] = np.asarray(json.dumps(head, sort_keys=True))
    return out


def agent_files(scenario: Any, design: Any, run_id: int) -> list[dict[str, np.ndarray]] | None:
    """Each agent's own slice file of a deployment (its section only, bound to ``run_id``), or None when the family ships none.

    None comes with one line on stderr: the agent processes then design the team themselves.
    """
    try:
        design.agent_slice(0)  # a family without slices says so before the payloads are learned
        shapes = payloads(scenario, design)  # once for the team
        return [slice_sections(scenario, design, [i], run_id=run_id, shapes=shapes) for i in range(int(design.n_agents))]
    except UnsupportedOperationError as exc:
        import sys

        print(f"teamkf deploy: {exc}; every agent process designs the team", file=sys.stderr)
        return None


def write_slices(path: str | Path, sections: dict[str, np.ndarray]) -> None:
    """Write ``sections`` to ``path`` (an ``.npz``; written to a temporary file, then renamed: :func:`~teamkf.study.outputs.write_atomic`)."""
    from .outputs import write_atomic

    write_atomic(path, lambda fh: np.savez(fh, **sections))  # type: ignore[arg-type]  # a file handle: no suffix added


def design_out_arrays(scenario: Any, designs: dict[str, Any]) -> dict[str, np.ndarray]:
    """What ``teamkf design --out`` writes: each design's arrays (``E/...``) and the slices of those that ship them (``slices/E/...``)."""
    arrays: dict[str, np.ndarray] = {}
    for name, d in designs.items():
        arrays.update({f"{name}/{k}": v for k, v in d.arrays().items()})
        if d.realizable:
            try:
                arrays.update(slice_sections(scenario, d))
            except UnsupportedOperationError:
                pass  # a family without slices: its agents design for themselves (docs/deploy.md)
    return arrays


def _refuse(path: str, what: str) -> ArgumentError:
    return ArgumentError(f"--design: {path}: {what}", argument="--design")


def read_slice(path: str, scenario: Any, estimator: str, index: int, run_id: int | None = None) -> tuple[str, dict[str, np.ndarray], dict[str, Any]]:
    """Agent ``index``'s ``(kind, arrays, meta)`` from the slice file ``path``, after checking that it is this run's.

    Refused in one line (:class:`~teamkf.exceptions.ArgumentError` on ``--design``): a file that is not a
    slice file (truncated, damaged, another format or version), without ``estimator``, designed for another
    scenario / options / horizon (its content hash), for another roster (run id), without agent ``index``,
    or whose arrays do not match their digest.
    """
    if not Path(path).is_file():
        raise _refuse(path, "no such file; write it with teamkf design SCENARIO --out FILE.npz")
    try:
        with np.load(path, allow_pickle=False) as f:
            key = f"slices/{estimator}/meta"
            if key not in f.files:
                have = sorted({k.split("/")[1] for k in f.files if k.startswith("slices/") and k.endswith("/meta")})
                raise _refuse(path, f"expected a slice of {estimator!r}, found slices of {have or 'no estimator'}; design it or pass --estimator")
            head = json.loads(str(f[key][()]))
            if head.get("format") != FORMAT or head.get("format_version") != FORMAT_VERSION:
                raise _refuse(
                    path, f"expected format {FORMAT} version {FORMAT_VERSION}, found {head.get('format')} version {head.get('format_version')}"
                )
            want = content_hash(scenario, estimator)
            if head.get("content_hash") != want:
                raise _refuse(
                    path,
                    f"designed for another scenario, options or horizon (content hash {str(head.get('content_hash'))[:16]}, "
                    f"the scenario {getattr(scenario, 'name', '?')} gives {want[:16]}); design it again from this scenario",
                )
            if head.get("run_id") is not None and run_id is not None and int(head["run_id"]) != int(run_id):
                raise _refuse(path, f"written for run {head['run_id']}, the roster is of run {run_id}; use the slice of this roster's run")
            entry = head.get("agents", {}).get(str(index))
            if entry is None:
                raise _refuse(path, f"expected agent {index}'s slice (--id {index}), found agents {sorted(map(int, head.get('agents', {})))}")
            prefix = f"slices/{estimator}/{index}/"
            arrays = {k[len(prefix) :]: f[k] for k in f.files if k.startswith(prefix)}
    except ArgumentError:
        raise
    except (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile, json.JSONDecodeError, TypeError) as exc:
        raise _refuse(path, f"not a readable slice file (truncated or damaged: {type(exc).__name__}: {exc})") from None
    if _digest(arrays) != entry.get("digest"):
        raise _refuse(path, f"agent {index}'s arrays do not match their digest (the file was modified or damaged); write it again")
    try:
        from ..deploy.payload import specs_from_json

        shipped = specs_from_json(head["payloads"])
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise _refuse(path, f"its payload structures are not readable ({type(exc).__name__}: {exc}); write it again") from None
    meta = {**entry.get("meta", {}), "estimator": estimator, "payload_specs": shipped}
    return str(entry.get("kind")), arrays, meta


def agent_design(args: Any, scenario: Any, name: str, run_id: int | None = None) -> tuple[Any, Any]:
    """``(design, agent)`` of ``teamkf agent``: rebuilt from ``--design`` (no team design), or the team design and its agent ``--id``."""
    from ..deploy import check_deployable
    from ..estimators._slices import SliceContext, agent_from_slice

    i = int(args.id)
    path = getattr(args, "design", None)
    if path is None:
        design = scenario.design(name)
        check_deployable(design, scenario.graph)
        return design, None  # the runtime builds design.graph_agents()[i]
    kind, arrays, meta = read_slice(path, scenario, name, i, run_id)
    ctx = SliceContext(scenario.system, scenario.cost, scenario.graph, scenario.information, scenario.horizon)
    shipped = meta.pop("payload_specs")
    view, agent = agent_from_slice(kind, ctx, i, arrays, meta)
    view.info["payload_specs"] = shipped  # its in-neighbours' payload structures, learned by the team's design (AgentCore)
    check_deployable(view, scenario.graph)
    return view, agent
