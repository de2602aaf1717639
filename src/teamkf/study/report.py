"""What ``teamkf evaluate`` prints and writes: the text table, the JSON object, and the links each cost is under.

A scenario with a ``[network]`` table has links that drop, jitter or fail. An analytic cost is then one of
two things, and the reports say which (:func:`cost_links`, the row key ``cost_links``):

``"lossy"``
    the expected cost under the scenario's links: the drop-aware design's exact expected cost (its
    ``p_drop``/``jitter`` are the scenario's and there are no outages or failures), the cost of a design
    that uses no link (the centralized bound, the local filters), and every Monte Carlo cost (simulated
    over the links).
``"perfect"``
    the design's cost on links that never drop (MTMSE, MMSE, KCF, ...): over the scenario's links its cost is
    higher, and only its Monte Carlo mean says by how much. The text table marks such a cost
    ``(perfect links)`` and says so in a note; the JSON entry has ``"cost_links": "perfect"``.
``"assumed"``
    the drop-aware design's expected cost under the links it was designed for (its own ``p_drop`` in the
    ``[mtmse_lossy]`` table, or with outages/failures it does not model), which are not the scenario's.

The column "vs mtmse" never sets a cost under one link model against a cost under another: with Monte Carlo
it compares the costs under the scenario's links (exact where the row has one, else its Monte Carlo mean);
without, it compares only rows under the same links and shows "-" for the others.

The link model itself (per-edge drop probabilities, jitter bounds, outages, failures) is recorded by
:func:`link_record` (JSON ``"links"``, sweep column ``links`` as :func:`link_text`) and printed in the
header and plot titles.
"""

from __future__ import annotations

import math
from typing import Any, Mapping

from .textout import format_table  # noqa: F401  (the one plain-text table; used below and by the CLI)

__all__ = [
    "fmt",
    "pct",
    "format_table",
    "cost_label",
    "link_record",
    "link_text",
    "cost_links",
    "evaluation_table",
    "evaluation_json",
    "sweep_cell",
    "SWEEP_NOTE",
    "PERFECT_MARK",
]

#: the mark of an analytic cost on perfect links in a table of a scenario whose links drop
PERFECT_MARK = "(perfect links)"
_ASSUMED_MARK = "(its design's links)"


# ---------------------------------------------------------------------------
# formatting
# ---------------------------------------------------------------------------
def cost_label(horizon: int | None) -> str:
    """``"J_T"`` (finite horizon) or ``"average cost"``."""
    return "J_T" if horizon is not None else "average cost"


def fmt(x: float | None) -> str:
    """A cost as the tables print it: 2 decimals from 100, 4 below, e-notation for the very large or small."""
    if x is None:
        return "-"
    if not math.isfinite(x):
        return "diverged"
    ax = abs(x)
    if ax != 0 and (ax >= 1e7 or ax < 1e-3):
        return f"{x:.4e}"
    return f"{x:.2f}" if ax >= 100 else f"{x:.4f}"


def pct(p: float) -> str:
    """A relative difference in percent; huge ones (a diverging estimator) in e-notation, not 40 digits."""
    if not math.isfinite(p):
        return "diverged"
    return f"{p:+.3e} %" if abs(p) >= 1e5 else f"{p:+.2f} %"


# ---------------------------------------------------------------------------
# the link model
# ---------------------------------------------------------------------------
def _per_edge(x: Any) -> Any:
    if isinstance(x, Mapping):
        return {f"{a}->{b}": v for (a, b), v in sorted(x.items())}
    return x


def link_record(links: Any) -> dict[str, Any]:
    """The link model as plain JSON: ``{"perfect", "p_drop", "jitter", "outages", "failures"}``.

    ``links`` is a :class:`~teamkf.simulation.links.LinkModel` or None (reliable links). A per-edge
    ``p_drop``/``jitter`` is a mapping ``"a->b"`` -> value (other edges: 0).

    Examples
    --------
    >>> from teamkf.simulation.links import LinkModel
    >>> link_record(LinkModel(p_drop=0.5))
    {'perfect': False, 'p_drop': 0.5, 'jitter': 0, 'outages': [], 'failures': {}}
    >>> link_record(None)["perfect"]
    True
    """
    if links is None:
        return {"perfect": True, "p_drop": 0.0, "jitter": 0, "outages": [], "failures": {}}
    return {
        "perfect": bool(links.trivial),
        "p_drop": _per_edge(links.p_drop),
        "jitter": _per_edge(links.jitter),
        "outages": [list(o) for o in links.outages],
        "failures": {str(a): int(s) for a, s in sorted(links.failures.items())},
    }


def link_text(record: Mapping[str, Any] | None) -> str:
    """One line for a :func:`link_record`: ``"p_drop 0.5 on every edge"``, ``"perfect"``, ...

    Examples
    --------
    >>> link_text({"perfect": False, "p_drop": 0.3, "jitter": 1, "outages": [[0, 1, 4, 6]], "failures": {"2": 9}})
    'p_drop 0.3 on every edge; jitter 0..1 steps on every edge; outage 0->1 steps 4..6; agent 2 fails at step 9'
    """
    if record is None or record.get("perfect", True):
        return "perfect"
    parts = []
    for key, what in (("p_drop", "p_drop {} on every edge"), ("jitter", "jitter 0..{} steps on every edge")):
        v = record.get(key)
        if isinstance(v, Mapping):
            if any(x for x in v.values()):
                parts.append(f"{key} " + ", ".join(f"{e}: {x:g}" for e, x in v.items()) + " (other edges 0)")
        elif v:
            parts.append(what.format(f"{v:g}"))
    parts += [f"outage {a}->{b} steps {f}..{last}" for a, b, f, last in record.get("outages", [])]
    parts += [f"agent {a} fails at step {s}" for a, s in record.get("failures", {}).items()]
    return "; ".join(parts) or "perfect"


def _same_links(design_links: Mapping[str, Any], links: Any, graph: Any) -> bool:
    """True when the links a design's expected cost assumes (p_drop, jitter) are the scenario's, edge by edge."""
    if links.outages or links.failures:
        return False

    def of(x: Any, e: tuple[int, int]) -> float:
        return float(x.get(e, 0.0)) if isinstance(x, Mapping) else float(x)

    for a, b, _ in graph.edges:
        e = (int(a), int(b))
        if of(design_links.get("p_drop", 0.0), e) != links.p_of(e) or of(design_links.get("jitter", 0), e) != links.jitter_of(e):
            return False
    return True


def cost_links(design: Any, links: Any, graph: Any, method: str = "analytic") -> str:
    """Which links a row's cost is under: ``"perfect"``, ``"lossy"`` (the scenario's) or ``"assumed"`` (module docstring).

    Parameters
    ----------
    design : Design
        The estimator's design.
    links : LinkModel or None
        The scenario's links (None: reliable).
    graph : CommGraph
        The scenario's graph (the edges a per-edge drop probability is compared on).
    method : str
        The row's method: a ``"monte-carlo"`` cost is simulated over the links.
    """
    lossy = links is not None and not links.trivial
    if not lossy:
        return "perfect"
    if method == "monte-carlo" or getattr(design, "omniscient", False):
        return "lossy"
    alg = getattr(design, "algorithm", None)  # a filter that sends nothing (the local filters): links change nothing
    if alg is not None and getattr(alg, "info_graph", 1) is None and not getattr(alg, "payload_kinds", {1: 1}):
        return "lossy"
    assumed = getattr(design, "cost_link_model", None)  # the drop-aware design: its expected cost's links
    if assumed is not None:
        return "lossy" if _same_links(assumed, links, graph) else "assumed"
    return "perfect"


# ---------------------------------------------------------------------------
# evaluate: the table and the JSON object
# ---------------------------------------------------------------------------
def _under_links(row: Mapping[str, Any], key: str) -> float | None:
    """A row's cost under the scenario's links: its own when it is one, else its Monte Carlo mean (or None)."""
    if row.get("cost_links") == "lossy":
        return row[key]  # type: ignore[no-any-return]
    return row.get("mc_cost")


def _rel(v: Any, ref: Any) -> str:
    ok = v is not None and ref is not None and math.isfinite(v) and math.isfinite(ref) and ref != 0
    return pct(100.0 * (v - ref) / ref) if ok else "-"


def evaluation_table(ev: Any) -> str:
    """The text table of an evaluation: cost (analytic, or MC marked; perfect-link costs marked), vs mtmse, Monte Carlo.

    With lossy links, notes under the table say what a ``(perfect links)`` cost is and what "vs mtmse" compares.
    """
    key = ev.cost_key
    lossy = bool(getattr(ev, "links", None)) and not ev.links.get("perfect", True)
    refrow = next((r for r in ev.rows if r["estimator"] == "mtmse"), None)
    headers = ["estimator", cost_label(ev.horizon)]
    if refrow is not None:
        headers.append("vs mtmse")
    if ev.runs:
        headers += ["MC mean", "MC 95% CI"]
    rows, marks = [], set()
    for r in ev.rows:
        v, mc = r[key], r["method"] == "monte-carlo"
        shown = "diverged" if r["diverged"] and (v is None or not math.isfinite(v)) else fmt(v) + (" (MC)" if mc else "")
        where = r.get("cost_links")
        if lossy and not mc and where in ("perfect", "assumed"):
            shown += " " + (PERFECT_MARK if where == "perfect" else _ASSUMED_MARK)
            marks.add(where)
        row = [r["label"], shown]
        if refrow is not None:
            if not lossy:
                row.append(_rel(v, refrow[key]))
            elif ev.runs:
                row.append(_rel(_under_links(r, key), _under_links(refrow, key)))
            else:
                row.append(_rel(v, refrow[key]) if where == refrow.get("cost_links") else "-")
        if ev.runs:
            lo, hi = (r["ci95_low"], r["ci95_high"]) if mc else (r["mc_ci95_low"], r["mc_ci95_high"])
            mean = v if mc else r["mc_cost"]
            row += ["", ""] if mean is None else [fmt(mean), f"[{fmt(lo)}, {fmt(hi)}]"]
        rows.append(row)
    out = format_table(headers, rows)
    notes = []
    if "perfect" in marks:
        notes.append(
            f"{PERFECT_MARK}: the analytic cost on links that never drop, not the cost over these links"
            + (" (that is its MC mean)" if ev.runs else " (add --monte-carlo RUNS to simulate it over them)")
        )
    if "assumed" in marks:
        notes.append(f"{_ASSUMED_MARK}: the expected cost under the links given in its own table, not these")
    designs = [(r["label"], d) for r in ev.rows if (d := ev.designs.get(r["estimator"])) is not None]
    notes += [sampled_note(label, d.info) for label, d in designs if d.info.get("exact") is False and "interval" in d.info]
    notes += [bound_note(label, d.info) for label, d in designs if "known_pattern_gap" in d.info]
    if lossy and refrow is not None:
        notes.append(
            "vs mtmse: costs under these links (exact where the row has one, else the MC mean)"
            if ev.runs
            else "vs mtmse: only between costs under the same links ('-': a cost under these links against a perfect-link one)"
        )
    return out + "".join(f"\n  {n}" for n in notes)


def sampled_note(label: str, info: Mapping[str, Any]) -> str:
    """The line under a table for an expected cost estimated over sampled link patterns (each pattern's moments exact)."""
    lo, hi = info["interval"]
    how = (
        f"the re-sending design's exact {fmt(info['resend_cost'])} plus the paired difference over {info.get('patterns')} fresh link patterns"
        if "resend_cost" in info
        else f"over {info.get('patterns')} sampled link patterns"
    )
    return f"{label}: an estimate of its expected cost ({how}), 95 % [{fmt(lo)}, {fmt(hi)}]"


def bound_note(label: str, info: Mapping[str, Any]) -> str:
    """The line under a table for a design that computed its known-pattern bound (``known_bound``): the gap and the bound."""
    b = info["known_pattern_bound"]
    told = "told what any protocol can tell (causal)" if b.get("knowledge") == "causal" else "told every drop"
    relays = b["relay"] + (f", re-sending {b['resend']}" if b.get("resend", 1) > 1 and b["relay"] == "flood" else "")
    how = "exact" if b["exact"] else f"{b['n_patterns']} patterns, 95 % [{fmt(b['interval'][0])}, {fmt(b['interval'][1])}]"
    return f"{label}: {100.0 * info['known_pattern_gap']:.2f} % above the known-pattern bound {fmt(b['value'])} ({told}; relays {relays}; {how})"


def _json_float(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


def evaluation_json(ev: Any, version: str) -> dict[str, Any]:
    """``teamkf evaluate --json``: the evaluation's rows under ``estimators`` (the contract of scenario-and-cli.md).

    Each entry is the row (:data:`teamkf.study.evaluation.ROW_KEYS`, strict JSON; keys that do not apply to it
    left out) with ``stage_costs``, and the contract's list forms ``ci95`` = [ci95_low, ci95_high] and
    ``mc_ci95`` = [mc_ci95_low, mc_ci95_high] beside the row's own keys. ``links`` is the link model
    (:func:`link_record`) and each entry's ``cost_links`` says which links its cost is under (module docstring).
    """
    out: dict[str, Any] = {"scenario": ev.scenario, "horizon": ev.horizon, "teamkf_version": version, "schema_version": ev.schema_version}
    if getattr(ev, "links", None) is not None:
        out["links"] = dict(ev.links)
    if ev.details.get("control"):
        out["control"] = ev.details["control"]
    if ev.monte_carlo:  # what repeats the Monte Carlo: seed, runs, block and chunk sizes, teamkf version
        first = next(iter(ev.monte_carlo.values()))
        out["monte_carlo"] = {"runs": ev.runs, "seed": ev.seed, "batch": first.batch, "chunk": first.chunk, "teamkf_version": version}
    out["estimators"] = {}
    for row in ev.json_rows():
        name = row["estimator"]
        entry: dict[str, Any] = {"method": row["method"], ev.cost_key: row[ev.cost_key]}
        if row["method"] == "monte-carlo" or row.get("ci95_low") is not None:  # an analytic cost estimated over link patterns too
            entry.update(ci95=[row["ci95_low"], row["ci95_high"]], ci95_low=row["ci95_low"], ci95_high=row["ci95_high"])
        if row["mc_cost"] is not None or row["mc_ci95_low"] is not None:
            entry.update(mc_cost=row["mc_cost"], mc_ci95=[row["mc_ci95_low"], row["mc_ci95_high"]])
            entry.update(mc_ci95_low=row["mc_ci95_low"], mc_ci95_high=row["mc_ci95_high"])
        entry.update({k: row[k] for k in ("runs", "seed", "label", "cost_links") if row.get(k) is not None})
        d = ev.designs.get(name)
        if d is not None and "variant" in d.info:
            entry["variant"] = d.info["variant"]
        if d is not None and "known_pattern_gap" in d.info:  # known_bound: the bound (value, interval, knowledge) and the gap
            entry.update(known_pattern_bound=d.info["known_pattern_bound"], known_pattern_gap=d.info["known_pattern_gap"])
        entry["diverged"] = row["diverged"]
        if "non_finite" in row:
            entry["non_finite"] = row["non_finite"]
        if ev.horizon is not None:
            stages = ev.stage_costs(name)
            if stages is not None:
                entry["stage_costs"] = [_json_float(c) for c in stages]
        out["estimators"][name] = entry
    return out


#: the note under a sweep table with :func:`sweep_cell` marks
SWEEP_NOTE = "*: an analytic cost on perfect links at a point whose links drop (its mc_cost, with runs, is the cost over them)"


def sweep_cell(row: Mapping[str, Any], key: str) -> tuple[str, bool]:
    """A sweep row's cost as the sweep table prints it, and whether it is marked ``*`` (perfect links, lossy point)."""
    v = row.get(key)
    if v is None:
        return "-", False
    marked = row.get("cost_links") in ("perfect", "assumed") and row.get("links") not in (None, "perfect")
    return fmt(v) + ("*" if marked else ""), marked
