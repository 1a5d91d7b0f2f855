"""The front end: everything that turns two frames of one tip camera into a segment angle.

Holds two-view geometry: bearings, the generalized epipolar constraint and its Sampson error
(:mod:`~apcc_graph.frontend.geometry`), the 1-point solver and its RANSAC
(:mod:`~apcc_graph.frontend.one_point`, docs/estimation.md, "Two frames") and feature tracking
from images with OpenCV (:mod:`~apcc_graph.frontend.tracking`).

May import: :mod:`apcc_graph.model` and :mod:`apcc_graph.io` (tracking reads image folders and
writes track tables).
"""

from apcc_graph.frontend.one_point import one_point, one_point_ransac

__all__ = ["one_point", "one_point_ransac"]
