"""Custom GTSAM factors for apcc_graph (the back end; filled in by the back-end work).

What goes here, one module per factor (see DESIGN.md and STYLE.md 4-6):

- the APCC kinematic factor tying a segment's base pose, its angle and its tip pose;
- the generalized epipolar factor: Sampson-type residuals of all correspondences of one tip
  camera between two frames, with a robust loss per correspondence;
- priors: robot base, motion between consecutive angles, soft joint limits, calibration variables.

Each module holds a pure numpy ``*_residual`` function returning the residual and its analytic
Jacobians (GTSAM's right-hand convention ``x * Exp(dx)``), and a thin constructor that wraps it in
``gtsam.CustomFactor``. This package imports only apcc_graph's maths modules (kinematics, robot,
geometry), never the estimators.
"""
