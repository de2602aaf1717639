"""The arguments of ``teamkf filter`` and ``teamkf measurements convert`` (light: built without numpy or MCAP).

:mod:`teamkf.cli` calls :func:`add_filter_parser` and :func:`add_parsers`; ``measurements convert`` imports
:mod:`teamkf.study.recording` only when it runs.
"""

from __future__ import annotations

from typing import Any, Callable

__all__ = ["add_filter_parser", "add_parsers"]


def _convert(args: Any) -> int:
    from .recording import cmd_convert

    return cmd_convert(args)


def add_filter_parser(add: Callable[[str, str], Any], func: Callable[[Any], int], positive_int: Callable[[str], int]) -> None:
    """``teamkf filter`` (its command is :func:`teamkf.cli._cmd_filter`)."""
    p = add("filter", "filter recorded measurements with every estimator of a scenario (CSV, Parquet, NPZ or MCAP in; CSV, Parquet or MCAP out)")
    p.add_argument("scenario", metavar="SCENARIO")
    p.add_argument(
        "--measurements",
        required=True,
        metavar="FILE",
        help="long form step,agent,y0,... (.csv/.parquet), one array per agent (.npz), or a ROS 2 recording (.mcap, with --map); NaN or absent = missing",
    )
    p.add_argument(
        "--truth",
        metavar="FILE",
        help="the true states step,x0,... (.csv/.parquet), .npz key 'x', or a recording's [[truth]] topics (.mcap): adds the realized team cost",
    )
    p.add_argument(
        "--out",
        required=True,
        metavar="FILE",
        help="estimates step,agent,estimator,z0,... (.csv or .parquet; with --truth also FILE-cost.csv/.parquet) or ROS 2 topics /teamkf/<estimator>/agent<i> (.mcap)",
    )
    p.add_argument(
        "--map", metavar="MAP.toml", help="the topic map of a recording: period, start, [[topics]] topic, agent, fields (needed with .mcap)"
    )
    p.add_argument("--estimators", nargs="+", metavar="NAME", help="estimators to run (default: the scenario's)")
    p.add_argument("--json", action="store_true", help="print one JSON object (steps, estimators, realized total costs)")
    p.add_argument(
        "--chunk-rows", type=positive_int, default=400_000, metavar="N", help="steady-state scenarios are streamed N rows at a time (default 400000)"
    )
    drops_help = "replay a deployment in-process from its drop record (teamkf deploy --record): the same estimates, bit for bit"
    p.add_argument("--drops", metavar="DROPS", help=drops_help)
    p.set_defaults(func=func)


def add_parsers(add: Callable[..., Any]) -> None:
    """``teamkf measurements convert``."""
    p = add("measurements", "convert recorded measurements: a ROS 2 recording (MCAP) to a table, or back")
    sub = p.add_subparsers(dest="measurements_command", metavar="ACTION", required=True)
    c = add(
        "convert",
        "a recording (.mcap) to a table (step,agent,y0,... .csv/.parquet or .npz), or a table to a recording "
        "(one topic per [[topics]] entry of the map, a message type made from its fields, stamps start + k x period)",
        sub,
    )
    c.add_argument("input", metavar="IN", help="the recording (.mcap) or the table (.csv, .parquet, .npz)")
    c.add_argument("--map", required=True, metavar="MAP.toml", help="the topic map: period, start, [[topics]] topic, agent, fields")
    c.add_argument("--out", required=True, metavar="OUT", help="the table (.csv, .parquet, .npz) or the recording (.mcap)")
    c.set_defaults(func=_convert)
