"""Deprecated location of :mod:`teamkf.study.evaluate` (moved in teamkf 0.2); this alias goes in 0.3."""

import sys

import teamkf.study.evaluate as _moved
from teamkf.study.evaluate import *  # noqa: F401,F403

sys.modules[__name__] = _moved
