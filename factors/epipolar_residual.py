"""The generalized epipolar residual in joint space, and its analytic Jacobians (pure numpy).

Variables: the bending angles ``theta_a[j]`` and ``theta_b[j]`` of segments ``j = 0..i`` at frames
a and b, where camera i rides on segment i; optionally each segment's calibration ``k_j`` and
``delta_max_j``. The kinematics enter through the product of segment transforms, so no pose
variables are needed::

    world_T_cam(f) = world_T_base(f) . T_0(theta_f[0]) ... T_i(theta_f[i]) . tip_T_cam
    camA_T_camB    = world_T_cam(a)^-1 . world_T_cam(b)

The robot base poses ``world_T_base`` are known inputs (identity for a fixed base).

Residual (docs/estimation.md, "Two frames" and "The epipolar model, kept for comparison"): per
correspondence, the Sampson error of unit bearings ``e``
(:func:`apcc_graph.frontend.geometry.sampson_gradient`; radians on the bearings' tangent planes),
whitened by ``sigma`` (radians; pixel noise / focal length): ``r = e / sigma``, dimensionless.

Jacobians: the Sampson error's gradient with respect to the essential matrix, ``G = de / dE``
(3x3 per correspondence), is contracted with ``dE / dx`` for each variable x (from the matrix
derivatives of the segment transforms, :func:`apcc_graph.model.kinematics.apcc_transform_scalar`
and its calibration derivatives).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from apcc_graph.frontend.geometry import sampson_gradient, skew
from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.scalar_kinematics import (
    apcc_transform_scalar,
    apcc_transform_scalar_calibration,
)
from apcc_graph.model.segment import Segment

_NO_MOTION = 1e-12
"""Below this Sampson denominator (unit bearings; it scales with the camera's translation in
metres) a correspondence is treated as showing no motion: residual and Jacobian zero. At round-off
baselines the ratio would otherwise be 0/0 noise with Jacobians near 1e16."""


# ----------------------------------------------------------------------------------- chain
@dataclass(frozen=True)
class _Chain:
    """``P = T_0 ... T_n-1`` and its derivatives: ``d_theta[j]``, optionally ``d_k[j]``,
    ``d_delta[j]`` (each 4x4)."""

    P: FloatArray
    d_theta: list[FloatArray]
    d_k: list[FloatArray] | None = None
    d_delta: list[FloatArray] | None = None


_CHAIN_CACHE: dict[tuple, _Chain] = {}
_CHAIN_CACHE_SIZE = 4096
_EYE = np.eye(4)
_EYE.setflags(write=False)


def _chain(thetas: Sequence[float], segments: Sequence[Segment], psis: Sequence[float],
           derivatives: bool = True, calibration: bool = False) -> _Chain:
    """The chain product and its derivatives, memoised.

    In a smoother the same frame's chain is needed by every factor that frame is in, at the
    same linearisation point; a small cache (bounded, oldest entries dropped first) turns those
    repeats into dictionary look-ups. Cached arrays are read-only.
    """
    key = (tuple(thetas), tuple(psis), tuple(segments), derivatives, calibration)
    hit = _CHAIN_CACHE.get(key)
    if hit is not None:
        return hit
    out = _compute_chain(thetas, segments, psis, derivatives, calibration)
    if len(_CHAIN_CACHE) >= _CHAIN_CACHE_SIZE:
        for stale in list(_CHAIN_CACHE)[: _CHAIN_CACHE_SIZE // 4]:
            del _CHAIN_CACHE[stale]
    _CHAIN_CACHE[key] = out
    return out


def _compute_chain(thetas: Sequence[float], segments: Sequence[Segment], psis: Sequence[float],
                   derivatives: bool, calibration: bool) -> _Chain:
    n = len(segments)
    T, dT, dK, dD = [], [], [], []
    for t, s, p in zip(thetas, segments, psis, strict=True):
        if calibration:
            Tj, dTj, dKj, dDj = apcc_transform_scalar_calibration(float(t), s, float(p))
            dK.append(dKj)
            dD.append(dDj)
        else:
            Tj, dTj = apcc_transform_scalar(float(t), s, float(p))
        T.append(Tj)
        dT.append(dTj)
    prefix = [_EYE, T[0]] if n else [_EYE]
    for j in range(1, n):
        prefix.append(prefix[-1] @ T[j])
    if not derivatives:
        return _Chain(prefix[n], [])
    suffix = [_EYE] * (n + 1)
    for j in range(n - 1, -1, -1):
        suffix[j] = T[j] if j == n - 1 else T[j] @ suffix[j + 1]

    def spread(d: list[FloatArray]) -> list[FloatArray]:
        return [d[j] if n == 1 else prefix[j] @ d[j] @ suffix[j + 1] for j in range(n)]

    if calibration:
        return _Chain(prefix[n], spread(dT), spread(dK), spread(dD))
    return _Chain(prefix[n], spread(dT))


def _rigid_inverse(T: FloatArray) -> FloatArray:
    """Inverse of a rigid 4x4 transform (rotation transposed)."""
    out = np.zeros((4, 4))
    R_t = T[:3, :3].T
    out[:3, :3] = R_t
    out[:3, 3] = -R_t @ T[:3, 3]
    out[3, 3] = 1.0
    return out


# ------------------------------------------------------------------------ essential matrices
def _essential_derivative(pose: FloatArray, d_pose: FloatArray) -> FloatArray:
    """``vec(dE)`` ``(9, m)`` of ``E = [t]x R`` for pose derivatives ``(m, 4, 4)``."""
    R, t = pose[:3, :3], pose[:3, 3]
    dR, dt = d_pose[:, :3, :3], d_pose[:, :3, 3]
    # [dt]x R + [t]x dR, with [v]x expanded by components.
    st = skew(t)
    sdt = np.zeros((len(dt), 3, 3))
    sdt[:, 0, 1], sdt[:, 0, 2], sdt[:, 1, 2] = -dt[:, 2], dt[:, 1], -dt[:, 0]
    sdt[:, 1, 0], sdt[:, 2, 0], sdt[:, 2, 1] = dt[:, 2], -dt[:, 1], dt[:, 0]
    return (sdt @ R + st @ dR).reshape(len(dt), 9).T


def _pose_derivatives(A: _Chain, B: _Chain, left: FloatArray, W: FloatArray,
                      right: FloatArray, M: FloatArray, calibration: bool) -> FloatArray:
    """``d camA_T_camB`` ``(m, 4, 4)`` in theta_a[j], theta_b[j] (then k_j, delta_max_j).

    With ``pose = left W B M`` and ``right = A^-1 W B M``: theta_a[j] gives
    ``-left dA_j right``, theta_b[j] gives ``left W dB_j M``.
    """
    lw = left @ W
    d_poses = [-(left @ d) @ right for d in A.d_theta]
    d_poses += [lw @ d @ M for d in B.d_theta]
    if calibration:
        assert A.d_k is not None and A.d_delta is not None
        assert B.d_k is not None and B.d_delta is not None
        for da_list, db_list in ((A.d_k, B.d_k), (A.d_delta, B.d_delta)):
            d_poses += [lw @ db @ M - (left @ da) @ right
                        for da, db in zip(da_list, db_list, strict=True)]
    return np.stack(d_poses)


def _pair_essentials(
    thetas_b: Sequence[float], thetas_a: Sequence[Sequence[float]], segments: Sequence[Segment],
    psis: Sequence[float], tip_T_cam: FloatArray, world_T_base_b: FloatArray,
    world_T_base_a: Sequence[FloatArray], jacobians: bool, calibration: bool,
) -> tuple[FloatArray, list[FloatArray]]:
    """Per pair, ``E = [t]x R`` of ``camA_T_camB`` ``(P, 3, 3)`` and (with ``jacobians``) its
    derivatives ``vec(dE)`` ``(9, m)`` in the pair's variables."""
    B = _chain(thetas_b, segments, psis, jacobians, calibration)
    M = np.asarray(tip_T_cam, dtype=float)
    M_inv = _rigid_inverse(M)
    BM = B.P @ M
    base_b = np.asarray(world_T_base_b, dtype=float)
    E = np.empty((len(thetas_a), 3, 3))
    dE: list[FloatArray] = []
    for p, thetas in enumerate(thetas_a):
        A = _chain(thetas, segments, psis, jacobians, calibration)
        A_inv = _rigid_inverse(A.P)
        W = _rigid_inverse(np.asarray(world_T_base_a[p], dtype=float)) @ base_b
        left = M_inv @ A_inv
        WB = W @ BM
        pose = left @ WB
        E[p] = skew(pose[:3, 3]) @ pose[:3, :3]
        if jacobians:
            d_poses = _pose_derivatives(A, B, left, W, A_inv @ WB, M, calibration)
            dE.append(_essential_derivative(pose, d_poses))
    return E, dE


# ------------------------------------------------------------------------------- residuals
@dataclass(frozen=True)
class FrameResidual:
    """Whitened residuals of one camera between frame b and earlier frames ``a_p``.

    Attributes:
        r: ``(N,)`` whitened Sampson errors, pairs concatenated in order.
        rows: ``(P + 1,)`` offsets: pair p owns ``r[rows[p]:rows[p+1]]``.
        J_b: ``(N, n)`` d r / d theta_b[j].
        J_a: per pair, ``(N_p, n)`` d r / d theta_{a_p}[j] (only pair p's rows depend on them).
        J_k, J_delta: ``(N, n)`` d r / d k_j and d r / d delta_max_j (with calibration).
    """

    r: FloatArray
    rows: NDArray[np.int64]
    J_b: FloatArray | None = None
    J_a: list[FloatArray] | None = None
    J_k: FloatArray | None = None
    J_delta: FloatArray | None = None


def epipolar_frame_residual(
    thetas_b: Sequence[float],
    thetas_a: Sequence[Sequence[float]],
    segments: Sequence[Segment],
    tip_T_cam: FloatArray,
    world_T_base_b: FloatArray,
    world_T_base_a: Sequence[FloatArray],
    f_a: Sequence[FloatArray],
    f_b: Sequence[FloatArray],
    sigma: float | Sequence[float],
    psis: Sequence[float] | None = None,
    jacobians: bool = True,
    calibration: bool = False,
) -> FrameResidual:
    """Whitened Sampson residuals of pairs ``(a_p, b)`` and their Jacobians (pure numpy).

    Args:
        thetas_b: angles of segments ``0..i`` at frame b (radians).
        thetas_a: per pair, the angles of segments ``0..i`` at frame ``a_p``.
        segments: segments ``0..i`` (their k and delta_max are the calibration).
        tip_T_cam: the camera mounting on segment i.
        world_T_base_b, world_T_base_a: robot base poses at b and at each ``a_p``.
        f_a, f_b: per pair, ``(N_p, 3)`` unit bearings at ``a_p`` and b.
        sigma: Sampson-error standard deviation (radians), one or one per pair.
        psis: bending-plane angles (default zeros).
        jacobians: also compute the Jacobians.
        calibration: also the Jacobians with respect to each segment's k and delta_max.
    """
    n = len(segments)
    psis = [0.0] * n if psis is None else list(psis)
    n_pairs = len(thetas_a)
    sizes = [len(f) for f in f_a]
    rows = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
    row_sigma = np.repeat(np.broadcast_to(np.asarray(sigma, dtype=float), (n_pairs,)), sizes)
    E, dE = _pair_essentials(thetas_b, thetas_a, segments, psis, tip_T_cam, world_T_base_b,
                             world_T_base_a, jacobians, calibration)
    fa = np.concatenate(f_a) if n_pairs != 1 else np.asarray(f_a[0], dtype=float)
    fb = np.concatenate(f_b) if n_pairs != 1 else np.asarray(f_b[0], dtype=float)
    e, G = sampson_gradient(fa, fb, np.repeat(E, sizes, axis=0), _NO_MOTION)
    r = e / row_sigma
    if not jacobians:
        return FrameResidual(r, rows)
    G /= row_sigma[:, None]
    return _with_jacobians(r, rows, G, dE, n, calibration)


def _with_jacobians(r: FloatArray, rows: NDArray[np.int64], G: FloatArray,
                    dE: list[FloatArray], n: int, calibration: bool) -> FrameResidual:
    """The residual with its Jacobians: each pair's ``G dE`` split by variable."""
    J_b = np.empty((rows[-1], n))
    J_a: list[FloatArray] = []
    J_k = np.empty((rows[-1], n)) if calibration else None
    J_d = np.empty((rows[-1], n)) if calibration else None
    for p, dE_p in enumerate(dE):
        sl = slice(rows[p], rows[p + 1])
        J = G[sl] @ dE_p
        J_a.append(J[:, :n])
        J_b[sl] = J[:, n:2 * n]
        if J_k is not None and J_d is not None:
            J_k[sl] = J[:, 2 * n:3 * n]
            J_d[sl] = J[:, 3 * n:]
    return FrameResidual(r, rows, J_b, J_a, J_k, J_d)


def rescaled(res: FrameResidual, sigma: float | Sequence[float]) -> FrameResidual:
    """A residual computed with ``sigma = 1`` rescaled to ``sigma`` (one or one per pair)."""
    n_pairs = len(res.rows) - 1
    per_row = np.repeat(np.broadcast_to(np.asarray(sigma, dtype=float), (n_pairs,)),
                        np.diff(res.rows))
    J_a = None
    if res.J_a is not None:
        J_a = [ja / per_row[res.rows[p]:res.rows[p + 1], None] for p, ja in enumerate(res.J_a)]

    def scale(x: FloatArray | None) -> FloatArray | None:
        return None if x is None else x / per_row[:, None]

    return FrameResidual(res.r / per_row, res.rows, scale(res.J_b), J_a, scale(res.J_k),
                         scale(res.J_delta))


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
    """Whitened Sampson residuals of one frame pair and their Jacobians (pure numpy).

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
    res = epipolar_frame_residual(thetas_b, [thetas_a], segments, tip_T_cam, world_T_base_b,
                                  [world_T_base_a], [f_a], [f_b], sigma, psis, jacobians)
    if not jacobians:
        return res.r, None, None
    assert res.J_a is not None
    return res.r, res.J_a[0], res.J_b
