"""The APCC segment transform for one scalar angle, with its derivatives in theta and in the
calibrated parameters k and delta_max: the fast path for factor-graph callbacks.

Plain ``math`` on scalars, one configuration at a time (the vectorised functions of
:mod:`~apcc_graph.model.kinematics` pay numpy's per-call overhead); the values are those of
:func:`~apcc_graph.model.kinematics.apcc_transform` and its derivatives. Transforms are
``base_T_tip``, ``(4, 4)``, in the frames of :mod:`~apcc_graph.model.kinematics`.
"""

from __future__ import annotations

import math

import numpy as np

from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.segment import Segment


def apcc_transform_scalar(theta: float, segment: Segment,
                          psi: float = 0.0) -> tuple[FloatArray, FloatArray]:
    """``apcc_transform`` and its ``d/dtheta`` for one scalar angle, ``(4, 4)`` each."""
    c = segment.link_ratio
    l1, l2 = segment.l1, segment.l2
    half = 0.5 * theta
    s, h = math.sin(half), math.cos(half)
    root = math.sqrt(1.0 - (c * s) ** 2)
    chord = l1 * root + l2 * h
    dchord = -0.5 * s * l2 * (c * h / root + 1.0)
    rate = 1.0 - segment.deviation_rate
    px, pz = chord * s, chord * h
    dpx, dpz = 0.5 * h * chord + s * dchord, -0.5 * s * chord + h * dchord
    beta = theta * rate
    cb, sb = math.cos(beta), math.sin(beta)
    cp, sp = math.cos(psi), math.sin(psi)
    vb = 1.0 - cb
    T = np.array([
        [1.0 - vb * cp * cp, -vb * sp * cp, sb * cp, cp * px],
        [-vb * sp * cp, 1.0 - vb * sp * sp, sb * sp, sp * px],
        [-sb * cp, -sb * sp, cb, pz],
        [0.0, 0.0, 0.0, 1.0],
    ])
    r = rate
    dT = np.array([
        [-r * sb * cp * cp, -r * sb * sp * cp, r * cb * cp, cp * dpx],
        [-r * sb * sp * cp, -r * sb * sp * sp, r * cb * sp, sp * dpx],
        [-r * cb * cp, -r * cb * sp, -r * sb, dpz],
        [0.0, 0.0, 0.0, 0.0],
    ])
    return T, dT


def apcc_transform_scalar_calibration(
    theta: float, segment: Segment, psi: float = 0.0
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """``T``, ``dT/dtheta``, ``dT/dk`` and ``dT/ddelta_max`` for one scalar angle, ``(4, 4)`` each.

    The scalar fast path of :func:`apcc_transform_scalar` extended with the derivatives in the two
    calibrated parameters; ``T`` and ``dT/dtheta`` are bit-for-bit those of
    :func:`apcc_transform_scalar`. ``length``, ``theta_max`` and ``psi`` are held fixed.

    Notation as in :func:`~apcc_graph.model.kinematics.apcc_in_plane`:
    ``s, h = sin(theta/2), cos(theta/2)``, ``c = k / (1 - k)``, ``root = sqrt(1 - c^2 s^2)``,
    ``chord = l1 root + l2 h`` with ``l1 = (1 - k) L``, ``l2 = k L``; the tip is
    ``p = chord (cos psi s, sin psi s, h)`` and the rotation is
    ``R(beta) = Rz(psi) Ry(beta) Rz(-psi)`` with ``beta = theta (1 - delta_max / theta_max)``.

    - ``k`` enters only ``chord`` (through ``l1``, ``l2`` and ``c``), never the rotation. With
      ``dl1/dk = -L``, ``dl2/dk = L`` and ``dc/dk = 1 / (1 - k)^2``::

          dchord/dk = -L root - l1 c s^2 / ((1 - k)^2 root) + L h
                    = L (h - (1 + c s^2) / root)

      so ``dT/dk`` has only the translation column ``dchord/dk (cos psi s, sin psi s, h)``. It is
      exactly zero at ``theta = 0`` (``chord = L`` for every k).
    - ``delta_max`` enters only ``beta``, with ``dbeta/ddelta_max = -theta / theta_max``, so
      ``dT/ddelta_max = -(theta / theta_max) dR/dbeta`` (zero translation column), where
      ``dR/dbeta = cos(beta) [n]x + sin(beta) [n]x^2`` and ``n = (-sin psi, cos psi, 0)``; this is
      the rotation block of ``dT/dtheta`` with the factor ``1 - delta_max/theta_max`` replaced.

    Bottom rows of the three derivatives are zero.
    """
    T, dT = apcc_transform_scalar(theta, segment, psi)
    c = segment.link_ratio
    s, h = math.sin(0.5 * theta), math.cos(0.5 * theta)
    root = math.sqrt(1.0 - (c * s) ** 2)
    # d/dk: translation only.
    dchord_k = segment.length * (h - (1.0 + c * s * s) / root)
    dT_dk = np.zeros((4, 4))
    dT_dk[0, 3] = math.cos(psi) * s * dchord_k
    dT_dk[1, 3] = math.sin(psi) * s * dchord_k
    dT_dk[2, 3] = h * dchord_k
    # d/ddelta_max: rotation only. dT/dtheta's rotation block is dR/dbeta times
    # dbeta/dtheta = 1 - delta_max/theta_max (> 0); swap that factor for -theta/theta_max.
    dT_dd = np.zeros((4, 4))
    dT_dd[:3, :3] = dT[:3, :3] * (-theta / segment.theta_max / (1.0 - segment.deviation_rate))
    return T, dT, dT_dk, dT_dd


def bending_transform_scalar(u: float, v: float, segment: Segment, small_theta: float
                             ) -> tuple[FloatArray, FloatArray, FloatArray]:
    """``base_T_tip`` of one bending vector ``(u, v)`` and its derivatives ``dT/du``, ``dT/dv``
    (``(4, 4)`` each): the values of :func:`~apcc_graph.model.bending.bending_transform` and
    :func:`~apcc_graph.model.bending.bending_transform_derivative`, whose conventions these
    are: ``dT/du = cos psi dT/dtheta - sin psi (dT/dpsi) / theta`` and ``dT/dv = sin psi
    dT/dtheta + cos psi (dT/dpsi) / theta``, the second term taken at ``small_theta`` below
    it. ``dT/dpsi`` is written out from the matrix of :func:`apcc_transform_scalar` (its
    entries in ``1 - cos beta``, ``sin beta`` and the tip's ``px``), so nothing cancels near
    straight."""
    theta, psi = math.hypot(u, v), math.atan2(v, u)
    T, d_theta = apcc_transform_scalar(theta, segment, psi)
    lifted = theta if theta >= small_theta else small_theta
    T_psi = T if lifted == theta else apcc_transform_scalar(lifted, segment, psi)[0]
    c, s = math.cos(psi), math.sin(psi)
    beta = lifted * (1.0 - segment.deviation_rate)
    sb, vb = math.sin(beta), 2.0 * math.sin(0.5 * beta) ** 2
    px = c * T_psi[0, 3] + s * T_psi[1, 3]
    cross = -vb * (c * c - s * s)
    d_psi = np.array([
        [2.0 * vb * c * s, cross, -sb * s, -s * px],
        [cross, -2.0 * vb * c * s, sb * c, c * px],
        [sb * s, -sb * c, 0.0, 0.0],
        [0.0, 0.0, 0.0, 0.0],
    ]) / lifted
    return T, c * d_theta - s * d_psi, s * d_theta + c * d_psi
