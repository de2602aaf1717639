import os

import numpy as np
import pytest
from hypothesis import settings

# CI (``CI=true``, as .ci/run sets it) draws the same Hypothesis examples on every run, so a red run is
# reproducible and never a coin toss; a developer's run keeps exploring new examples (and replays the
# failures in its local example database).
settings.register_profile("ci", derandomize=True, database=None, print_blob=True)
if os.environ.get("CI"):
    settings.load_profile("ci")


@pytest.fixture
def rng():
    return np.random.default_rng(12345)
