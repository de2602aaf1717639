r"""
Fig. 5: the 4-vehicle platoon
=============================

Section IV-B of Afshari & Mahajan (2021): line graph with unit delays, cost (6). :math:`\Delta^{mmse}` and :math:`\Delta^{KCF}` against :math:`\lambda`.

This page runs ``teamkf reproduce fig5 --quick``: the same computation at a reduced size.
Columns whose name mentions the *paper* hold the published values, shown only for comparison.
"""

# %%
# Run the experiment from the registry; the figure is the PNG it writes.
import tempfile

from teamkf import experiments

result = experiments.run("fig5", tempfile.mkdtemp(), quick=True)
result

# %%
# What to know when reading the table
print(result.notes)
