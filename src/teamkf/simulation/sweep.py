"""Deprecated location of :mod:`teamkf.study.sweep` (moved in teamkf 0.2); this alias goes in 0.3."""

import sys

import teamkf.study.sweep as _moved
from teamkf.study.sweep import *  # noqa: F401,F403

sys.modules[__name__] = _moved
