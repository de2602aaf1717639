"""Deprecated location of :mod:`teamkf.estimators.kcf` (moved in teamkf 0.2); this alias goes in 0.3."""

import sys

import teamkf.estimators.kcf as _moved
from teamkf.estimators.kcf import *  # noqa: F401,F403

sys.modules[__name__] = _moved
