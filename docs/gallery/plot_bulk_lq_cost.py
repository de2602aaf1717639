r"""
Bulk filter: average LQ cost against the feedback gain (Figs. 10-11)
====================================================================

Abedinpour Fallah et al., Section 4.5: the exact expected cost of the closed loop against the Monte Carlo estimate with explicit agents, for :math:`a = 2` and :math:`a = 5`.

This page runs ``teamkf reproduce bulk-lq-cost --quick``: the same computation at a reduced size.
Columns whose name mentions the *paper* hold the published values, shown only for comparison.
"""

# %%
# Run the experiment from the registry; the figure is the PNG it writes.
import tempfile

from teamkf import experiments

result = experiments.run("bulk-lq-cost", tempfile.mkdtemp(), quick=True)
result

# %%
# What to know when reading the table
print(result.notes)
