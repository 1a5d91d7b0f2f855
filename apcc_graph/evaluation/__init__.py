"""How good an estimate is: accuracy against ground truth and the Cramér-Rao bounds.

Holds the accuracy report: RMS per segment and per window (:mod:`~apcc_graph.evaluation.accuracy`),
the bound of one segment's angle from two frames (:mod:`~apcc_graph.evaluation.two_view_bound`)
and the bound of every angle of a whole sequence, with each track's point a nuisance and,
optionally, the models unknown or a fixed lag (:mod:`~apcc_graph.evaluation.sequence_bound`;
docs/estimation.md, "The yardstick").

May import: every layer below it (model, io, frontend, calibration, simulation, factors,
estimation).
"""
