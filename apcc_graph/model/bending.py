"""A spatial segment's bend as one vector: ``b = theta (cos psi, sin psi)``.

A segment that bends in 3-D has a bending angle ``theta >= 0`` and a bending-plane angle ``psi``
(:mod:`~apcc_graph.model.kinematics`: ``T(theta, psi) = Rz(psi) T(theta, 0) Rz(-psi)``). At
``theta = 0`` every ``psi`` gives the same straight segment, so ``psi`` is undefined there and
``(theta, psi)`` is a poor unknown near straight: a step through straight turns ``psi`` by pi.
The *bending vector* ``b = (u, v) = theta (cos psi, sin psi)`` has neither problem. The transform
is smooth in it: the rotation is about ``n = (-sin psi, cos psi, 0)`` by ``beta = theta -
delta(theta)``, i.e. the rotation vector ``(1 - delta_max/theta_max) (-v, u, 0)``, linear in
``b``; the tip is ``px(theta) (cos psi, sin psi, 0) + pz(theta) e_z`` with ``px`` odd and ``pz``
even in ``theta``, so ``(px / theta) (u, v, 0) + pz e_z`` is smooth too. A planar robot is the
special case ``v = 0`` with ``u = theta`` of either sign.

Conventions: ``base_T_tip`` transforms, radians; ``theta`` returned by :func:`polar` is
``|b| >= 0`` and ``psi`` in ``(-pi, pi]`` (0 for a straight segment). Derivatives are matrix
derivatives ``dT/du, dT/dv``, bottom rows zero; they are the chain rule of ``(dT/dtheta,
dT/dpsi)`` with ``dtheta = cos psi du + sin psi dv`` and ``dpsi = (-sin psi du + cos psi dv) /
theta``. ``dT/dpsi`` vanishes like ``theta``, so ``(dT/dpsi) / theta`` has a finite limit; below
:data:`SMALL_THETA` it is evaluated at ``SMALL_THETA`` (an error of order ``SMALL_THETA``
times the segment's length, 1e-8: its terms in ``1 - cos beta`` are second order).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.kinematics import apcc_transform, apcc_transform_derivative
from apcc_graph.model.segment import Segment

SMALL_THETA = 1e-8
"""Below this bend (radians) the ``psi`` derivative is taken at this bend instead."""


def polar(u: ArrayLike, v: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """``(theta, psi)`` of bending vectors ``(u, v)`` (radians): ``theta = |b| >= 0``,
    ``psi = atan2(v, u)`` (0 where ``b = 0``)."""
    u, v = np.broadcast_arrays(np.asarray(u, dtype=float), np.asarray(v, dtype=float))
    return np.hypot(u, v), np.arctan2(v, u)


def bending_vector(theta: ArrayLike, psi: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """``(u, v) = theta (cos psi, sin psi)`` (radians); ``theta`` may be negative."""
    theta, psi = np.broadcast_arrays(np.asarray(theta, dtype=float),
                                     np.asarray(psi, dtype=float))
    return theta * np.cos(psi), theta * np.sin(psi)


def bending_transform(u: ArrayLike, v: ArrayLike, segment: Segment) -> FloatArray:
    """``base_T_tip`` of bending vectors ``(u, v)``, ``(..., 4, 4)``; broadcasts."""
    theta, psi = polar(u, v)
    return apcc_transform(theta, segment, psi)


def bending_transform_derivative(u: ArrayLike, v: ArrayLike, segment: Segment
                                 ) -> tuple[FloatArray, FloatArray]:
    """Matrix derivatives ``(dT/du, dT/dv)`` of :func:`bending_transform`, each
    ``(..., 4, 4)``, finite and continuous through ``b = 0``."""
    theta, psi = polar(u, v)
    d_theta = apcc_transform_derivative(theta, segment, psi)[0]
    lifted = np.maximum(theta, SMALL_THETA)
    d_psi_per_theta = apcc_transform_derivative(lifted, segment, psi)[1] / lifted[..., None, None]
    c, s = np.cos(psi)[..., None, None], np.sin(psi)[..., None, None]
    return c * d_theta - s * d_psi_per_theta, s * d_theta + c * d_psi_per_theta
