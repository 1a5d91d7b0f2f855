"""Evaluation: accuracy against ground truth and against the physical limit (Cramer-Rao bound).

Cramer-Rao bound on theta_b. Each correspondence's Sampson error ``e_i`` is, to first order, its
geometric (maximum-likelihood) residual after eliminating the unknown 3-D point, in radians on
the bearings' tangent planes. With isotropic noise of ``sigma`` radians per axis on each bearing,
``e_i ~ N(0, sigma^2)``, so the Fisher information on theta_b is ``sum_i (de_i/dtheta_b)^2 /
sigma^2`` and no unbiased estimator has a smaller standard deviation than its inverse square root.
Pixel noise maps to ``sigma = noise_px / focal`` (exact at the principal point, slightly
conservative towards the image corners).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from apcc_graph.geometry import SegmentTwoView, epipolar_errors
from apcc_graph.segment import Segment


def crlb_theta(
    f_a: ArrayLike,
    f_b: ArrayLike,
    theta_a: float,
    theta_b: float,
    segment: Segment,
    tip_T_cam: ArrayLike | None = None,
    baseA_T_baseB: ArrayLike | None = None,
    noise_px: float = 1.0,
    focal: float = 500.0,
    psi: float = 0.0,
) -> float:
    """Cramer-Rao bound (standard deviation, radians) on theta_b given theta_a.

    Args:
        f_a, f_b: ``(N, 3)`` unit bearings (ideally noise-free: the bound is evaluated there).
        theta_a: the bend at frame a (radians, known).
        theta_b: the true bend at frame b (radians).
        segment: the segment.
        tip_T_cam: camera mounting.
        baseA_T_baseB: base motion a -> b.
        noise_px: pixel noise standard deviation per axis.
        focal: focal length in pixels.
        psi: bending-plane angle (radians).

    Returns:
        The smallest achievable standard deviation of theta_b (radians); ``inf`` without
        information (e.g. no correspondences).
    """
    view = SegmentTwoView.build(theta_a, segment, tip_T_cam, baseA_T_baseB, psi)
    _, de = epipolar_errors(np.asarray(f_a, float), np.asarray(f_b, float), view, theta_b,
                            derivative=True)
    sigma = noise_px / focal
    info = float(np.sum(np.square(de))) / (sigma * sigma)
    return 1.0 / math.sqrt(info) if info > 0.0 else math.inf
