r"""
Fig. 3: the UAV formation
=========================

Section IV-A of Afshari & Mahajan (2021): :math:`n = 4` and :math:`10` UAVs on a complete graph with delay 2, cost (5). :math:`\Delta^{mmse}` is analytic (eqs. 35 and 47); the Kalman-consensus filter is evaluated by Monte Carlo, in its honest (delayed) and ideal (not realizable) variants.

This page runs ``teamkf reproduce fig3 --quick``: the same computation at a reduced size.
Columns whose name mentions the *paper* hold the published values, shown only for comparison.
"""

# %%
# Run the experiment from the registry; the figure is the PNG it writes.
import tempfile

from teamkf import experiments

result = experiments.run("fig3", tempfile.mkdtemp(), quick=True)
result

# %%
# What to know when reading the table
print(result.notes)
