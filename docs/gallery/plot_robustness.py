r"""
Robustness: team cost under packet drops and jitter
===================================================

Team cost (Monte Carlo, 95 % intervals) against the packet-drop probability and the extra delay (jitter) of
every link, for every registered family on the 4-vehicle platoon and the 4-UAV formation, plus MTMSE designed
for the delay bound (robust to bounded jitter). A packet that misses its deadline is replaced by the agent's
expectation of it (MTMSE, MMSE); consensus filters fuse the neighbours that delivered.

This page runs ``teamkf reproduce robustness --quick``: a coarser grid and fewer runs.
"""

# %%
# Run the experiment from the registry; the figure is the PNG it writes.
import tempfile

from teamkf import experiments

result = experiments.run("robustness", tempfile.mkdtemp(), quick=True)
result

# %%
# What to know when reading the table
print(result.notes)
