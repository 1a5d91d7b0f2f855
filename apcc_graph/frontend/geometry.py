"""Two-view geometry of a tip camera: relative pose, essential matrix, Sampson error, slope gate.

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

This module is the one home of the Sampson error (:func:`sampson_terms`, used by
:func:`sampson_error`, :func:`sampson_gradient`, the basis expansion of
:mod:`~apcc_graph.frontend.basis` and the epipolar factor) and of the outlier gate on its slope
(:func:`slope_gate`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.kinematics import apcc_transform, apcc_transform_derivative
from apcc_graph.model.segment import Segment

_TINY = 1e-300
SLOPE_OUTLIER = 100.0
"""A correspondence whose Sampson slope exceeds this multiple of the median slope of its frame
pair is ill-posed (near the epipole the Sampson error's denominator vanishes)."""


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


def sampson_terms(num: FloatArray, norms2: FloatArray, floor: float = _TINY,
                  differential: bool = False
                  ) -> FloatArray | tuple[FloatArray, FloatArray, FloatArray]:
    """The Sampson error of unit bearings from its products (any shape, element-wise).

    With ``n = f_a^T E f_b`` (``num``) and ``s = |E f_b|^2 + |E^T f_a|^2`` (``norms2``), the
    tangent-plane gradient norms of unit bearings simplify to
    ``|P_a E f_b|^2 + |P_b E^T f_a|^2 = s - 2 n^2 = d^2``, and ``e = n / d``. Differentiating,

        de = a dn - b ds / 2,   a = 1/d + 2 n^2/d^3,   b = n / d^3,

    with ``ds / 2 = E f_b . dE f_b + E^T f_a . dE^T f_a``. Where ``d <= floor`` (no motion) the
    error and both coefficients are 0, never NaN.

    Returns:
        ``e``; with ``differential``, ``(e, a, b)``.
    """
    den = np.sqrt(np.maximum(norms2 - 2.0 * num * num, 0.0))
    ok = den > floor
    inv = np.where(ok, 1.0 / np.where(ok, den, 1.0), 0.0)
    e = num * inv
    if not differential:
        return e
    b = e * inv * inv
    return e, inv + 2.0 * num * b, b


def sampson_error(f_a: ArrayLike, f_b: ArrayLike, E: ArrayLike,
                  dE: ArrayLike | None = None) -> FloatArray | tuple[FloatArray, FloatArray]:
    """Sampson error of unit bearings for one or many essential matrices (radians).

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
    norms2 = _dot(Efb, Efb) + _dot(Etfa, Etfa)
    if dE is None:
        return sampson_terms(num, norms2)
    e, a, b = sampson_terms(num, norms2, differential=True)
    dE = np.asarray(dE, dtype=float)
    dEfb = f_b @ np.swapaxes(dE, -1, -2)
    dEtfa = f_a @ dE
    return e, a * _dot(f_a, dEfb) - b * (_dot(Efb, dEfb) + _dot(Etfa, dEtfa))


def sampson_gradient(f_a: FloatArray, f_b: FloatArray, E: FloatArray,
                     floor: float = _TINY) -> tuple[FloatArray, FloatArray]:
    """Sampson errors ``e`` ``(N,)`` and their gradients ``G = de/dE``, flattened ``(N, 9)``.

    ``E`` is ``(N, 3, 3)``, one essential matrix per correspondence. By :func:`sampson_terms`,
    ``de/dE = a f_a f_b^T - b (E f_b f_b^T + f_a f_a^T E)``. Zero where the denominator is at
    most ``floor`` (no motion).
    """
    Efb = np.einsum("nij,nj->ni", E, f_b)
    Etfa = np.einsum("nji,nj->ni", E, f_a)
    num = np.einsum("ni,ni->n", f_a, Efb)
    norms2 = np.einsum("ni,ni->n", Efb, Efb) + np.einsum("ni,ni->n", Etfa, Etfa)
    e, a, b = sampson_terms(num, norms2, floor, differential=True)
    c = b[:, None, None]
    G = (f_a[:, :, None] * (f_b[:, None, :] * a[:, None, None] - c * Etfa[:, None, :])
         - c * Efb[:, :, None] * f_b[:, None, :])
    return e, G.reshape(len(e), 9)


def slope_gate(slopes: ArrayLike) -> NDArray[np.bool_]:
    """Which correspondences of one frame pair have a sane Sampson slope ``de / d theta``.

    Near the epipole the Sampson error's denominator vanishes and its slope explodes: such a
    correspondence carries no parallax information, only ill-conditioning. A correspondence is
    kept when ``|slope| < SLOPE_OUTLIER * median |slope|``, with numpy's median (the mean of
    the two middle values for an even count: the textbook definition, symmetric in the data)
    floored at ``1e-12`` so that a pair without motion keeps nothing rather than NaN.

    Args:
        slopes: ``(N,)`` Sampson slopes (any sign) of one frame pair's correspondences.

    Returns:
        ``(N,)`` mask, True for the correspondences to keep.
    """
    slope = np.abs(np.asarray(slopes, dtype=float))
    if slope.size == 0:
        return np.zeros(slope.shape, dtype=bool)
    return slope < SLOPE_OUTLIER * max(float(np.median(slope)), 1e-12)


def checked_bearings(f_a: ArrayLike, f_b: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """``(N, 3)`` float arrays of two sets of bearings (one bearing ``(3,)`` becomes ``(1, 3)``).

    Raises:
        ValueError: the shapes differ or are not ``(N, 3)``.
    """
    f_a = np.asarray(f_a, dtype=float)
    f_b = np.asarray(f_b, dtype=float)
    if f_a.ndim == 1 and f_a.shape == (3,):
        f_a = f_a[None]
    if f_b.ndim == 1 and f_b.shape == (3,):
        f_b = f_b[None]
    if f_a.ndim != 2 or f_a.shape[1] != 3 or f_a.shape != f_b.shape:
        raise ValueError(f"f_a has shape {f_a.shape} and f_b {f_b.shape}: expected the same "
                         "(N, 3) unit bearings")
    return f_a, f_b


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
