"""Pictures of what simtest made and measured: dataset ground truth, evaluation runs, grasp runs.

``simtest show PATH`` (:mod:`simtest.cli.show`) calls :func:`simtest.viz.show.show`, which tells the three
kinds of folder apart by their files. Modules: :mod:`~simtest.viz.draw` (projection and drawing primitives),
:mod:`~simtest.viz.channels` (depth and dense channels as colour), :mod:`~simtest.viz.sheet` (layout, PNG),
:mod:`~simtest.viz.dataset_page`, :mod:`~simtest.viz.eval_page`, :mod:`~simtest.viz.grasp_page`.
"""
