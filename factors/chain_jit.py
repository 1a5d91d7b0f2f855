"""Tip-camera poses along the APCC chain, compiled, for segments in fixed bending planes.

The numpy reference is :func:`apcc_graph.factors.camera_chain.camera_poses` with the
kinematics of :mod:`apcc_graph.model.kinematics` (``apcc_in_plane``, ``plane_to_transform``,
``apcc_transform_derivative``); this kernel evaluates the same closed forms and the same
products, frame by frame, and agrees with it to rounding (``tests/test_reduced_jit.py``). It
exists because a projection factor's chunk asks for tens of frames' poses of a few segments
each, where numpy's per-call overhead, not arithmetic, dominated.

Units: metres and radians. ``segments`` ``(n, 4)`` holds each segment's ``(l1, l2, c,
rate)``: the link lengths, the link ratio ``c = l2 / l1`` and ``rate = 1 -
delta_max / theta_max`` (the tip angle is ``theta * rate``).
"""

from __future__ import annotations

import math

import numpy as np

from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.kernel_cache import njit


@njit(cache=True)
def _mul(A: FloatArray, B: FloatArray, out: FloatArray) -> None:
    """``out = A B`` for 4x4 homogeneous matrices (``out`` not ``A`` or ``B``)."""
    for i in range(4):
        for j in range(4):
            out[i, j] = (A[i, 0] * B[0, j] + A[i, 1] * B[1, j] + A[i, 2] * B[2, j]
                         + A[i, 3] * B[3, j])


@njit(cache=True)
def _segment(theta: float, seg: FloatArray, psi: float, T: FloatArray, dT: FloatArray) -> None:
    """Segment transform ``base_T_tip`` into ``T`` and its theta-derivative into ``dT``."""
    l1, l2, c, rate = seg[0], seg[1], seg[2], seg[3]
    s, h = math.sin(0.5 * theta), math.cos(0.5 * theta)
    root = math.sqrt(1.0 - (c * s) ** 2)
    chord = l1 * root + l2 * h
    dchord = -0.5 * s * l2 * (c * h / root + 1.0)
    beta = theta * rate
    px, pz = chord * s, chord * h
    dpx, dpz = 0.5 * h * chord + s * dchord, -0.5 * s * chord + h * dchord
    cb, sb, cp, sp = math.cos(beta), math.sin(beta), math.cos(psi), math.sin(psi)
    vb = 1.0 - cb
    r01 = -vb * sp * cp
    T[0, 0], T[0, 1], T[0, 2], T[0, 3] = 1.0 - vb * cp * cp, r01, sb * cp, cp * px
    T[1, 0], T[1, 1], T[1, 2], T[1, 3] = r01, 1.0 - vb * sp * sp, sb * sp, sp * px
    T[2, 0], T[2, 1], T[2, 2], T[2, 3] = -sb * cp, -sb * sp, cb, pz
    T[3, 0], T[3, 1], T[3, 2], T[3, 3] = 0.0, 0.0, 0.0, 1.0
    d01 = -rate * sb * sp * cp
    dT[0, 0], dT[0, 1], dT[0, 2], dT[0, 3] = -rate * sb * cp * cp, d01, rate * cb * cp, cp * dpx
    dT[1, 0], dT[1, 1], dT[1, 2], dT[1, 3] = d01, -rate * sb * sp * sp, rate * cb * sp, sp * dpx
    dT[2, 0], dT[2, 1], dT[2, 2], dT[2, 3] = -rate * cb * cp, -rate * cb * sp, -rate * sb, dpz
    dT[3, 0], dT[3, 1], dT[3, 2], dT[3, 3] = 0.0, 0.0, 0.0, 0.0


@njit(cache=True)
def fixed_plane_poses(x: FloatArray, segments: FloatArray, planes: FloatArray,
                      tip_T_cam: FloatArray, world_T_base: FloatArray, derivatives: bool
                      ) -> tuple[FloatArray, FloatArray]:
    """``world_T_cam`` ``(F, 4, 4)`` of a camera on the last of ``n`` segments and, with
    ``derivatives``, ``d world_T_cam / d theta_j`` ``(F, n, 4, 4)`` (else ``(F, 0, 4, 4)``).

    Args:
        x: ``(F, n)`` angles in the fixed planes ``planes`` ``(n,)``.
        segments: ``(n, 4)`` each segment's ``(l1, l2, c, rate)`` (module docstring).
        tip_T_cam: ``(4, 4)`` the mounting.
        world_T_base: ``(F, 4, 4)`` base poses, or ``(1, 4, 4)`` for every frame.
    """
    F, n = x.shape
    poses = np.empty((F, 4, 4))
    d_poses = np.empty((F, n if derivatives else 0, 4, 4))
    T, dT = np.empty((n, 4, 4)), np.empty((n, 4, 4))
    prefix, suffix = np.empty((n + 1, 4, 4)), np.empty((n + 1, 4, 4))
    tmp = np.empty((4, 4))
    for f in range(F):
        for j in range(n):
            _segment(x[f, j], segments[j], planes[j], T[j], dT[j])
        prefix[0] = world_T_base[f if world_T_base.shape[0] > 1 else 0]
        for j in range(n):
            _mul(prefix[j], T[j], prefix[j + 1])
        _mul(prefix[n], tip_T_cam, poses[f])
        if not derivatives:
            continue
        suffix[n] = tip_T_cam  # suffix[j] = T_j ... T_n-1 tip_T_cam
        for j in range(n - 1, 0, -1):
            _mul(T[j], suffix[j + 1], suffix[j])
        for j in range(n):
            _mul(prefix[j], dT[j], tmp)
            _mul(tmp, suffix[j + 1], d_poses[f, j])
    return poses, d_poses


def segment_table(segments: tuple) -> FloatArray:
    """``(n, 4)`` the kernel's ``(l1, l2, c, rate)`` of each segment."""
    return np.array([[s.l1, s.l2, s.link_ratio, 1.0 - s.deviation_rate] for s in segments],
                    dtype=float).reshape(-1, 4)
