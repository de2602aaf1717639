r"""
Bulk filter: discrepancy index (Fig. 6)
=======================================

Abedinpour Fallah et al., Sections 4.2-4.3: the exact bulk-filter gains against the isolated Kalman FIR sequence, with the gain vectors the paper prints (see :doc:`/bulk`).

This page runs ``teamkf reproduce bulk-discrepancy --quick``: the same computation at a reduced size.
Columns whose name mentions the *paper* hold the published values, shown only for comparison.
"""

# %%
# Run the experiment from the registry; the figure is the PNG it writes.
import tempfile

from teamkf import experiments

result = experiments.run("bulk-discrepancy", tempfile.mkdtemp(), quick=True)
result

# %%
# What to know when reading the table
print(result.notes)
