"""Deprecated location of :mod:`teamkf.study.scenario` (moved in teamkf 0.2); this alias goes in 0.3."""

import sys

import teamkf.study.scenario as _moved
from teamkf.study.scenario import *  # noqa: F401,F403

sys.modules[__name__] = _moved
