r"""
Decentralized LQG with one-step delayed sharing
===============================================

Appendix D of Afshari & Mahajan (2021): Theorem 4's controller through MTMSE against certainty equivalence, analytically and by closed-loop Monte Carlo.

This page runs ``teamkf reproduce lqg --quick``: the same computation at a reduced size.
Columns whose name mentions the *paper* hold the published values, shown only for comparison.
"""

# %%
# Run the experiment from the registry; the figure is the PNG it writes.
import tempfile

from teamkf import experiments

result = experiments.run("lqg", tempfile.mkdtemp(), quick=True)
result

# %%
# What to know when reading the table
print(result.notes)
