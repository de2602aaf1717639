"""The arguments of ``teamkf deploy`` and ``teamkf agent`` (light: the parsers are built without the runtime).

:mod:`teamkf.cli` calls :func:`add_parsers`; a command imports :mod:`teamkf.study.deploy` (Zenoh, the
agents) only when it runs.
"""

from __future__ import annotations

import argparse
import math
from typing import Any, Callable


def _command(name: str) -> Callable[[Any], int]:
    """The command ``teamkf.study.deploy.<name>``, imported when it runs."""

    def run(args: Any) -> int:
        from . import deploy

        return int(getattr(deploy, name)(args))

    run.__name__ = name
    return run


def _agent_step(form: str) -> Callable[[str], tuple[int, int]]:
    """An argparse type: ``AGENT:STEP`` as two integers >= 0 (``form`` names the two in the message)."""

    def parse(text: str) -> tuple[int, int]:
        try:
            a, s = (int(v) for v in text.split(":"))
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {form} (e.g. 2:100), found {text!r}") from None
        if a < 0 or s < 0:
            raise argparse.ArgumentTypeError(f"expected {form} with both >= 0, found {text!r}")
        return a, s

    return parse


_kill_spec = _agent_step("AGENT:STEP")
_died = _agent_step("AGENT:STEPS")


def _probability(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a probability in [0, 1], found {text!r}") from None
    if not 0.0 <= v <= 1.0:
        raise argparse.ArgumentTypeError(f"expected a probability in [0, 1], found {v}")
    return v


def _seconds(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number of seconds > 0, found {text!r}") from None
    if not v > 0 or not math.isfinite(v):
        raise argparse.ArgumentTypeError(f"expected a number of seconds > 0, found {v}")
    if v < 1e-3:  # heartbeats every deadline / 4: a shorter one floods the links (teamkf.study._limits.MIN_SECONDS)
        raise argparse.ArgumentTypeError(f"expected at least 0.001 s (1 ms; heartbeats run every deadline / 4), found {v:g}")
    return v


def count(least: int, what: str, *, phrase: str | None = None) -> Callable[[str], int]:
    """An argparse type: an integer >= ``least``; the message says ``expected <what>, an integer >= <least>`` (or ``phrase``)."""
    expected = phrase or f"{what}, an integer >= {least}"

    def parse(text: str) -> int:
        try:
            v = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {expected}, found {text!r}") from None
        if v < least:
            raise argparse.ArgumentTypeError(f"expected {expected}, found {v}")
        return v

    return parse


_seed = count(0, "a seed", phrase="a non-negative integer seed")


def _run_flags(p: Any) -> None:
    p.add_argument("--estimator", metavar="NAME", help="the family the agents run (default: the scenario's first estimator other than centralized)")
    p.add_argument(
        "--deadline",
        type=_seconds,
        default=2.0,
        metavar="S",
        help="a neighbour silent for S seconds is failed (heartbeats every S/4); no step waits longer than n_agents x S (default 2)",
    )
    p.add_argument("--join-timeout", type=_seconds, default=60.0, metavar="S", help="seconds an agent waits for its neighbours to join (default 60)")
    p.add_argument(
        "--p-drop", type=_probability, default=0.0, metavar="P", help="injected loss: each message is dropped by its sender with probability P"
    )
    p.add_argument("--seed", type=_seed, metavar="S", help="seed of the injected loss (default 0)")


def add_parsers(add: Callable[[str, str], Any]) -> None:
    """Add ``deploy`` and ``agent`` to the ``teamkf`` parser (``add(name, help)`` returns a subparser)."""
    p = add("deploy", "run one OS process per agent on this machine over Zenoh (loopback) and write the estimates teamkf filter writes")
    p.add_argument("scenario", metavar="SCENARIO")
    p.add_argument(
        "--measurements", required=True, metavar="FILE", help="the recorded log (as teamkf filter reads it); each agent keeps only its own column"
    )
    p.add_argument("--map", metavar="MAP.toml", help="the topic map of a ROS 2 recording (--measurements REC.mcap): period, start, [[topics]]")
    p.add_argument("--out", required=True, metavar="FILE", help="estimates step,agent,estimator,z0,... (.csv or .parquet)")
    _run_flags(p)
    p.add_argument("--record", metavar="DROPS", help="write the team's drop record (JSON) for teamkf filter --drops")
    p.add_argument(
        "--transport", choices=("zenoh", "queue"), default="zenoh", help="zenoh: one process per agent (default); queue: threads of this process"
    )
    p.add_argument(
        "--kill", type=_kill_spec, metavar="AGENT:STEP", help="fault injection: agent AGENT's process is killed (SIGKILL) before step STEP"
    )
    p.add_argument(
        "--timeout", type=_seconds, metavar="S", help="kill agents still running after S seconds (default: 120 + join timeout + steps x deadline)"
    )
    p.add_argument("--json", action="store_true", help="print one JSON object (per-agent reports, failures, misses)")
    p.add_argument("--rate", type=_hertz, metavar="HZ", help="the agents release the log's steps at HZ per second (its sensors' rate)")
    p.add_argument(
        "--insecure", action="store_true", help="run the agents without a team key (unsigned frames; to measure what authentication costs)"
    )
    p.set_defaults(func=_command("cmd_deploy"))

    p = add("agent", "run one agent of a scenario on this machine: it talks to the others through the roster's Zenoh endpoints")
    p.add_argument("scenario", metavar="SCENARIO")
    p.add_argument("--id", type=count(0, "an agent id"), required=True, metavar="I", help="this agent's id (0-based, as in the scenario)")
    p.add_argument("--roster", required=True, metavar="FILE", help="the roster (TOML/JSON): run_id, prefix, [[agents]] id and endpoint")
    p.add_argument(
        "--measurements",
        required=True,
        metavar="FILE",
        help="a recorded log (only this agent's rows, or a team log), or '-' for stdin: one line per step, 'step,y0,...'",
    )
    p.add_argument(
        "--map", metavar="MAP.toml", help="the topic map of a ROS 2 recording (--measurements REC.mcap); only this agent's topics are read"
    )
    p.add_argument("--out", metavar="FILE", help="its estimates (.csv, .parquet or .npz); '-' prints 'step,z0,...' lines as they come")
    p.add_argument("--report", metavar="FILE", help="write its report (JSON): steps, misses, frame counts, step latency, CPU")
    p.add_argument(
        "--stream",
        metavar="FILE",
        help="append every estimate to FILE as it is computed, one row of raw little-endian float64 per step (survives a crash)",
    )
    p.add_argument(
        "--design",
        metavar="FILE",
        help="its slice of the design (.npz from teamkf design --out, or written by teamkf deploy): the agent does not design the team",
    )
    p.add_argument("--steps", type=count(1, "a number of steps"), metavar="T", help="steps to run (default: the log's, or the horizon for stdin)")
    _run_flags(p)
    p.add_argument("--kill-at", type=count(0, "a step"), metavar="STEP", help="fault injection: the process kills itself (SIGKILL) before STEP")
    p.add_argument(
        "--rejoin",
        action="store_true",
        help="a restarted agent: learn the team's current step from the neighbours, start there from the design's prior (exit 3: completed, steps before missed)",
    )
    p.add_argument("--rate", type=_hertz, metavar="HZ", help="release the log's steps at HZ per second (a recorded log played at its sensor's rate)")
    p.add_argument(
        "--insecure",
        action="store_true",
        help="run without a team key when the roster has no key_file (unsigned frames: anyone who reaches the network can steer the team)",
    )
    p.set_defaults(func=_command("cmd_agent"))
    _add_record_parser(add)
    from .roster_cmd import add_parser as add_roster_parser

    add_roster_parser(add)


def _hertz(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a rate in steps per second > 0, found {text!r}") from None
    if not (v > 0 and math.isfinite(v) and v <= 1e6):
        raise argparse.ArgumentTypeError(f"expected a rate in steps per second in (0, 1e6], found {v:g}")
    return v


def _add_record_parser(add: Callable[[str, str], Any]) -> None:
    """``teamkf record merge REPORT... --out DROPS`` (:func:`teamkf.study.agent_ops.cmd_record_merge`)."""
    m = add("record", "drop records of deployments: merge the agents' reports (teamkf agent --report) of a run on separate machines")
    m.add_argument("action", choices=("merge",), help="merge: the agents' reports -> the team's drop record")
    m.add_argument("reports", nargs="+", metavar="REPORT", help="every agent's report once (a rejoined agent: each of its processes' reports)")
    m.add_argument("--out", required=True, metavar="DROPS", help="the team's drop record (JSON) for teamkf filter --drops")
    m.add_argument(
        "--died",
        type=_died,
        action="append",
        default=[],
        metavar="AGENT:STEPS",
        help="an agent whose process died without a report, and the steps it completed (the rows of its --stream file)",
    )
    m.add_argument("--json", action="store_true", help="print one JSON object")

    def run(args: Any) -> int:
        from .agent_ops import cmd_record_merge

        return int(cmd_record_merge(args))

    m.set_defaults(func=run)
