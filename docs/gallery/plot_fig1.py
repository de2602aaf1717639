r"""
Fig. 1: MTMSE vs MMSE, two agents
=================================

Two agents observe a scalar :math:`x \sim N(0,1)` through :math:`y_i = x + v_i` and pay the team cost (1) of Afshari & Mahajan (2021). Both costs come from Theorem 1 (:func:`teamkf.static_team_estimate`). The improvement :math:`\Delta = (J^{mmse} - J^*)/J^*` tends to :math:`\sigma^2 / (2 (1+\sigma^2)^2)` as :math:`\lambda` grows.

This page runs ``teamkf reproduce fig1 --quick``: the same computation at a reduced size.
Columns whose name mentions the *paper* hold the published values, shown only for comparison.
"""

# %%
# Run the experiment from the registry; the figure is the PNG it writes.
import tempfile

from teamkf import experiments

result = experiments.run("fig1", tempfile.mkdtemp(), quick=True)
result

# %%
# What to know when reading the table
print(result.notes)
