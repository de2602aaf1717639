r"""
CIKF vs the centralized Kalman filter (Das & Moura, Fig. 4)
===========================================================

The consensus+innovations Kalman filter on the Section VII-A random field (:func:`teamkf.study.random_field.random_field`): theory from the corrected Algorithm 2 and Monte Carlo of Algorithm 1, beside the centralized filter and the MTMSE optimum (see :doc:`/cikf`).

This page runs ``teamkf reproduce cikf-fig4 --quick``: the same computation at a reduced size.
Columns whose name mentions the *paper* hold the published values, shown only for comparison.
"""

# %%
# Run the experiment from the registry; the figure is the PNG it writes.
import tempfile

from teamkf import experiments

result = experiments.run("cikf-fig4", tempfile.mkdtemp(), quick=True)
result

# %%
# What to know when reading the table
print(result.notes)
