"""HTML representations for notebooks and the documentation site (``_repr_html_``).

Every result object shows itself as a compact HTML table: the fields a reader
looks at first (costs, horizon, runs, confidence intervals), never anything
that needs computing beyond a sum. :class:`DesignReprMixin` gives every design
the same table; the other result classes call :func:`html_table` directly.

Examples
--------
>>> print(html_table(["a", "paper a"], [{"a": 1.5, "paper a": 1.25}], published=lambda c: c.startswith("paper")))
<table class="teamkf-table">
<thead><tr><th>a</th><th class="teamkf-published" title="published value (comparison only)">paper a</th></tr></thead>
<tbody>
<tr><td>1.5</td><td class="teamkf-published">1.25</td></tr>
</tbody>
</table>
"""

from __future__ import annotations

import html
import math
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

__all__ = ["html_table", "format_value", "DesignReprMixin", "design_rows", "design_repr", "short_repr", "short_value", "MAX_ROWS", "MAX_REPR_LINES"]

#: tables longer than this show their first and last rows only
MAX_ROWS = 30

#: a cost (or relative cost) this large is an estimator that diverged (an error growing like 1.55^t over
#: T = 100 steps reaches 1e38); tables mark it so rather than print it as a number to compare
DIVERGED = 1e30


def format_value(v: Any) -> str:
    """A short text for one table cell: 6 significant digits for floats, '' for None, marked when diverged.

    Examples
    --------
    >>> format_value(1234.56789), format_value(float("nan")), format_value(7.2e37), format_value(None)
    ('1234.57', 'diverged', '7.2e+37 (diverged)', '')
    """
    if v is None:
        return ""
    if isinstance(v, (bool, np.bool_)):
        return str(bool(v))
    if isinstance(v, (float, np.floating)):
        f = float(v)
        if math.isnan(f):
            return "diverged"
        if math.isinf(f):
            return "∞ (diverged)" if f > 0 else "−∞ (diverged)"
        if abs(f) >= DIVERGED:
            return f"{f:.2g} (diverged)"
        return f"{f:.6g}"
    if isinstance(v, np.ndarray):
        return f"array{v.shape}"
    s = str(v)
    return s if len(s) <= 80 else s[:77] + "..."


def html_table(
    columns: Sequence[str],
    rows: Sequence[Mapping[str, Any]],
    *,
    caption: str | None = None,
    published: Callable[[str], bool] | None = None,
    max_rows: int = MAX_ROWS,
) -> str:
    """An HTML table of ``rows`` (dicts) in the order of ``columns``.

    Parameters
    ----------
    columns : column names, in order
    rows : one mapping per row (missing keys give empty cells)
    caption : optional caption (escaped)
    published : predicate on a column name; those columns are marked as
        published values (class ``teamkf-published``), shown for comparison
    max_rows : longer tables keep their first and last ``max_rows // 2`` rows
    """
    pub = published or (lambda c: False)

    def th(c: str) -> str:
        if pub(c):
            return f'<th class="teamkf-published" title="published value (comparison only)">{html.escape(c)}</th>'
        return f"<th>{html.escape(c)}</th>"

    def td(c: str, v: Any) -> str:
        cls = ' class="teamkf-published"' if pub(c) else ""
        return f"<td{cls}>{html.escape(format_value(v))}</td>"

    shown: list[Mapping[str, Any] | None] = list(rows)
    if len(shown) > max_rows:
        half = max(1, max_rows // 2)
        shown = [*rows[:half], None, *rows[-half:]]
    out = ['<table class="teamkf-table">']
    if caption:
        out.append(f"<caption>{html.escape(caption)}</caption>")
    out.append("<thead><tr>" + "".join(th(c) for c in columns) + "</tr></thead>")
    out.append("<tbody>")
    for r in shown:
        if r is None:
            out.append(f'<tr><td colspan="{len(columns)}">… {len(rows) - 2 * (max_rows // 2)} rows not shown …</td></tr>')
        else:
            out.append("<tr>" + "".join(td(c, r.get(c)) for c in columns) + "</tr>")
    out.append("</tbody>")
    out.append("</table>")
    return "\n".join(out)


def design_rows(design: Any) -> list[dict[str, Any]]:
    """(field, value) rows describing a design: family, horizon, analytic cost, agents; no computation beyond a sum."""
    rows: list[dict[str, Any]] = [
        {"field": "estimator", "value": getattr(design, "label", None) or getattr(design, "estimator", type(design).__name__)}
    ]
    rows.append({"field": "class", "value": type(design).__name__})
    system = getattr(design, "system", None)
    n_agents = getattr(system, "n_agents", None)
    if n_agents is not None:
        rows.append({"field": "agents", "value": n_agents})
    horizon = getattr(design, "horizon", None)
    rows.append({"field": "horizon T", "value": "∞ (steady state)" if horizon is None else horizon})
    stage = getattr(design, "stage_costs", None)
    if stage is not None:
        rows.append({"field": "total cost J_T (analytic)", "value": float(np.sum(stage))})
    avg = getattr(design, "average_cost", None)
    if avg is not None:
        rows.append({"field": "average cost (analytic)", "value": float(avg)})
    if stage is None and avg is None:
        rows.append({"field": "cost", "value": "no analytic cost (Monte Carlo)"})
    info = getattr(design, "info", None)
    if isinstance(info, Mapping):
        for k, v in info.items():
            if isinstance(v, (str, int, float, bool, np.integer, np.floating)) or v is None:
                rows.append({"field": str(k), "value": v})
    return rows


#: the most lines a short repr prints (one screen)
MAX_REPR_LINES = 20


def short_value(v: Any, width: int = 60) -> str:
    """A value for a one-line repr: arrays by shape, long sequences by length, long texts cut."""
    if isinstance(v, np.ndarray):
        return f"array{v.shape}" if v.size > 8 else np.array2string(v, separator=", ", threshold=8).replace("\n", "")
    if isinstance(v, (float, np.floating)):
        return format_value(v)
    if isinstance(v, (list, tuple)) and v and any(isinstance(x, (np.ndarray, list, tuple)) for x in v):
        return f"<{len(v)} {type(v).__name__} items>"
    text = repr(v)
    if "\n" in text or len(text) > width:
        name = type(v).__name__
        n = getattr(v, "n_agents", None)
        text = f"<{name}, {n} agents>" if isinstance(n, (int, np.integer)) else f"<{name}>"
    return text


def short_repr(obj: Any, fields: Sequence[tuple[str, Any]], *, width: int = 100) -> str:
    """``Class(a=..., b=...)`` with every value short (:func:`short_value`), wrapped, at most :data:`MAX_REPR_LINES` lines."""
    parts = [f"{k}={short_value(v)}" for k, v in fields]
    lines: list[str] = []
    line = f"{type(obj).__name__}("
    for i, part in enumerate(parts):
        piece = part + (", " if i < len(parts) - 1 else "")
        if len(line) + len(piece) > width and line.strip():
            lines.append(line.rstrip())
            line = "    "
        line += piece
    lines.append(line + ")")
    if len(lines) > MAX_REPR_LINES:
        lines = [*lines[: MAX_REPR_LINES - 1], "    ...)"]
    return "\n".join(lines)


def design_repr(design: Any) -> str:
    """A design in one short paragraph: family, class, agents, horizon and its analytic cost (never its arrays).

    Examples
    --------
    >>> from teamkf import LinearGaussianSystem, TeamCost, CommGraph, design_mtmse
    >>> d = design_mtmse(LinearGaussianSystem.platoon(4), TeamCost.platoon(4, 100.0), CommGraph.line(4, delay=1), horizon=100)
    >>> print(repr(d))
    TeamDesign(estimator='mtmse', agents=4, horizon=100, total_cost=4272.77)
    """
    fields: list[tuple[str, Any]] = [("estimator", getattr(design, "label", None) or getattr(design, "estimator", type(design).__name__))]
    n_agents = getattr(getattr(design, "system", None), "n_agents", None)
    if n_agents is not None:
        fields.append(("agents", int(n_agents)))
    fields.append(("horizon", getattr(design, "horizon", None)))
    stage = getattr(design, "stage_costs", None)
    avg = getattr(design, "average_cost", None)
    if stage is not None:
        fields.append(("total_cost", float(np.sum(stage))))
    elif avg is not None:
        fields.append(("average_cost", float(avg)))
    else:
        fields.append(("cost", "Monte Carlo"))
    return short_repr(design, fields)


class DesignReprMixin:
    """Gives a design a short ``repr`` (one screen at any size) and a compact HTML table in notebooks.

    A dataclass writes its own ``__repr__`` (every field, arrays in full: megabytes for a long horizon)
    unless the class already has one; :meth:`__init_subclass__` gives every subclass this short one
    before the dataclass decorator runs, so a user's design gets it too. A class that defines its own
    ``__repr__`` keeps it.
    """

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        if "__repr__" not in cls.__dict__:
            cls.__repr__ = design_repr  # type: ignore[method-assign,assignment]

    def __repr__(self) -> str:
        return design_repr(self)

    def _repr_html_(self) -> str:
        name = getattr(self, "estimator", type(self).__name__)
        return html_table(["field", "value"], design_rows(self), caption=f"teamkf design: {name}")
