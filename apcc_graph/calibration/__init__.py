"""Calibration of each segment's APCC parameters k and delta_max (docs/estimation.md,
"Calibrating a segment").

Holds the closed form from one measured tip pose (:mod:`~apcc_graph.calibration.closed_form`),
the least-squares fit over a recorded sweep (:mod:`~apcc_graph.calibration.fit`), the calibration
input files (:mod:`~apcc_graph.calibration.files`) and calibration from photos of ArUco markers:
the folder's setup file (:mod:`~apcc_graph.calibration.image_setup`), the marker geometry and
the joint corner fit (:mod:`~apcc_graph.calibration.marker_geometry`), marker detection and
corner alignment (:mod:`~apcc_graph.calibration.marker_detection`) and the measurement of a
folder of photos (:mod:`~apcc_graph.calibration.photos`).

May import: :mod:`apcc_graph.model`, :mod:`apcc_graph.io` and :mod:`apcc_graph.frontend`.
"""

from apcc_graph.calibration.closed_form import calibrate_from_tip
from apcc_graph.calibration.fit import fit_segment

__all__ = ["calibrate_from_tip", "fit_segment"]
