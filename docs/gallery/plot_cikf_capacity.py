r"""
CIKF tracking capacity (Das & Moura, Theorem 3)
===============================================

Tracking capacity on a nested family of graphs, from no links to the complete graph: the SDP, the graph-free and closed-form ceilings, and the bound with the MSE-optimal gains (see :doc:`/cikf`).

This page runs ``teamkf reproduce cikf-capacity --quick``: the same computation at a reduced size.
Columns whose name mentions the *paper* hold the published values, shown only for comparison.
"""

# %%
# Run the experiment from the registry; the figure is the PNG it writes.
import tempfile

from teamkf import experiments

result = experiments.run("cikf-capacity", tempfile.mkdtemp(), quick=True)
result

# %%
# What to know when reading the table
print(result.notes)
