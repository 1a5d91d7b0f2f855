"""Custom GTSAM factors for apcc_graph (the back end).

Conventions: the state is one vector per frame in the robot's parameterisation
(:class:`~apcc_graph.model.parameterisation.Bending`: an angle per segment in fixed bending
planes, or a bending vector per segment), radians; its tangent space is the identity, so
GTSAM's ``x + dx`` is plain addition. Self-calibration adds a ``Vector2`` ``(k, delta_max)``
per segment and a ``Pose3`` mounting per camera, whose tangent is gtsam's (``T . Exp(xi)``,
``xi = (omega, v)`` in the camera frame). The maths (residuals with analytic Jacobians) is pure
numpy, apart from the thin code that hands it to gtsam; docs/estimation.md derives it.

May import: :mod:`apcc_graph.model` and :mod:`apcc_graph.frontend`, never the estimators. The
folder sits at the top of the repository and installs as ``apcc_graph.factors``.

Modules:

- :mod:`apcc_graph.factors.camera_chain`: tip-camera poses along the APCC chain and their
  derivatives in the frame vector's components, and the chain that fixes one camera's poses.
- :mod:`apcc_graph.factors.track_points`: one camera's tracks and their observation model (whitened
  reprojection errors).
- :mod:`apcc_graph.factors.triangulation`: each track's point for given camera poses (inverse-depth
  Levenberg-Marquardt, robust variant).
- :mod:`apcc_graph.factors.reduced_system`: the projection model's Gauss-Newton system in the
  frame vectors, each track's point eliminated (Schur complement).
- :mod:`apcc_graph.factors.projection`: the projection factor over a chunk of tracks
  (Cholesky-compressed reduced system), its keys, and chunking of tracks.
- :mod:`apcc_graph.factors.landmark`: landmarks (points kept as variables) and camera-pose
  variables tied to the angles.
- :mod:`apcc_graph.factors.kinematic`: the APCC kinematic factor in pose space (base Pose3, angle,
  tip Pose3), residual in the tangent space of Pose3.
- :mod:`apcc_graph.factors.drifting_tie`: consecutive frames' kinematic ties of a segment
  correlated in time (a model error that drifts, a Gauss-Markov process).
"""
