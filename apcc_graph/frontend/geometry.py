"""Two-view geometry of a tip camera: relative pose, essential matrix, Sampson error.

Frames (docs/estimation.md, "Conventions" and "Two frames"). For one segment between frames
a and b::

    camA_T_camB = cam_T_tip . T(theta_a)^-1 . baseA_T_baseB . T(theta_b) . tip_T_cam

with ``T = apcc_transform`` (base_T_tip) and ``baseA_T_baseB`` the motion of the segment's base
(identity for a fixed base). Bearings ``f_a, f_b`` are unit vectors in the camera frames; the
generalized epipolar constraint is ``f_a . (t x R f_b) = f_a^T E f_b = 0`` with
``(R, t) = camA_T_camB`` and ``E = [t]x R``.

Error: the algebraic value scales with |t| and favours small motions, so the library scores
correspondences with the Sampson (first-order geometric) error for unit bearings,

    e = f_a^T E f_b / sqrt(|P_a E f_b|^2 + |P_b E^T f_a|^2),   P = I - f f^T,

which is in **radians on the bearings' tangent planes**: a pixel threshold ``px`` is ``px / focal``.
At exactly zero motion (E = 0) the constraint holds trivially and ``e`` is defined as 0, never NaN.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.kinematics import apcc_transform, apcc_transform_derivative
from apcc_graph.model.segment import Segment

_TINY = 1e-300


def skew(v: ArrayLike) -> FloatArray:
    """``[v]x`` for ``(..., 3)`` vectors, ``(..., 3, 3)``."""
    v = np.asarray(v, dtype=float)
    out = np.zeros(v.shape[:-1] + (3, 3))
    out[..., 0, 1], out[..., 0, 2] = -v[..., 2], v[..., 1]
    out[..., 1, 0], out[..., 1, 2] = v[..., 2], -v[..., 0]
    out[..., 2, 0], out[..., 2, 1] = -v[..., 1], v[..., 0]
    return out


@dataclass(frozen=True)
class SegmentTwoView:
    """The fixed parts of ``camA_T_camB(theta_b) = left @ T(theta_b) @ right`` for one segment.

    Attributes:
        segment: the segment.
        psi: bending-plane angle (radians).
        left: ``cam_T_tip . T(theta_a)^-1 . baseA_T_baseB`` (4x4).
        right: ``tip_T_cam`` (4x4).
        fixed_base: True when ``baseA_T_baseB`` is the identity, so that ``theta_b = theta_a`` is a
            trivial root of every correspondence.
        theta_a: the angle at frame a (radians).
    """

    segment: Segment
    psi: float
    left: FloatArray
    right: FloatArray
    fixed_base: bool
    theta_a: float

    @classmethod
    def build(cls, theta_a: float, segment: Segment, tip_T_cam: ArrayLike | None = None,
              baseA_T_baseB: ArrayLike | None = None, psi: float = 0.0) -> SegmentTwoView:
        """Assemble the fixed parts from frame a's angle, the mounting and the base motion."""
        right = np.eye(4) if tip_T_cam is None else np.asarray(tip_T_cam, dtype=float)
        base = np.eye(4) if baseA_T_baseB is None else np.asarray(baseA_T_baseB, dtype=float)
        if right.shape != (4, 4) or base.shape != (4, 4):
            raise ValueError("tip_T_cam and baseA_T_baseB must be 4x4 transforms")
        theta_a = float(theta_a)
        Ta = apcc_transform(theta_a, segment, psi)
        left = np.linalg.inv(right) @ np.linalg.inv(Ta) @ base
        fixed = bool(np.max(np.abs(base - np.eye(4))) < 1e-12)
        return cls(segment, float(psi), left, right, fixed, theta_a)

    def relative_pose(self, theta_b: ArrayLike) -> FloatArray:
        """``camA_T_camB`` for each theta_b, ``(..., 4, 4)``."""
        return self.left @ apcc_transform(theta_b, self.segment, self.psi) @ self.right

    def relative_pose_derivative(self, theta_b: ArrayLike) -> FloatArray:
        """``d camA_T_camB / d theta_b``, ``(..., 4, 4)``."""
        d_theta, _ = apcc_transform_derivative(theta_b, self.segment, self.psi)
        return self.left @ d_theta @ self.right


def relative_camera_pose(
    theta_a: float,
    theta_b: ArrayLike,
    segment: Segment,
    tip_T_cam: ArrayLike | None = None,
    baseA_T_baseB: ArrayLike | None = None,
    psi: float = 0.0,
) -> FloatArray:
    """``camA_T_camB`` of the camera on ``segment`` between frames a and b, ``(..., 4, 4)``.

    Args:
        theta_a: bend at frame a (radians).
        theta_b: bend(s) at frame b (radians), any shape.
        segment: the segment the camera rides on.
        tip_T_cam: camera mounting (default identity).
        baseA_T_baseB: motion of the segment's base from a to b (default identity).
        psi: bending-plane angle (radians), the same in both frames.
    """
    return SegmentTwoView.build(theta_a, segment, tip_T_cam, baseA_T_baseB, psi).relative_pose(
        theta_b)


def essential_matrix(camA_T_camB: ArrayLike) -> FloatArray:
    """``E = [t]x R`` of ``(..., 4, 4)`` relative poses, ``(..., 3, 3)``."""
    pose = np.asarray(camA_T_camB, dtype=float)
    return skew(pose[..., :3, 3]) @ pose[..., :3, :3]


def _dot(x: FloatArray, y: FloatArray) -> FloatArray:
    """Row-wise dot products over the last axis (one fused pass, no temporary)."""
    return np.einsum("...i,...i->...", x, y)


def sampson_error(f_a: ArrayLike, f_b: ArrayLike, E: ArrayLike,
                  dE: ArrayLike | None = None) -> FloatArray | tuple[FloatArray, FloatArray]:
    """Sampson error of unit bearings for one or many essential matrices (radians).

    For unit ``f_a, f_b`` the tangent-plane gradient norms simplify:
    ``|P_a E f_b|^2 + |P_b E^T f_a|^2 = |E f_b|^2 + |E^T f_a|^2 - 2 (f_a^T E f_b)^2``.

    Args:
        f_a, f_b: ``(N, 3)`` unit bearings in cameras a and b.
        E: ``(3, 3)`` or ``(M, 3, 3)`` essential matrices.
        dE: optional derivative of E with respect to a scalar parameter, same shape as E.

    Returns:
        ``e`` with shape ``(N,)`` or ``(M, N)``; with ``dE``, also ``de`` of the same shape.
    """
    f_a = np.asarray(f_a, dtype=float)
    f_b = np.asarray(f_b, dtype=float)
    E = np.asarray(E, dtype=float)
    Efb = f_b @ np.swapaxes(E, -1, -2)  # rows: E f_b
    Etfa = f_a @ E  # rows: E^T f_a
    num = _dot(f_a, Efb)
    den2 = _dot(Efb, Efb) + _dot(Etfa, Etfa) - 2.0 * num * num
    den = np.sqrt(np.maximum(den2, 0.0))
    ok = den > _TINY
    safe = np.where(ok, den, 1.0)
    e = np.where(ok, num / safe, 0.0)
    if dE is None:
        return e
    dE = np.asarray(dE, dtype=float)
    dEfb = f_b @ np.swapaxes(dE, -1, -2)
    dEtfa = f_a @ dE
    dnum = _dot(f_a, dEfb)
    dden = (_dot(Efb, dEfb) + _dot(Etfa, dEtfa)
            - 2.0 * num * dnum) / safe
    de = np.where(ok, (dnum * den - num * dden) / (safe * safe), 0.0)
    return e, de


def epipolar_errors(
    f_a: ArrayLike,
    f_b: ArrayLike,
    view: SegmentTwoView,
    theta_b: ArrayLike,
    derivative: bool = False,
) -> FloatArray | tuple[FloatArray, FloatArray]:
    """Sampson errors (radians) of correspondences for hypotheses ``theta_b``.

    Args:
        f_a, f_b: ``(N, 3)`` unit bearings.
        view: the segment's two-view set-up (frame a's angle, mounting, base motion).
        theta_b: a scalar or ``(M,)`` hypotheses (radians).
        derivative: also return ``d e / d theta_b``.

    Returns:
        ``(N,)`` or ``(M, N)`` errors (and derivatives).
    """
    pose = view.relative_pose(theta_b)
    E = essential_matrix(pose)
    if not derivative:
        return sampson_error(f_a, f_b, E)
    d_pose = view.relative_pose_derivative(theta_b)
    dE = skew(d_pose[..., :3, 3]) @ pose[..., :3, :3] + skew(pose[..., :3, 3]) @ d_pose[..., :3,
                                                                                       :3]
    return sampson_error(f_a, f_b, E, dE)
