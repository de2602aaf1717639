"""Scenario and sweep files as data: TOML, or JSON by the file's suffix, read with one clear error.

Duplicate JSON keys, nesting deeper than the code can walk, undecodable bytes and syntax errors are each
one :class:`~teamkf.exceptions.ScenarioError` naming the file (and the line and column where known).
"""

from __future__ import annotations

import json
import tomllib
from pathlib import Path
from typing import Any, Mapping

from ..exceptions import ScenarioError
from .dotted import _parse_path, _path_str, set_dotted  # noqa: F401  (set_dotted: public here too)

__all__ = ["read_data_file", "check_depth"]


def _no_duplicates(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    """``object_pairs_hook`` of the JSON reader: a key written twice in one object is an error (TOML's rule), not last-wins."""
    out: dict[str, Any] = {}
    for k, v in pairs:
        if k in out:
            raise _DuplicateKey(k)
        out[k] = v
    return out


class _DuplicateKey(Exception):
    pass


def read_data_file(p: Path) -> dict[str, Any]:
    """The table in a TOML file (or a JSON file, by its suffix); one clear ScenarioError otherwise.

    Refused with one line naming the file: bytes that are not UTF-8 (a UTF-16 or binary file),
    a syntax error (line and column), a key written twice in one table (JSON too, where
    Python's reader would keep the last), nesting deeper than the parser's recursion limit,
    integers beyond Python's 4300-digit conversion limit, and a top level that is not a table.
    """
    try:
        raw = p.read_bytes()
    except IsADirectoryError:
        raise ScenarioError(f"{p}: is a directory; expected a scenario file (.toml or .json)") from None
    if raw.startswith((b"\xff\xfe", b"\xfe\xff")) or b"\x00" in raw[:4096]:
        raise ScenarioError(f"{p}: expected a UTF-8 text file (TOML or JSON), found UTF-16 or binary data (NUL bytes); save it as UTF-8")
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise ScenarioError(f"{p}: expected a UTF-8 text file (TOML or JSON), found undecodable bytes at position {exc.start}") from None
    kind = "JSON" if p.suffix.lower() == ".json" else "TOML"
    try:
        if kind == "JSON":
            data = json.loads(text, object_pairs_hook=_no_duplicates)
        else:
            data = tomllib.loads(text)
    except json.JSONDecodeError as exc:
        raise ScenarioError(f"{p}: invalid JSON: {exc.msg} (at line {exc.lineno}, column {exc.colno})") from None
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(f"{p}: invalid TOML: {exc}") from None
    except _DuplicateKey as exc:
        raise ScenarioError(f"{p}: invalid JSON: the key {exc.args[0]!r} is written twice in one object; keep one") from None
    except RecursionError:
        raise ScenarioError(f"{p}: invalid {kind}: nested deeper than the parser can read (lists or tables inside each other); flatten it") from None
    except ValueError as exc:  # an integer beyond Python's int-string conversion limit (4300 digits)
        raise ScenarioError(
            f"{p}: invalid {kind}: a number cannot be read ({' '.join(str(exc).split())}); write it as a float or fewer digits"
        ) from None
    if not isinstance(data, dict):
        raise ScenarioError(f"{p}: expected a table (JSON object) at the top level, found {type(data).__name__}")
    check_depth(data, str(p))
    return data


#: the deepest nesting of lists and tables a scenario or sweep holds (a matrix of a time-varying system is 3 deep)
MAX_DEPTH = 32


def check_depth(data: Any, source: str = "scenario") -> None:
    """Refuse data nested deeper than :data:`MAX_DEPTH` (iteratively: no recursion), naming the key where it happens.

    Linear in the size of ``data``: only the top-level key is carried along (the message names it).
    """
    stack: list[tuple[Any, int, str]] = [(data, 0, "")]
    pop, push = stack.pop, stack.append
    while stack:
        node, depth, top = pop()
        if depth > MAX_DEPTH:
            top = top or source
            raise ScenarioError(
                f"{top}: expected at most {MAX_DEPTH} levels of nested lists and tables, found more (in {source}); "
                "no scenario key is nested that deep: check the brackets",
                argument=top,
            )
        kind = type(node)
        if kind is dict or (kind is not list and isinstance(node, Mapping)):
            for k, v in node.items():
                if type(v) in (list, dict) or isinstance(v, Mapping):
                    push((v, depth + 1, top or str(k)))
        elif kind is list:
            for v in node:
                if type(v) in (list, dict) or isinstance(v, Mapping):
                    push((v, depth + 1, top))
