"""Custom GTSAM factors for apcc_graph (the back end).

Conventions: the state is the bending angle of each segment at each frame, a Vector1 value
(radians); its tangent space is the identity, so GTSAM's ``x + dx`` is plain addition. Each
module holds a pure numpy residual with analytic Jacobians and a thin constructor returning a
gtsam factor (STYLE.md 4-6); this package imports only apcc_graph's maths modules (kinematics,
geometry, segment), never the estimators.

- :mod:`factors.epipolar`: the generalized epipolar factor of one tip camera between a frame and
  one or several earlier frames, in joint space (the APCC chain inside the residual), Sampson
  residuals whitened by the pixel noise, a robust loss per correspondence, optional calibration
  variables (k, delta_max), QR-compressed residuals and first-estimate linear factors.
- :mod:`factors.kinematic`: the APCC kinematic factor in pose space (base Pose3, angle, tip
  Pose3), residual in the tangent space of Pose3.
- :mod:`factors.priors`: absolute angle prior, random-walk motion prior (both gtsam C++
  factors), soft joint limits.
"""
