"""Deployment runtime: teamkf agents as real processes on a real network.

The same online agents the in-process runtime runs (``design.graph_agents()``,
:func:`teamkf.estimators.base.pass_messages`), one per process (or thread),
exchanging their payloads as frames of the package's own versioned format,
every one signed with HMAC-SHA256 under the team key, over a :class:`Transport`
— Zenoh by default (``pip install 'teamkf[deploy]'``), or in-process queues. Each agent holds only its own measurements and its own
design, waits at every step for the messages due (a step barrier with a
deadline), fuses them in the graph's order, and records what it missed; the
record replays in-process to the same bits.

==========================  ==========================================================
:mod:`.codec`               the frame: header, typed raw arrays, HMAC-SHA256 tag (version 2)
:mod:`.payload`             the payload structure each sender's design sends (checked on every frame)
:mod:`.transport`           :class:`Transport`, :class:`ZenohTransport`, :class:`QueueTransport`
:mod:`.agent`               :func:`run_agent`: barrier, deadline, loss injection, drop record
:mod:`.replay`              :class:`DropRecord` and :func:`replay` (in-process, bit for bit)
:mod:`.roster`              :class:`Roster`: agents and their endpoints
:mod:`.launcher`            :func:`launch`: one process per agent, none left behind
==========================  ==========================================================

The CLI (``teamkf deploy``, ``teamkf agent``, ``teamkf filter --drops``) reaches it
through :mod:`teamkf.study.deploy`; how to run it is in docs/deploy.md.
"""

from .agent import AgentCore, AgentResult, DeployError, Mailbox, check_deployable, run_agent
from .codec import Frame, FrameError, decode_frame, encode_frame
from .launcher import ChildResult, launch
from .replay import DropRecord, replay
from .roster import Roster, free_ports
from .transport import QueueHub, QueueTransport, Transport, TransportError, ZenohTransport

__all__ = [
    "AgentCore",
    "AgentResult",
    "ChildResult",
    "DeployError",
    "DropRecord",
    "Frame",
    "FrameError",
    "Mailbox",
    "QueueHub",
    "QueueTransport",
    "Roster",
    "Transport",
    "TransportError",
    "ZenohTransport",
    "check_deployable",
    "decode_frame",
    "encode_frame",
    "free_ports",
    "launch",
    "replay",
    "run_agent",
]
