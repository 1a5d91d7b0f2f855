"""Estimators of the segment angles over a sequence.

Holds the options shared by every graph (:mod:`~apcc_graph.estimation.options`), graph building
shared by the batch and the smoothers (:mod:`~apcc_graph.estimation.graph`,
:mod:`~apcc_graph.estimation.epipolar_graph`, :mod:`~apcc_graph.estimation.robust`), the
paper's chain (:mod:`~apcc_graph.estimation.chain`), the batch optimiser
(:mod:`~apcc_graph.estimation.batch`), the result type (:mod:`~apcc_graph.estimation.result`)
and the one call behind ``apcc_graph.estimate`` (:mod:`~apcc_graph.estimation.methods`).

The fixed-lag smoothers:

- shared by both: their options records (:mod:`~apcc_graph.estimation.smoother_options`), the
  window and gtsam's smoother holding it (:mod:`~apcc_graph.estimation.window`), a new frame's
  initial angles (:mod:`~apcc_graph.estimation.initial_guess`);
- the projection smoother, the default (:mod:`~apcc_graph.estimation.projection_smoother`), with
  its track pieces and factors (:mod:`~apcc_graph.estimation.projection_tracks`,
  :mod:`~apcc_graph.estimation.live_tracks`) and landmarks
  (:mod:`~apcc_graph.estimation.landmarks`);
- the epipolar smoother (:mod:`~apcc_graph.estimation.smoother`, which also runs either smoother
  over a sequence), with its window (:mod:`~apcc_graph.estimation.epipolar_window`), front end
  (:mod:`~apcc_graph.estimation.epipolar_front_end`), first-estimate factors
  (:mod:`~apcc_graph.estimation.first_estimate`) and online self-calibration
  (:mod:`~apcc_graph.estimation.online_calibration`).

May import: :mod:`apcc_graph.model`, :mod:`apcc_graph.io`, :mod:`apcc_graph.frontend`,
:mod:`apcc_graph.calibration` and :mod:`factors`.
"""
