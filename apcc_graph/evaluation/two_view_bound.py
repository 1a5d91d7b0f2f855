"""The Cramér-Rao bound of one segment's angle theta_b from two frames of its tip camera
(docs/estimation.md, "The paper's two-view experiment"): the yardstick of the 1-point solver.

To first order each correspondence's epipolar residual
``r_i = f_a^T E f_b`` is Gaussian with variance ``noise_px^2 (|J_a^T E f_b|^2 + |J_b^T E^T f_a|^2)``
where ``J`` is the derivative of a unit bearing with respect to its pixel (pinhole; the unknown
3-D point is eliminated by the epipolar constraint itself). The Fisher information on theta_b is
``sum_i (dr_i/dtheta_b)^2 / var(r_i)`` and no unbiased estimator has a smaller standard
deviation than its inverse square root. Without a camera the pixel Jacobian is replaced by
``1 / focal`` on the tangent plane (exact at the principal point; the bound is then too large
towards the image corners, where a pixel spans a smaller angle).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from apcc_graph.frontend.geometry import SegmentTwoView, skew
from apcc_graph.model.camera import TipCamera
from apcc_graph.model.segment import Segment


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
    camera: TipCamera | None = None,
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
        focal: focal length in pixels (used when ``camera`` is not given).
        psi: bending-plane angle (radians).
        camera: the camera, for exact pixel-to-bearing Jacobians (pinhole part).

    Returns:
        The smallest achievable standard deviation of theta_b (radians); ``inf`` without
        information (e.g. no correspondences).
    """
    f_a = np.asarray(f_a, dtype=float)
    f_b = np.asarray(f_b, dtype=float)
    view = SegmentTwoView.build(theta_a, segment, tip_T_cam, baseA_T_baseB, psi)
    pose = view.relative_pose(theta_b)
    d_pose = view.relative_pose_derivative(theta_b)
    E = skew(pose[:3, 3]) @ pose[:3, :3]
    dE = skew(d_pose[:3, 3]) @ pose[:3, :3] + skew(pose[:3, 3]) @ d_pose[:3, :3]
    dr = np.einsum("ni,ij,nj->n", f_a, dE, f_b)
    g_a = f_b @ E.T  # d r / d f_a
    g_b = f_a @ E  # d r / d f_b
    var = noise_px**2 * (_pixel_gain(f_a, g_a, camera, focal) + _pixel_gain(f_b, g_b, camera,
                                                                           focal))
    info = float(np.sum(dr * dr / np.maximum(var, 1e-300)))
    return 1.0 / math.sqrt(info) if info > 0.0 else math.inf


def _pixel_gain(f: np.ndarray, grad: np.ndarray, camera: TipCamera | None,
                focal: float) -> np.ndarray:
    """``|J^T grad|^2`` with J the derivative of the unit bearing f with respect to its pixel."""
    tangent = grad - np.einsum("ni,ni->n", grad, f)[:, None] * f  # (I - f f^T) grad
    if camera is None:
        return np.einsum("ni,ni->n", tangent, tangent) / focal**2
    # f = r / |r| with r = ((u - cx) / fx, (v - cy) / fy, 1): df/du = (I - f f^T) e_x / (fx |r|).
    norm_r = 1.0 / f[:, 2]  # |r| = 1 / f_z
    du = tangent[:, 0] / (camera.fx * norm_r)
    dv = tangent[:, 1] / (camera.fy * norm_r)
    return du * du + dv * dv
