r"""
Finite-memory bulk filters: stabilization map (Fig. 12)
=======================================================

Abedinpour Fallah et al., Sections 4.1 and 4.6: memory-:math:`n` gains (Theorem 2) on a grid of :math:`(a, a_f)`, one closed-loop run of explicit agents per point.

This page runs ``teamkf reproduce bulk-stabilization --quick``: the same computation at a reduced size.
Columns whose name mentions the *paper* hold the published values, shown only for comparison.
"""

# %%
# Run the experiment from the registry; the figure is the PNG it writes.
import tempfile

from teamkf import experiments

result = experiments.run("bulk-stabilization", tempfile.mkdtemp(), quick=True)
result

# %%
# What to know when reading the table
print(result.notes)
