"""Calibration of each segment's APCC parameters k and delta_max (docs/estimation.md,
"Calibrating a segment").

Holds the closed form from one measured tip pose and the least-squares fit over a recorded
sweep (:mod:`~apcc_graph.calibration.fit`), the calibration input files
(:mod:`~apcc_graph.calibration.files`) and calibration from photos of ArUco markers
(:mod:`~apcc_graph.calibration.photos`).

May import: :mod:`apcc_graph.model`, :mod:`apcc_graph.io` and :mod:`apcc_graph.frontend`.
"""

from apcc_graph.calibration.fit import calibrate_from_tip, fit_segment

__all__ = ["calibrate_from_tip", "fit_segment"]
