"""Estimators of the segment bends over a sequence (docs/estimation.md).

- The one call behind ``apcc_graph.estimate`` (:mod:`~apcc_graph.estimation.methods`), the
  options it takes, one record per concern (:mod:`~apcc_graph.estimation.options`), the
  result every estimator returns (:mod:`~apcc_graph.estimation.result`) and many sequences at
  once, in process or on Dask (:mod:`~apcc_graph.estimation.many`).
- The one parameterisation every estimator solves for, and the way back to angles and planes
  (:mod:`~apcc_graph.estimation.bends`): a planar robot is the case of fixed bending planes.
- The two-frame front end, segment by segment with the 1-point or 2-point solver
  (:mod:`~apcc_graph.estimation.front_end`), and the paper's chain that runs it over a
  recording (:mod:`~apcc_graph.estimation.chain`).
- The start when nobody gives it: hypotheses refined by the batch over the first second,
  reported undetermined when the images cannot tell (:mod:`~apcc_graph.estimation.start_search`).
- Graph building shared by the batch and the smoother: the projection-model terms
  (:mod:`~apcc_graph.estimation.graph`) and outlier decisions
  (:mod:`~apcc_graph.estimation.robust`); every gtsam key is in :mod:`apcc_graph.factors.keys`.
- Two measurement models, the exact model and model error as noise, chosen in one place for
  the batch (:mod:`~apcc_graph.estimation.terms`) and for the smoother
  (:mod:`~apcc_graph.estimation.smoother.measurement`).
- The batch optimiser (:mod:`~apcc_graph.estimation.batch`, one robust loop over either
  model: :mod:`~apcc_graph.estimation.batch_solve`).
- The fixed-lag smoother (:mod:`~apcc_graph.estimation.smoother`: its stages, the only owner
  of iSAM2, the gap detectors and the restarts), its options
  (:mod:`~apcc_graph.estimation.smoother_options`), its window
  (:mod:`~apcc_graph.estimation.window`), a new frame's start
  (:mod:`~apcc_graph.estimation.initial_guess`), the tracks it watches
  (:mod:`~apcc_graph.estimation.projection_tracks`, :mod:`~apcc_graph.estimation.live_tracks`,
  :mod:`~apcc_graph.estimation.tip_tracks`) and its landmarks
  (:mod:`~apcc_graph.estimation.landmarks`); a run over a recorded sequence
  (:mod:`~apcc_graph.estimation.smoother_runs`).

May import: :mod:`apcc_graph.model`, :mod:`apcc_graph.io`, :mod:`apcc_graph.frontend`,
:mod:`apcc_graph.calibration`, :mod:`apcc_graph.simulation` and :mod:`apcc_graph.factors`; never the
evaluation, the benchmarks, the plots or the command line.
"""
