r"""
Table I: information shedding on the platoon
============================================

Afshari & Mahajan (2021), Table I: the full structure IS0 and the reduced structures IS1 and IS2, designed exactly with Theorem 2. The published column is shown beside ours; the own-reading bound column explains why it cannot be matched (see :doc:`/errata`).

This page runs ``teamkf reproduce table1 --quick``: the same computation at a reduced size.
Columns whose name mentions the *paper* hold the published values, shown only for comparison.
"""

# %%
# Run the experiment from the registry; the figure is the PNG it writes.
import tempfile

from teamkf import experiments

result = experiments.run("table1", tempfile.mkdtemp(), quick=True)
result

# %%
# What to know when reading the table
print(result.notes)
