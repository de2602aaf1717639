"""Deprecated location of :mod:`teamkf.study.random_field` (moved in teamkf 0.2); this alias goes in 0.3."""

import sys

import teamkf.study.random_field as _moved
from teamkf.study.random_field import *  # noqa: F401,F403

sys.modules[__name__] = _moved
