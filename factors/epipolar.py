"""Generalized epipolar factor, in joint space: all correspondences of one tip camera, two frames.

Variables: the bending angles ``theta_a[j]`` and ``theta_b[j]`` of segments ``j = 0..i`` at frames
a and b (Vector1 values in GTSAM), where camera i rides on segment i. The kinematics enter
through the product of segment transforms, so no pose variables are needed (joint space: the
APCC chain is exact inside the residual instead of being a separate soft constraint)::

    world_T_cam(f) = world_T_base(f) . T_0(theta_f[0]) ... T_i(theta_f[i]) . tip_T_cam
    camA_T_camB    = world_T_cam(a)^-1 . world_T_cam(b)

The robot base poses ``world_T_base`` are known inputs (identity for a fixed base).

Residual (paper section IV, NOTES.md section 5): per correspondence k, the Sampson error of unit
bearings ``e_k`` (radians on the bearings' tangent planes, :mod:`apcc_graph.geometry`), whitened by
``sigma = noise_px / focal``: ``r_k = e_k / sigma`` (dimensionless). Robust loss per
correspondence: gtsam's robust noise models reweight a whole factor by one weight, so the factor
applies the m-estimator weight ``w(r_k)`` of each correspondence itself, exactly as
``noiseModel::Robust::WhitenSystem`` does for one residual: residual and Jacobian rows scaled by
``sqrt(w(r_k))``, the weight held fixed while linearising (iteratively reweighted least squares).

Jacobians: analytic, ``d r_k / d theta`` (Vector1 tangent space is the identity, so GTSAM's
right-hand convention ``x + dx`` is plain addition), from the matrix derivatives of the segment
transforms (:func:`apcc_graph.kinematics.apcc_transform_derivative`).
"""

from __future__ import annotations

from collections.abc import Sequence

import gtsam
import numpy as np
from numpy.typing import NDArray

from apcc_graph.geometry import sampson_error, skew
from apcc_graph.kinematics import apcc_transform_scalar
from apcc_graph.segment import Segment

FloatArray = NDArray[np.float64]

ROBUST_LOSSES = ("huber", "cauchy", "none")


def _chain(thetas: Sequence[float], segments: Sequence[Segment],
           psis: Sequence[float]) -> tuple[FloatArray, list[FloatArray]]:
    """``P = T_0 ... T_i`` and ``dP/dtheta_j`` for each j."""
    pairs = [apcc_transform_scalar(float(t), s, float(p))
             for t, s, p in zip(thetas, segments, psis, strict=True)]
    T = [pair[0] for pair in pairs]
    dT = [pair[1] for pair in pairs]
    n = len(T)
    prefix = [np.eye(4)]
    for j in range(n):
        prefix.append(prefix[-1] @ T[j])
    suffix = [np.eye(4)] * (n + 1)
    for j in range(n - 1, -1, -1):
        suffix[j] = T[j] @ suffix[j + 1]
    return prefix[n], [prefix[j] @ dT[j] @ suffix[j + 1] for j in range(n)]


def robust_weights(r: FloatArray, loss: str, k: float) -> FloatArray:
    """M-estimator weights of whitened residuals, the formulas of gtsam's mEstimator models.

    Huber: ``1`` for ``|r| <= k``, else ``k / |r|``; Cauchy: ``1 / (1 + (r / k)^2)``.
    """
    if loss == "none":
        return np.ones_like(r)
    a = np.abs(r)
    if loss == "huber":
        return np.where(a <= k, 1.0, k / np.maximum(a, 1e-300))
    if loss == "cauchy":
        return 1.0 / (1.0 + (r / k) ** 2)
    raise ValueError(f"robust loss {loss!r}: expected one of {ROBUST_LOSSES}")


def epipolar_residual(
    thetas_a: Sequence[float],
    thetas_b: Sequence[float],
    segments: Sequence[Segment],
    tip_T_cam: FloatArray,
    world_T_base_a: FloatArray,
    world_T_base_b: FloatArray,
    f_a: FloatArray,
    f_b: FloatArray,
    sigma: float,
    psis: Sequence[float] | None = None,
    jacobians: bool = True,
) -> tuple[FloatArray, FloatArray | None, FloatArray | None]:
    """Whitened Sampson residuals and their Jacobians (pure numpy; no robust weighting).

    Args:
        thetas_a, thetas_b: angles of segments ``0..i`` at frames a and b (radians).
        segments: those segments.
        tip_T_cam: the camera mounting on segment i.
        world_T_base_a, world_T_base_b: robot base poses at a and b.
        f_a, f_b: ``(N, 3)`` unit bearings.
        sigma: Sampson-error standard deviation (radians; pixels / focal).
        psis: bending-plane angles (default zeros).

        jacobians: also compute the Jacobians (otherwise they are ``None``).

    Returns:
        ``r`` ``(N,)``, ``J_a`` ``(N, i+1)`` and ``J_b`` ``(N, i+1)``.
    """
    psis = [0.0] * len(segments) if psis is None else list(psis)
    A, dA = _chain(thetas_a, segments, psis)
    B, dB = _chain(thetas_b, segments, psis)
    M = np.asarray(tip_T_cam, dtype=float)
    M_inv = np.linalg.inv(M)
    A_inv = np.linalg.inv(A)
    W = np.linalg.inv(world_T_base_a) @ world_T_base_b
    left = M_inv @ A_inv
    right = W @ B @ M
    pose = left @ right
    if not jacobians:
        E = skew(pose[:3, 3]) @ pose[:3, :3]
        return sampson_error(f_a, f_b, E) / sigma, None, None
    d_poses = [-(M_inv @ A_inv @ d @ A_inv) @ right for d in dA]
    d_poses += [left @ W @ d @ M for d in dB]
    R, t = pose[:3, :3], pose[:3, 3]
    E = skew(t) @ R
    dE = np.stack([skew(d[:3, 3]) @ R + skew(t) @ d[:3, :3] for d in d_poses])
    e, de = sampson_error(f_a, f_b, np.broadcast_to(E, dE.shape), dE)
    n = len(segments)
    r = e[0] / sigma
    jac = de.T / sigma  # (N, 2n)
    return r, jac[:, :n], jac[:, n:]


def epipolar_factor(
    keys_a: Sequence[int],
    keys_b: Sequence[int],
    segments: Sequence[Segment],
    tip_T_cam: FloatArray,
    world_T_base_a: FloatArray,
    world_T_base_b: FloatArray,
    f_a: FloatArray,
    f_b: FloatArray,
    sigma: float,
    loss: str = "huber",
    loss_scale: float = 1.345,
    psis: Sequence[float] | None = None,
) -> gtsam.CustomFactor:
    """A ``gtsam.CustomFactor`` over the angle keys of frames a and b (Vector1 values).

    Args:
        keys_a, keys_b: keys of ``theta[0..i]`` at frames a and b.
        segments, tip_T_cam, world_T_base_a, world_T_base_b, f_a, f_b, sigma, psis: as in
            :func:`epipolar_residual`.
        loss: ``"huber"``, ``"cauchy"`` or ``"none"``, applied per correspondence.
        loss_scale: the m-estimator's threshold in whitened units (sigmas).
    """
    if loss not in ROBUST_LOSSES:
        raise ValueError(f"robust loss {loss!r}: expected one of {ROBUST_LOSSES}")
    keys_a, keys_b = list(keys_a), list(keys_b)
    n = len(keys_a)
    f_a = np.ascontiguousarray(f_a, dtype=float)
    f_b = np.ascontiguousarray(f_b, dtype=float)
    base_a = np.asarray(world_T_base_a, dtype=float)
    base_b = np.asarray(world_T_base_b, dtype=float)
    segs = list(segments)

    def error_func(this: gtsam.CustomFactor, values: gtsam.Values,
                   H: list[np.ndarray] | None) -> np.ndarray:
        th_a = [values.atVector(k)[0] for k in keys_a]
        th_b = [values.atVector(k)[0] for k in keys_b]
        r, ja, jb = epipolar_residual(th_a, th_b, segs, tip_T_cam, base_a, base_b, f_a, f_b,
                                      sigma, psis, jacobians=H is not None)
        sw = np.sqrt(robust_weights(r, loss, loss_scale))
        if H is not None:
            assert ja is not None and jb is not None
            for j in range(n):
                H[j] = np.asfortranarray((ja[:, j] * sw)[:, None])
                H[n + j] = np.asfortranarray((jb[:, j] * sw)[:, None])
        return r * sw

    return gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(len(f_a)), keys_a + keys_b,
                              error_func)
