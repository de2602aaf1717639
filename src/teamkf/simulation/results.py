"""Deprecated location of :mod:`teamkf.study.results` (moved in teamkf 0.2); this alias goes in 0.3."""

import sys

import teamkf.study.results as _moved
from teamkf.study.results import *  # noqa: F401,F403

sys.modules[__name__] = _moved
