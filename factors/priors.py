"""Priors on the bending angles (Vector1 values): absolute, motion between frames, joint limits.

- :func:`angle_prior`: ``r = (theta - theta0) / sigma`` (gtsam ``PriorFactorVector``, C++).
- :func:`motion_prior`: random walk between consecutive frames,
  ``r = (theta_b - theta_a) / (sigma_rate * sqrt(dt))`` with ``sigma_rate`` in rad/sqrt(s)
  (gtsam ``BetweenFactorVector``, C++).
- :func:`joint_limit_factor`: soft limit, ``r = max(0, |theta| - theta_max) / sigma``, zero inside
  the range; Jacobian ``sign(theta) / sigma`` outside, 0 inside (Python CustomFactor).
"""

from __future__ import annotations

import math

import gtsam
import numpy as np


def angle_prior(key: int, theta: float, sigma: float) -> gtsam.PriorFactorVector:
    """Absolute prior on one angle (radians)."""
    return gtsam.PriorFactorVector(key, np.array([float(theta)]),
                                   gtsam.noiseModel.Isotropic.Sigma(1, sigma))


def motion_prior(key_a: int, key_b: int, sigma_rate: float,
                 dt: float) -> gtsam.BetweenFactorVector:
    """Random-walk prior between the same segment's angle at two frames ``dt`` seconds apart."""
    sigma = sigma_rate * math.sqrt(max(dt, 1e-9))
    return gtsam.BetweenFactorVector(key_a, key_b, np.zeros(1),
                                     gtsam.noiseModel.Isotropic.Sigma(1, sigma))


def joint_limit_residual(theta: float, theta_max: float, sigma: float) -> tuple[float, float]:
    """Residual and derivative of the soft joint limit."""
    excess = abs(theta) - theta_max
    if excess <= 0.0:
        return 0.0, 0.0
    return excess / sigma, math.copysign(1.0, theta) / sigma


def joint_limit_factor(key: int, theta_max: float, sigma: float) -> gtsam.CustomFactor:
    """Soft joint limit ``|theta| <= theta_max`` (radians), ``sigma`` the softness."""

    def error_func(this: gtsam.CustomFactor, values: gtsam.Values,
                   H: list[np.ndarray] | None) -> np.ndarray:
        r, d = joint_limit_residual(values.atVector(key)[0], theta_max, sigma)
        if H is not None:
            H[0] = np.array([[d]])
        return np.array([r])

    return gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(1), [key], error_func)
