"""Segment kinematics, vectorised: the PCC (Webster and Jones) and APCC 2L-5R transforms, their
derivatives in theta and psi, the body twists and the derivatives in k and delta_max.

Frames (docs/estimation.md, "Conventions"). A segment's base frame has +z along the backbone
tangent. A planar segment bends in its x-z plane by a rotation about +y; ``theta > 0`` moves the
tip toward +x. A spatial segment's bending plane is turned by ``psi`` about +z:
``T(theta, psi) = Rz(psi) T(theta, 0) Rz(-psi)``. Every transform returned here is ``base_T_tip``
(it maps points in the tip frame to the base frame), as a homogeneous ``(..., 4, 4)`` array.

APCC 2L-5R (docs/estimation.md, "The robot") is a chain of five joints and two links
(:mod:`~apcc_graph.model.joint_chain` builds it joint by joint, and the tests check that the two
agree). Multiplied out, it is a closed form that this module evaluates directly: one rotation
about the axis ``n = Rz(psi) e_y`` by ``beta = theta - delta``, and an in-plane translation to
the tip, which lies on the PCC chord at ``theta/2`` from the base axis.

Derivatives come in three forms:

- :func:`apcc_transform_derivative`: the 4x4 matrix derivatives ``dT/dtheta`` and ``dT/dpsi``;
- :func:`apcc_body_twists`: body-frame twists ``xi`` in GTSAM's ``Pose3`` tangent order
  ``(omega, v)`` with GTSAM's right-hand convention, ``T(theta + e) = T(theta) Exp(e xi) + O(e^2)``;
- :func:`apcc_transform_calibration_derivative`: the matrix derivatives ``dT/dk`` and
  ``dT/ddelta_max``.

Everything broadcasts: ``theta`` and ``psi`` may be arrays of any (broadcast-compatible) shape and
the result has that shape followed by ``(4, 4)`` or ``(6,)``. The same transform and derivatives
for one scalar angle, without numpy's per-call overhead, are in
:mod:`~apcc_graph.model.scalar_kinematics`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.segment import Segment

_SERIES_LIMIT = 1e-3
"""Below this |x| the series of sin(x)/x is used: its truncation error there is < 1e-20."""


def sinc(x: ArrayLike) -> FloatArray:
    """``sin(x) / x`` with the value 1 at ``x = 0``, accurate to machine precision everywhere.

    Near zero it evaluates ``1 - x^2/6 + x^4/120`` (error below ``x^6/5040``); elsewhere the ratio,
    so no division by a small number ever happens.
    """
    x = np.asarray(x, dtype=float)
    small = np.abs(x) < _SERIES_LIMIT
    safe = np.where(small, 1.0, x)
    x2 = x * x
    return np.where(small, 1.0 - x2 / 6.0 + x2 * x2 / 120.0, np.sin(safe) / safe)


def bend_rotation_entries(beta: ArrayLike, psi: ArrayLike) -> list[list[FloatArray]]:
    """Entries ``R[r][c]`` of ``Rz(psi) Ry(beta) Rz(-psi)`` as separate broadcast arrays.

    Rodrigues' formula with the bend axis ``n = Rz(psi) e_y = (-sin psi, cos psi, 0)``:
    ``R = I + sin(beta) [n]x + (1 - cos(beta)) [n]x^2``.
    """
    beta, psi = np.broadcast_arrays(np.asarray(beta, dtype=float), np.asarray(psi, dtype=float))
    cb, sb = np.cos(beta), np.sin(beta)
    cp, sp = np.cos(psi), np.sin(psi)
    vb = 1.0 - cb
    r01 = -vb * sp * cp
    return [
        [1.0 - vb * cp * cp, r01, sb * cp],
        [r01, 1.0 - vb * sp * sp, sb * sp],
        [-sb * cp, -sb * sp, cb],
    ]


def plane_to_transform(beta: ArrayLike, px: ArrayLike, pz: ArrayLike, psi: ArrayLike) -> FloatArray:
    """Homogeneous ``Rz(psi) [Ry(beta) | (px, 0, pz)] Rz(-psi)``, broadcast, ``(..., 4, 4)``.

    Args:
        beta: tip rotation about the bend axis, radians.
        px, pz: tip position in the bending plane (metres): across and along the base axis.
        psi: bending-plane angle, radians.
    """
    beta, px, pz, psi = np.broadcast_arrays(
        *(np.asarray(a, dtype=float) for a in (beta, px, pz, psi))
    )
    out = np.zeros(beta.shape + (4, 4))
    rot = bend_rotation_entries(beta, psi)
    for r in range(3):
        for c in range(3):
            out[..., r, c] = rot[r][c]
    out[..., 0, 3] = np.cos(psi) * px
    out[..., 1, 3] = np.sin(psi) * px
    out[..., 2, 3] = pz
    out[..., 3, 3] = 1.0
    return out


def pcc_transform(theta: ArrayLike, length: float, psi: ArrayLike = 0.0) -> FloatArray:
    """Constant-curvature (PCC) segment transform ``base_T_tip`` (Webster and Jones).

    ``T = [Ry(theta) | (L/theta) (1 - cos theta, 0, sin theta)]`` turned by ``psi`` (the
    constant-curvature model). Written as ``L (sin(theta/2) sinc(theta/2), 0, sinc(theta))``, so it
    is exact and finite at ``theta = 0`` (the straight segment) with no division by theta.

    Args:
        theta: bending angle(s) in radians, any shape.
        length: arc length L in metres.
        psi: bending-plane angle(s) in radians, broadcast against ``theta``.

    Returns:
        ``(..., 4, 4)`` homogeneous transforms, the broadcast shape of ``theta`` and ``psi`` first.
    """
    theta = np.asarray(theta, dtype=float)
    px, pz = pcc_in_plane(theta, length)
    return plane_to_transform(theta, px, pz, np.asarray(psi, dtype=float))


def pcc_in_plane(theta: ArrayLike, length: float) -> tuple[FloatArray, FloatArray]:
    """PCC tip position ``(px, pz)`` in the bending plane (metres); the tip angle is theta.

    ``px = L (1 - cos theta) / theta = L sin(theta/2) sinc(theta/2)``,
    ``pz = L sin(theta) / theta = L sinc(theta)``: exact at ``theta = 0``.
    """
    theta = np.asarray(theta, dtype=float)
    half = 0.5 * theta
    return length * np.sin(half) * sinc(half), length * sinc(theta)


@dataclass(frozen=True)
class InPlaneAPCC:
    """The APCC transform in the bending plane (``psi = 0``), and its theta-derivatives.

    The tip lies on the chord: ``(px, pz) = chord * (sin(theta/2), cos(theta/2))``.
    """

    beta: FloatArray  # tip rotation angle theta - delta (radians)
    px: FloatArray  # tip position across the base axis (metres)
    pz: FloatArray  # tip position along the base axis (metres)
    dbeta: float  # d beta / d theta (a constant, 1 - delta_max / theta_max)
    dpx: FloatArray  # d px / d theta (metres per radian)
    dpz: FloatArray  # d pz / d theta (metres per radian)
    chord: FloatArray  # distance base -> tip (metres)


def apcc_in_plane(theta: ArrayLike, segment: Segment) -> InPlaneAPCC:
    """APCC tip rotation and position in the bending plane, with derivatives in theta.

    With ``s, h = sin(theta/2), cos(theta/2)`` and ``a = asin(c s)`` (so ``phi = theta/2 + a``),
    the first link points at ``theta - phi = theta/2 - a`` and the second at ``theta``. Using
    ``l1 c = l2`` the tip reduces to ``chord * (s, h)`` with
    ``chord = l1 sqrt(1 - c^2 s^2) + l2 h``: three transcendental evaluations per angle.

    Args:
        theta: bending angle(s) in radians.
        segment: the segment.

    Returns:
        ``beta = theta - delta``, the tip position ``(px, pz)``, their derivatives, the chord.
    """
    theta = np.asarray(theta, dtype=float)
    c = segment.link_ratio
    l1, l2 = segment.l1, segment.l2
    half = 0.5 * theta
    s, h = np.sin(half), np.cos(half)
    root = np.sqrt(1.0 - (c * s) ** 2)  # cos(a) > 0 because c < 1
    chord = l1 * root + l2 * h
    dchord = -0.5 * s * l2 * (c * h / root + 1.0)
    rate = 1.0 - segment.deviation_rate
    return InPlaneAPCC(
        beta=theta * rate,
        px=chord * s,
        pz=chord * h,
        dbeta=rate,
        dpx=0.5 * h * chord + s * dchord,
        dpz=-0.5 * s * chord + h * dchord,
        chord=chord,
    )


def apcc_transform(theta: ArrayLike, segment: Segment, psi: ArrayLike = 0.0) -> FloatArray:
    """APCC 2L-5R segment transform ``base_T_tip`` (docs/estimation.md, "The robot").

    The tip lies on the PCC chord at angle ``theta/2`` from the base axis, and the tip tangent is at
    ``theta - delta``. With ``k = 0.25`` and ``delta_max = 0`` it agrees with :func:`pcc_transform`
    to fourth order in theta.

    Args:
        theta: ideal bending angle(s) in radians, any shape.
        segment: the segment (length, k, delta_max, theta_max).
        psi: bending-plane angle(s) in radians, broadcast against ``theta``.

    Returns:
        ``(..., 4, 4)`` homogeneous transforms.
    """
    planar = apcc_in_plane(np.asarray(theta, dtype=float), segment)
    return plane_to_transform(planar.beta, planar.px, planar.pz, np.asarray(psi, dtype=float))


def apcc_transform_derivative(
    theta: ArrayLike, segment: Segment, psi: ArrayLike = 0.0
) -> tuple[FloatArray, FloatArray]:
    """Matrix derivatives ``(dT/dtheta, dT/dpsi)`` of :func:`apcc_transform`, each ``(..., 4, 4)``.

    The bottom rows are zero (derivatives of a homogeneous matrix).
    """
    theta = np.asarray(theta, dtype=float)
    psi = np.asarray(psi, dtype=float)
    planar = apcc_in_plane(theta, segment)
    beta, psi_b = np.broadcast_arrays(planar.beta, psi)
    px, pz, dpx, dpz = (
        np.broadcast_to(a, beta.shape) for a in (planar.px, planar.pz, planar.dpx, planar.dpz)
    )
    cb, sb = np.cos(beta), np.sin(beta)
    cp, sp = np.cos(psi_b), np.sin(psi_b)
    vb = 1.0 - cb

    d_theta = np.zeros(beta.shape + (4, 4))
    # dR/dbeta = cos(b) [n]x + sin(b) [n]x^2, times dbeta/dtheta.
    r = planar.dbeta
    d_theta[..., 0, 0] = -r * sb * cp * cp
    d_theta[..., 0, 1] = -r * sb * sp * cp
    d_theta[..., 0, 2] = r * cb * cp
    d_theta[..., 1, 0] = d_theta[..., 0, 1]
    d_theta[..., 1, 1] = -r * sb * sp * sp
    d_theta[..., 1, 2] = r * cb * sp
    d_theta[..., 2, 0] = -r * cb * cp
    d_theta[..., 2, 1] = -r * cb * sp
    d_theta[..., 2, 2] = -r * sb
    d_theta[..., 0, 3] = cp * dpx
    d_theta[..., 1, 3] = sp * dpx
    d_theta[..., 2, 3] = dpz

    d_psi = np.zeros(beta.shape + (4, 4))
    # Differentiate the entries of plane_to_transform with respect to psi.
    d_psi[..., 0, 0] = 2.0 * vb * cp * sp
    d_psi[..., 0, 1] = -vb * (cp * cp - sp * sp)
    d_psi[..., 0, 2] = -sb * sp
    d_psi[..., 1, 0] = d_psi[..., 0, 1]
    d_psi[..., 1, 1] = -2.0 * vb * sp * cp
    d_psi[..., 1, 2] = sb * cp
    d_psi[..., 2, 0] = sb * sp
    d_psi[..., 2, 1] = -sb * cp
    d_psi[..., 0, 3] = -sp * px
    d_psi[..., 1, 3] = cp * px
    return d_theta, d_psi


def apcc_transform_calibration_derivative(
    theta: ArrayLike, segment: Segment, psi: ArrayLike = 0.0
) -> tuple[FloatArray, FloatArray]:
    """Matrix derivatives ``(dT/dk, dT/ddelta_max)`` of :func:`apcc_transform`, ``(..., 4, 4)``.

    The vectorised form of
    :func:`~apcc_graph.model.scalar_kinematics.apcc_transform_scalar_calibration` (same maths):
    ``k`` moves only the tip along the chord direction,
    ``dchord/dk = L (h - (1 + c s^2) / root)``; ``delta_max`` turns only the tip,
    ``dbeta/ddelta_max = -theta / theta_max``. ``length``, ``theta_max`` and ``psi`` are held
    fixed; bottom rows are zero.
    """
    theta = np.asarray(theta, dtype=float)
    theta, psi_b = np.broadcast_arrays(theta, np.asarray(psi, dtype=float))
    c = segment.link_ratio
    s, h = np.sin(0.5 * theta), np.cos(0.5 * theta)
    root = np.sqrt(1.0 - (c * s) ** 2)
    dchord_k = segment.length * (h - (1.0 + c * s * s) / root)
    cp, sp = np.cos(psi_b), np.sin(psi_b)
    d_k = np.zeros(theta.shape + (4, 4))
    d_k[..., 0, 3] = cp * s * dchord_k
    d_k[..., 1, 3] = sp * s * dchord_k
    d_k[..., 2, 3] = h * dchord_k
    d_theta = apcc_transform_derivative(theta, segment, psi_b)[0]
    d_delta = np.zeros(theta.shape + (4, 4))
    d_delta[..., :3, :3] = d_theta[..., :3, :3] * (
        -theta / (segment.theta_max * (1.0 - segment.deviation_rate)))[..., None, None]
    return d_k, d_delta


def apcc_body_twists(
    theta: ArrayLike, segment: Segment, psi: ArrayLike = 0.0
) -> tuple[FloatArray, FloatArray]:
    """Body-frame twists ``(xi_theta, xi_psi)`` of :func:`apcc_transform`, each ``(..., 6)``.

    Convention: GTSAM ``Pose3`` tangent order ``(omega, v)`` and right-hand perturbation,
    ``T(theta + e, psi) = T(theta, psi) Exp(e xi_theta) + O(e^2)`` (likewise for psi). In matrix
    terms ``xi^ = T^-1 dT``.

    - ``xi_theta``: ``omega = (1 - delta_max/theta_max) n`` with ``n = Rz(psi) e_y`` (the bend
      axis, which is the same in base and tip frames), ``v = R^T dp/dtheta``.
    - ``xi_psi``: ``omega = R^T e_z - e_z``, ``v = R^T (e_z x p)``.
    """
    theta = np.asarray(theta, dtype=float)
    psi = np.asarray(psi, dtype=float)
    planar = apcc_in_plane(theta, segment)
    T = plane_to_transform(planar.beta, planar.px, planar.pz, psi)
    R = T[..., :3, :3]
    p = T[..., :3, 3]
    cp, sp = np.cos(psi), np.sin(psi)
    shape = T.shape[:-2]

    xi_theta = np.zeros(shape + (6,))
    xi_theta[..., 0] = -planar.dbeta * sp
    xi_theta[..., 1] = planar.dbeta * cp
    dp = np.stack(np.broadcast_arrays(cp * planar.dpx, sp * planar.dpx, planar.dpz), axis=-1)
    xi_theta[..., 3:] = np.einsum("...ji,...j->...i", R, dp)

    xi_psi = np.zeros(shape + (6,))
    xi_psi[..., 0:3] = R[..., 2, :]  # R^T e_z is the third row of R
    xi_psi[..., 2] -= 1.0
    ez_cross_p = np.stack([-p[..., 1], p[..., 0], np.zeros(shape)], axis=-1)
    xi_psi[..., 3:] = np.einsum("...ji,...j->...i", R, ez_cross_p)
    return xi_theta, xi_psi
