"""``python -m teamkf``: the command line (:func:`teamkf.cli.main`).

Ctrl-C ends as it does inside :func:`~teamkf.cli.main` (one line, exit 130) even in the few milliseconds
before it runs, while the command line's own module imports.
"""

import sys

try:
    from .cli import main
except KeyboardInterrupt:
    print("teamkf: interrupted", file=sys.stderr)
    raise SystemExit(130) from None

raise SystemExit(main())
