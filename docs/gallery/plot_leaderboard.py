r"""
Leaderboard: every distributed filter against the exact team optimum
====================================================================

Every registered family and variant (local, diffusion, covariance intersection, KCF, ICF, HCMCI, CIKF, per-agent
MMSE) on the same delayed graphs, ranked by its **exact** analytic team cost relative to MTMSE (the team optimum
for what the graph delivers) and beside the centralized bound. ``honest`` variants exchange once per step over the
graph's edges and delays and delay-compensate what they receive; ``ideal`` ones exchange within the step, as
their papers assume, and can therefore go below MTMSE. No honest filter can: a property test checks it.

This page runs ``teamkf reproduce leaderboard --quick``: fewer and smaller networks. Under packet drops:
``teamkf reproduce leaderboard-drops``.
"""

# %%
# Run the experiment from the registry; the figure is the PNG it writes.
import tempfile

from teamkf import experiments

result = experiments.run("leaderboard", tempfile.mkdtemp(), quick=True)
result

# %%
# What to know when reading the table
print(result.notes)
