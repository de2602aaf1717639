r"""
Bulk filter: stationarity index and thresholds (Fig. 5, Table 1)
================================================================

Abedinpour Fallah et al., Section 4.2: the stationarity index (61) against :math:`a` and the thresholds :math:`\bar a(a_f, N)`, beside the published Table 1 (see :doc:`/bulk`).

This page runs ``teamkf reproduce bulk-stationarity --quick``: the same computation at a reduced size.
Columns whose name mentions the *paper* hold the published values, shown only for comparison.
"""

# %%
# Run the experiment from the registry; the figure is the PNG it writes.
import tempfile

from teamkf import experiments

result = experiments.run("bulk-stationarity", tempfile.mkdtemp(), quick=True)
result

# %%
# What to know when reading the table
print(result.notes)
