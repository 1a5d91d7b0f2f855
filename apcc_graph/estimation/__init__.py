"""Estimators of the segment angles over a sequence.

Holds the options shared by every graph (:mod:`~apcc_graph.estimation.options`), graph building
shared by the batch and the smoothers (:mod:`~apcc_graph.estimation.graph`,
:mod:`~apcc_graph.estimation.epipolar_graph`, :mod:`~apcc_graph.estimation.robust`), the
paper's chain (:mod:`~apcc_graph.estimation.chain`), the batch optimiser
(:mod:`~apcc_graph.estimation.batch`), the fixed-lag smoothers
(:mod:`~apcc_graph.estimation.projection_smoother`, the default, and
:mod:`~apcc_graph.estimation.smoother`, on epipolar residuals), their shared start-up and
window bookkeeping, the result type (:mod:`~apcc_graph.estimation.result`) and the one call
behind ``apcc_graph.estimate`` (:mod:`~apcc_graph.estimation.methods`).

May import: :mod:`apcc_graph.model`, :mod:`apcc_graph.io`, :mod:`apcc_graph.frontend`,
:mod:`apcc_graph.calibration` and :mod:`factors`.
"""
