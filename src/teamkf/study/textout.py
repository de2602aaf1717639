"""The CLI's text and JSON output: aligned plain-text tables and strict, compact JSON.

Light on purpose (numpy is imported on first use): :mod:`teamkf.cli` imports this module at start-up,
and ``teamkf --help`` loads no numerical package.
"""

from __future__ import annotations

import json
from typing import TYPE_CHECKING, Any, Sequence

from .._lazy import lazy_module

if TYPE_CHECKING:
    import numpy as np
else:
    np = lazy_module("numpy")

__all__ = ["format_table", "dumps_json"]


def format_table(headers: Sequence[str], rows: Sequence[Sequence[Any]], *, indent: str = "  ", align: str | None = None) -> str:
    """Plain-text table; ``align`` has one letter per column ("l" or "r"), default: first left, the others right."""
    cells = [[str(h) for h in headers]] + [[str(c) for c in r] for r in rows]
    widths = [max(len(r[k]) for r in cells) for k in range(len(headers))]
    al = align or ("l" + "r" * (len(headers) - 1))
    lines = []
    for n, r in enumerate(cells):
        parts = [c.ljust(w) if a == "l" else c.rjust(w) for c, w, a in zip(r, widths, al)]
        lines.append(indent + "  ".join(parts).rstrip())
        if n == 0:
            lines.append(indent + "  ".join("-" * w for w in widths))
    return "\n".join(lines)


def dumps_json(obj: Any) -> str:
    """JSON with objects indented and lists of numbers kept on one line."""

    def enc(x: Any, level: int) -> str:
        pad, inner = "  " * level, "  " * (level + 1)
        if isinstance(x, dict):
            if not x:
                return "{}"
            items = [f"{inner}{json.dumps(str(k))}: {enc(v, level + 1)}" for k, v in x.items()]
            return "{\n" + ",\n".join(items) + "\n" + pad + "}"
        if isinstance(x, (list, tuple)):
            if all(not isinstance(v, (dict, list, tuple, np.ndarray)) for v in x):
                return "[" + ", ".join(enc(v, level + 1) for v in x) + "]"
            return "[\n" + ",\n".join(inner + enc(v, level + 1) for v in x) + "\n" + pad + "]"
        if isinstance(x, np.ndarray):
            return enc(x.tolist(), level)
        if isinstance(x, np.generic):
            x = x.item()
        if isinstance(x, float) and not np.isfinite(x):
            return "null"  # strict JSON (RFC 8259) has no NaN or Infinity
        if x is None or isinstance(x, (str, bool, int, float)):
            return json.dumps(x, allow_nan=False)
        return enc(str(x), level)  # anything else (a path, ...) as its text

    return enc(obj, 0)
