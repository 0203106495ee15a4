"""Robustness sweeps: a grid of estimators x conditions, run cell by cell, reported from tidy tables.

| module | owns |
|---|---|
| :mod:`~simtest.sweeps.grid` | the sweep config (estimators, factors, grasp block), the condition grid, running the cells on a back end |
| :mod:`~simtest.sweeps.cells` | the on-disk cell layout, finishing a cell, the tidy ``results.csv`` / ``summary.csv`` |
| :mod:`~simtest.sweeps.uncertainty` | each score's count ``n`` and 95 % interval (Wilson, bootstrap over targets) |
| :mod:`~simtest.sweeps.report` | ``tables.md`` and ``report.html``, read from ``results.csv`` / ``summary.csv`` only |
| :mod:`~simtest.sweeps.plots` | the report's plots, with their intervals |
"""
