"""Evaluation: an estimator over a BOP dataset, scored against its ground truth.

| module | owns |
|---|---|
| :mod:`~simtest.evaluation.run` | :func:`~simtest.evaluation.run.evaluate`: estimator over a dataset -> results CSV, ``metrics.json``, ``errors.csv``, ``failures.csv``, tables; ``score_results`` for a BOP results file |
| :mod:`~simtest.evaluation.images` | what an estimator sees of one image, one guarded call, scenes as units of work on a back end |
| :mod:`~simtest.evaluation.scoring` | matching of estimates to targets, per-target errors, aggregates |
| :mod:`~simtest.evaluation.tracking` | tracking scores and outputs of a sequence evaluation |
| :mod:`~simtest.evaluation.tables` | evaluation tables laid out from the metric registry |
| :mod:`~simtest.evaluation.detection` | the BOP24 6D detection task (estimators told no targets) and the classification table |
"""
