r"""
Information shedding: the Pareto front
======================================

Every hop-window structure of the platoon (:mod:`teamkf.network.shedding`), validated as realizable and designed exactly; the front of total local dimension against :math:`J_T^*`.

This page runs ``teamkf reproduce shedding --quick``: the same computation at a reduced size.
Columns whose name mentions the *paper* hold the published values, shown only for comparison.
"""

# %%
# Run the experiment from the registry; the figure is the PNG it writes.
import tempfile

from teamkf import experiments

result = experiments.run("shedding", tempfile.mkdtemp(), quick=True)
result

# %%
# What to know when reading the table
print(result.notes)
