r"""
Bulk filter: the persistently time-varying regime (Figs. 7-9)
=============================================================

Abedinpour Fallah et al., Section 4.4: :math:`a = 5`, :math:`f = 4.5`; exact gains, cross-covariance and variance of the population mean, and the period of the oscillation for several :math:`N`.

This page runs ``teamkf reproduce bulk-timevarying --quick``: the same computation at a reduced size.
Columns whose name mentions the *paper* hold the published values, shown only for comparison.
"""

# %%
# Run the experiment from the registry; the figure is the PNG it writes.
import tempfile

from teamkf import experiments

result = experiments.run("bulk-timevarying", tempfile.mkdtemp(), quick=True)
result

# %%
# What to know when reading the table
print(result.notes)
