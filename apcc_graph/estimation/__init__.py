"""Estimators of the segment angles over a sequence (docs/estimation.md).

- The one call behind ``apcc_graph.estimate`` (:mod:`~apcc_graph.estimation.methods`), the
  result every estimator returns (:mod:`~apcc_graph.estimation.result`) and many sequences at
  once, in process or on Dask (:mod:`~apcc_graph.estimation.many`).
- The paper's chain, frame by frame and segment by segment (:mod:`~apcc_graph.estimation.chain`).
- The start when nobody gives it: hypotheses refined by the batch over the first second,
  reported undetermined when the images cannot tell (:mod:`~apcc_graph.estimation.start_search`).
- Graph building shared by the batch and the smoother: the options
  (:mod:`~apcc_graph.estimation.options`), the projection-model terms
  (:mod:`~apcc_graph.estimation.graph`) and outlier decisions
  (:mod:`~apcc_graph.estimation.robust`).
- The batch optimiser (:mod:`~apcc_graph.estimation.batch`).
- The fixed-lag smoother (:mod:`~apcc_graph.estimation.smoother`): its options
  (:mod:`~apcc_graph.estimation.smoother_options`), its window
  (:mod:`~apcc_graph.estimation.window`), a new frame's start
  (:mod:`~apcc_graph.estimation.initial_guess`), the tracks it watches
  (:mod:`~apcc_graph.estimation.projection_tracks`, :mod:`~apcc_graph.estimation.live_tracks`)
  and its landmarks (:mod:`~apcc_graph.estimation.landmarks`); a run over a recorded sequence
  (:mod:`~apcc_graph.estimation.smoother_runs`).

May import: :mod:`apcc_graph.model`, :mod:`apcc_graph.io`, :mod:`apcc_graph.frontend`,
:mod:`apcc_graph.calibration`, :mod:`apcc_graph.simulation` and :mod:`apcc_graph.factors`; never the
evaluation, the benchmarks, the plots or the command line.
"""
