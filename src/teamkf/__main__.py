"""``python -m teamkf``: the command line (:func:`teamkf.cli.main`).

Ctrl-C ends as it does inside :func:`~teamkf.cli.main` (one line, exit 130) even in the few milliseconds
before it runs, while the command line's own module imports. A Ctrl-C that lands inside a compiled module's
import can surface as another error (numpy turns it into an ImportError), so the signal itself is recorded.
"""

import signal
import sys

_interrupted: list[int] = []


def _on_interrupt(signum: int, frame: object) -> None:
    _interrupted.append(signum)
    raise KeyboardInterrupt


signal.signal(signal.SIGINT, _on_interrupt)
try:
    from .cli import main

    signal.signal(signal.SIGINT, signal.default_int_handler)
except BaseException:
    if not _interrupted:
        raise
    print("teamkf: interrupted", file=sys.stderr)
    raise SystemExit(130) from None

raise SystemExit(main())
