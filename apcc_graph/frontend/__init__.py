"""The front end: everything that turns two frames of one tip camera into a segment angle.

Modules (docs/estimation.md, "Two frames"):

- :mod:`~apcc_graph.frontend.geometry`: two-view geometry: relative pose, essential matrix,
  bearings, the Sampson error and its gradient, and the outlier gate on its slope;
- :mod:`~apcc_graph.frontend.basis`: the epipolar constraint of one segment on nine basis
  functions of its angle, and Sampson errors of many hypotheses through them;
- :mod:`~apcc_graph.frontend.roots`: every root of that constraint (the solver's root finding);
- :mod:`~apcc_graph.frontend.one_point`: the 1-point solver;
- :mod:`~apcc_graph.frontend.ransac`: 1-point RANSAC and robust refinement of the angle;
- :mod:`~apcc_graph.frontend.spatial_basis`: a spatial segment's epipolar constraint, exactly, in
  its bending vector;
- :mod:`~apcc_graph.frontend.eliminant`, :mod:`~apcc_graph.frontend.pair_roots`: eliminating the
  bending-plane angle between two correspondences, and every root of what is left;
- :mod:`~apcc_graph.frontend.two_point`: the 2-point solver of a spatial segment;
- :mod:`~apcc_graph.frontend.spatial_ransac`: 2-point RANSAC and robust refinement of the
  bending vector, the numpy reference and the entry point of both engines;
- :mod:`~apcc_graph.frontend.spatial_jit`, :mod:`~apcc_graph.frontend.pair_jit`,
  :mod:`~apcc_graph.frontend.ransac_jit`: the same 2-point RANSAC compiled with numba (the
  default engine): bends, Sampson errors and refinement; the pairs' coefficients, eliminant
  and roots; the sampling loop;
- :mod:`~apcc_graph.frontend.tracking`: feature tracking from images with OpenCV.

May import: :mod:`apcc_graph.model` and :mod:`apcc_graph.io` (tracking reads image folders and
writes track tables).
"""

from apcc_graph.frontend.one_point import one_point
from apcc_graph.frontend.ransac import one_point_ransac
from apcc_graph.frontend.spatial_ransac import two_point_ransac
from apcc_graph.frontend.two_point import two_point

__all__ = ["one_point", "one_point_ransac", "two_point", "two_point_ransac"]
