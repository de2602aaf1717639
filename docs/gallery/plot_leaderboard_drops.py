r"""
Leaderboard under packet drops: every filter with its rule for lost messages
============================================================================

The leaderboard's families on the UAV formation n = 4 and the platoon when every packet is dropped with
probability p = 0.1 or 0.5: each family runs in the message-passing runtime with the behaviour for lost
messages that its literature gives, its published defaults and its tuned form (the options the exact
leaderboard picked), beside the drop-aware design ``mtmse_lossy`` designed for each p. The team cost is a Monte
Carlo estimate (common random numbers, 95 % intervals) relative to MTMSE's under the same drops; the
drop-aware design's exact expected cost is the column ``J_T exact``.

This page runs ``teamkf reproduce leaderboard-drops --quick``: a short horizon and few runs.
"""

# %%
# Run the experiment from the registry; the figure is the PNG it writes.
import tempfile

from teamkf import experiments

result = experiments.run("leaderboard-drops", tempfile.mkdtemp(), quick=True)
result

# %%
# What to know when reading the table
print(result.notes)
