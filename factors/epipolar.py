"""Generalized epipolar factors, in joint space: the correspondences of one tip camera between
frames.

Variables: the bending angles ``theta_a[j]`` and ``theta_b[j]`` of segments ``j = 0..i`` at frames
a and b (Vector1 values in GTSAM), where camera i rides on segment i; optionally each segment's
calibration ``k_j`` and ``delta_max_j`` (Vector1 values too, online self-calibration). The
kinematics enter through the product of segment transforms, so no pose variables are needed::

    world_T_cam(f) = world_T_base(f) . T_0(theta_f[0]) ... T_i(theta_f[i]) . tip_T_cam
    camA_T_camB    = world_T_cam(a)^-1 . world_T_cam(b)

Joint space against a Pose3 formulation (:mod:`factors.kinematic`): one unknown per segment and
frame instead of an angle plus a 6-dof pose per segment, and the APCC chain holds exactly inside
the residual rather than as a soft constraint; the graph is 7x smaller and needs no pose
initialisation. The robot base poses ``world_T_base`` are known inputs (identity for a fixed base).

Residual (paper section IV; docs/estimation.md, "Two frames"): per correspondence, the Sampson error
of unit bearings ``e`` (radians on the bearings' tangent planes, :mod:`apcc_graph.frontend.geometry`),
whitened by ``sigma`` (radians; pixel noise / focal length): ``r = e / sigma``, dimensionless.
Robust loss per correspondence: gtsam's robust noise models reweight a whole factor by one
weight, so the factor applies the m-estimator weight ``w(r_k)`` of each correspondence itself,
exactly as ``noiseModel::Robust::WhitenSystem`` does for one residual: residual and Jacobian rows
scaled by ``sqrt(w(r_k))``, the weight held fixed while linearising (iteratively reweighted least
squares).

Two groupings of the same residual:

- :func:`epipolar_factor`: one camera, one frame pair (a, b);
- :func:`epipolar_frame_factor`: one camera, frame b against several earlier frames ``a_p``
  (all the pairs a new frame brings): one Python callback instead of one per pair, which is what
  makes the fixed-lag smoother fast (Python factors run serially).

Jacobians: analytic. The Sampson error's gradient with respect to the essential matrix,
``G = d e / d E`` (3x3 per correspondence), is contracted with ``d E / d x`` for each variable x
(from the matrix derivatives of the segment transforms,
:func:`apcc_graph.model.kinematics.apcc_transform_scalar` and its calibration derivatives). The
tangent space of Vector1 is the identity, so GTSAM's right-hand convention ``x + dx`` is plain
addition.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import gtsam
import numpy as np
from numpy.typing import NDArray

from apcc_graph.frontend.geometry import skew
from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.kinematics import apcc_transform_scalar, apcc_transform_scalar_calibration
from apcc_graph.model.segment import Segment, calibrated

ROBUST_LOSSES = ("huber", "cauchy", "none")
_TINY = 1e-300
_NO_MOTION = 1e-12
"""Below this Sampson denominator (unit bearings; it scales with the camera's translation in
metres) a correspondence is treated as showing no motion: residual and Jacobian zero. At round-off
baselines the ratio would otherwise be 0/0 noise with Jacobians near 1e16."""
SLOPE_OUTLIER = 100.0
"""A correspondence whose Sampson slope exceeds this multiple of the pair's median is ill-posed
(near the epipole the Sampson error's denominator vanishes)."""


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


def robust_weights(r: FloatArray, loss: str, k: float) -> FloatArray:
    """M-estimator weights of whitened residuals, the formulas of gtsam's mEstimator models.

    Huber: ``1`` for ``|r| <= k``, else ``k / |r|``; Cauchy: ``1 / (1 + (r / k)^2)``.
    """
    if loss == "none":
        return np.ones_like(r)
    a = np.abs(r)
    if loss == "huber":
        return np.where(a <= k, 1.0, k / np.maximum(a, _TINY))
    if loss == "cauchy":
        return 1.0 / (1.0 + (r / k) ** 2)
    raise ValueError(f"robust loss {loss!r}: expected one of {ROBUST_LOSSES}")


def _sampson_gradient(f_a: FloatArray, f_b: FloatArray,
                      E: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Sampson errors ``e`` ``(N,)`` of unit bearings and ``G = de/dE`` flattened ``(N, 9)``.

    ``E`` is ``(N, 3, 3)``, one essential matrix per correspondence. With ``n = f_a^T E f_b``
    and ``d^2 = |E f_b|^2 + |E^T f_a|^2 - 2 n^2``, ``e = n / d`` and
    ``de/dE = (f_a f_b^T) (1/d + 2 n^2/d^3) - n / d^3 (E f_b f_b^T + f_a f_a^T E)``.
    Zero where ``d`` vanishes (no motion).
    """
    Efb = np.einsum("nij,nj->ni", E, f_b)
    Etfa = np.einsum("nji,nj->ni", E, f_a)
    num = np.einsum("ni,ni->n", f_a, Efb)
    den2 = np.einsum("ni,ni->n", Efb, Efb) + np.einsum("ni,ni->n", Etfa, Etfa) - 2.0 * num * num
    den = np.sqrt(np.maximum(den2, 0.0))
    ok = den > _NO_MOTION
    inv = np.where(ok, 1.0 / np.where(ok, den, 1.0), 0.0)
    e = num * inv
    c = (e * inv * inv)[:, None, None]  # n / d^3
    G = (f_a[:, :, None] * (f_b[:, None, :] * ((inv + 2.0 * num * c[:, 0, 0])[:, None, None])
                             - c * Etfa[:, None, :])
         - c * Efb[:, :, None] * f_b[:, None, :])
    return e, G.reshape(len(e), 9)


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
    B = _chain(thetas_b, segments, psis, jacobians, calibration)
    M = np.asarray(tip_T_cam, dtype=float)
    M_inv = _rigid_inverse(M)
    base_b = np.asarray(world_T_base_b, dtype=float)
    BM = B.P @ M
    E = np.empty((n_pairs, 3, 3))
    dE: list[FloatArray] = []
    for p in range(n_pairs):
        A = _chain(thetas_a[p], segments, psis, jacobians, calibration)
        A_inv = _rigid_inverse(A.P)
        W = _rigid_inverse(np.asarray(world_T_base_a[p], dtype=float)) @ base_b
        left = M_inv @ A_inv
        WB = W @ BM
        pose = left @ WB
        E[p] = skew(pose[:3, 3]) @ pose[:3, :3]
        if not jacobians:
            continue
        # d pose: theta_a[j] -> -left dA_j A^-1 W B M; theta_b[j] -> left W dB_j M.
        lw = left @ W
        right = A_inv @ WB
        d_poses = [-(left @ d) @ right for d in A.d_theta]
        d_poses += [lw @ d @ M for d in B.d_theta]
        if calibration:
            assert A.d_k is not None and A.d_delta is not None
            assert B.d_k is not None and B.d_delta is not None
            for da_list, db_list in ((A.d_k, B.d_k), (A.d_delta, B.d_delta)):
                d_poses += [lw @ db @ M - (left @ da) @ right
                            for da, db in zip(da_list, db_list, strict=True)]
        dE.append(_essential_derivative(pose, np.stack(d_poses)))
    fa = np.concatenate(f_a) if n_pairs != 1 else np.asarray(f_a[0], dtype=float)
    fb = np.concatenate(f_b) if n_pairs != 1 else np.asarray(f_b[0], dtype=float)
    e, G = _sampson_gradient(fa, fb, np.repeat(E, sizes, axis=0))
    r = e / row_sigma
    if not jacobians:
        return FrameResidual(r, rows)
    G /= row_sigma[:, None]
    J_b = np.empty((rows[-1], n))
    J_a: list[FloatArray] = []
    J_k = np.empty((rows[-1], n)) if calibration else None
    J_d = np.empty((rows[-1], n)) if calibration else None
    for p in range(n_pairs):
        sl = slice(rows[p], rows[p + 1])
        J = G[sl] @ dE[p]
        J_a.append(J[:, :n])
        J_b[sl] = J[:, n:2 * n]
        if J_k is not None and J_d is not None:
            J_k[sl] = J[:, 2 * n:3 * n]
            J_d[sl] = J[:, 3 * n:]
    return FrameResidual(r, rows, J_b, J_a, J_k, J_d)


def _rigid_inverse(T: FloatArray) -> FloatArray:
    """Inverse of a rigid 4x4 transform (rotation transposed)."""
    out = np.zeros((4, 4))
    R_t = T[:3, :3].T
    out[:3, :3] = R_t
    out[:3, 3] = -R_t @ T[:3, 3]
    out[3, 3] = 1.0
    return out


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


# --------------------------------------------------------------------------------- factors
def calibrated_segments(segments: Sequence[Segment], values: gtsam.Values,
                      keys: Sequence[tuple[int, int]]) -> list[Segment]:
    """Segments with k and delta_max read from the calibration variables (clamped to range)."""
    return [calibrated(seg, values.atVector(k_key)[0], values.atVector(d_key)[0])
            for seg, (k_key, d_key) in zip(segments, keys, strict=True)]


class EpipolarFrameFactor:
    """The epipolar factor of one camera between frame b and earlier frames ``a_p``.

    Holds the measurements and builds the ``gtsam.CustomFactor`` (:attr:`factor`); see
    :func:`epipolar_frame_factor` for the arguments. Two additions for streaming use:

    - ``gate``: correspondences whose Sampson error at the *first* evaluation exceeds ``gate``
      (radians), or whose Sampson slope is an outlier (near the epipole), are left out from
      then on; a pair left with fewer than ``min_rows`` correspondences is left out whole.
      :attr:`kept` gives the surviving fraction per pair.
    - :meth:`linear_factor`: the factor linearised once, as a C++ ``LinearContainerFactor``
      (first-estimate Jacobians), so gtsam never calls back into Python for it.
    """

    def __init__(
        self,
        keys_b: Sequence[int],
        keys_a: Sequence[Sequence[int]],
        segments: Sequence[Segment],
        tip_T_cam: FloatArray,
        world_T_base_b: FloatArray,
        world_T_base_a: Sequence[FloatArray],
        f_a: Sequence[FloatArray],
        f_b: Sequence[FloatArray],
        sigma: float | Sequence[float],
        loss: str = "huber",
        loss_scale: float = 1.345,
        psis: Sequence[float] | None = None,
        calibration_keys: Sequence[tuple[int, int]] | None = None,
        compress: bool = True,
        gate: float | None = None,
        min_rows: int = 1,
    ) -> None:
        if loss not in ROBUST_LOSSES:
            raise ValueError(f"robust loss {loss!r}: expected one of {ROBUST_LOSSES}")
        if len(keys_a) != len(f_a) or len(f_a) != len(f_b) or len(f_a) != len(world_T_base_a):
            raise ValueError("epipolar_frame_factor: keys_a, world_T_base_a, f_a and f_b must "
                             "have one entry per pair")
        self.keys_b = [int(k) for k in keys_b]
        self.keys_a = [[int(k) for k in ks] for ks in keys_a]
        self.segments = list(segments)
        self.tip_T_cam = np.asarray(tip_T_cam, dtype=float)
        self.f_a = [np.ascontiguousarray(f, dtype=float) for f in f_a]
        self.f_b = [np.ascontiguousarray(f, dtype=float) for f in f_b]
        self.base_b = np.asarray(world_T_base_b, dtype=float)
        self.bases_a = [np.asarray(b, dtype=float) for b in world_T_base_a]
        self.sigma = sigma
        self.loss, self.loss_scale, self.psis = loss, loss_scale, psis
        self.cal_keys = (None if calibration_keys is None
                         else [(int(k), int(d)) for k, d in calibration_keys])
        self.compress = compress
        self.gate, self.min_rows = gate, min_rows
        self.keys = [k for ks in self.keys_a for k in ks] + self.keys_b
        if self.cal_keys is not None:
            self.keys += [k for pair in self.cal_keys for k in pair]
        self.n_rows = sum(len(f) for f in self.f_a)
        self.mask: NDArray[np.bool_] | None = None if gate is not None else np.ones(
            self.n_rows, dtype=bool)
        self._memo: dict[str, object] = {}
        self.dim = len(self.keys) + 1 if compress else self.n_rows

    @property
    def factor(self) -> gtsam.CustomFactor:
        """A ``gtsam.CustomFactor`` evaluating this factor (a new wrapper per access).

        The wrapper holds this object, never the reverse: a reference cycle through gtsam's C++
        side would be invisible to Python's garbage collector and leak every factor.
        """
        return gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(self.dim), self.keys,
                                  self._error)

    @property
    def kept(self) -> FloatArray:
        """Fraction of each pair's correspondences inside the gate (after the first call)."""
        if self.mask is None:
            return np.ones(len(self.f_a))
        rows = np.concatenate([[0], np.cumsum([len(f) for f in self.f_a])])
        return np.array([self.mask[rows[p]:rows[p + 1]].mean() if rows[p + 1] > rows[p]
                         else 0.0 for p in range(len(self.f_a))])

    def _set_mask(self, res: FrameResidual) -> None:
        """Gate at the first evaluation (``res`` computed with ``sigma = 1``: radians)."""
        assert res.J_b is not None and self.gate is not None
        i = len(self.keys_b) - 1
        mask = np.zeros(self.n_rows, dtype=bool)
        for p in range(len(self.f_a)):
            lo, hi = res.rows[p], res.rows[p + 1]
            if hi == lo:
                continue
            slope = np.abs(res.J_b[lo:hi, i])
            mid = (hi - lo) // 2
            median = float(np.partition(slope, mid)[mid])  # upper median; cheap
            sane = slope < SLOPE_OUTLIER * max(median, 1e-12)
            keep = (np.abs(res.r[lo:hi]) < self.gate) & sane
            if keep.sum() >= self.min_rows:
                mask[lo:hi] = keep
        self.mask = mask

    def _error(self, this: gtsam.CustomFactor, values: gtsam.Values,
               H: list[np.ndarray] | None) -> np.ndarray:
        point = tuple(values.atVector(k)[0] for k in self.keys)
        memo = self._memo
        if memo.get("point") == point and (H is None or "H" in memo):
            # gtsam asks again at the same point (e.g. iSAM2 re-eliminating after a
            # marginalisation): answer from the memo instead of recomputing.
            if H is not None:
                for j, h in enumerate(memo["H"]):  # type: ignore[arg-type]
                    H[j] = h
            return memo["r"]  # type: ignore[return-value]
        r, J = self.evaluate(values, point, jacobians=H is not None)
        memo.clear()
        memo["point"], memo["r"] = point, r
        if H is not None:
            assert J is not None
            jac = [np.asfortranarray(J[:, j : j + 1]) for j in range(len(self.keys))]
            memo["H"] = jac
            for j, col in enumerate(jac):
                H[j] = col
        return r

    def evaluate(self, values: gtsam.Values, point: tuple[float, ...] | None = None,
                 jacobians: bool = True) -> tuple[FloatArray, FloatArray | None]:
        """The factor's (robust-weighted, possibly compressed) residual and Jacobian."""
        if point is None:
            point = tuple(values.atVector(k)[0] for k in self.keys)
        values_of = dict(zip(self.keys, point, strict=True))
        th_b = [values_of[k] for k in self.keys_b]
        th_a = [[values_of[k] for k in ks] for ks in self.keys_a]
        segs = (self.segments if self.cal_keys is None
                else calibrated_segments(self.segments, values, self.cal_keys))
        first = self.mask is None
        res = epipolar_frame_residual(th_b, th_a, segs, self.tip_T_cam, self.base_b,
                                      self.bases_a, self.f_a, self.f_b,
                                      1.0 if first else self.sigma, self.psis,
                                      jacobians=jacobians or first,
                                      calibration=self.cal_keys is not None)
        if first:
            self._set_mask(res)
            res = _scaled(res, self.sigma)
        assert self.mask is not None
        sw = np.sqrt(robust_weights(res.r, self.loss, self.loss_scale)) * self.mask
        r = res.r * sw
        n_keys = len(self.keys)
        if not jacobians:
            if self.compress:
                out = np.zeros(n_keys + 1)
                out[-1] = math.sqrt(float(r @ r))
                r = out
            return r, None
        assert res.J_b is not None and res.J_a is not None
        n = len(self.keys_b)
        J = np.zeros((self.n_rows, n_keys))
        for p, ja in enumerate(res.J_a):
            lo, hi = res.rows[p], res.rows[p + 1]
            J[lo:hi, p * n:(p + 1) * n] = ja
        h = len(res.J_a) * n
        J[:, h:h + n] = res.J_b
        if self.cal_keys is not None:
            assert res.J_k is not None and res.J_delta is not None
            J[:, h + n::2] = res.J_k
            J[:, h + n + 1::2] = res.J_delta
        J *= sw[:, None]
        if self.compress:
            # [J | r] = Q [R | Q^T r; 0 | c]: the same Gauss-Newton system and the same error
            # in n_keys + 1 rows instead of one per correspondence.
            Rr = np.linalg.qr(np.column_stack([J, r]), mode="r")
            tri = np.zeros((n_keys + 1, n_keys + 1))
            tri[: Rr.shape[0]] = Rr
            J, r = tri[:, :n_keys], tri[:, n_keys].copy()
        return r, J

    def linear_factor(self, values: gtsam.Values) -> gtsam.LinearContainerFactor:
        """The factor linearised at ``values`` (first-estimate Jacobians), evaluated in C++
        from then on: ``error(x) = 0.5 |J (x - x0) + r0|^2``."""
        point = gtsam.Values()
        for k in self.keys:
            point.insert(k, values.atVector(k))
        return gtsam.LinearContainerFactor(self.factor.linearize(point), point)


def _scaled(res: FrameResidual, sigma: float | Sequence[float]) -> FrameResidual:
    """A residual computed with ``sigma = 1`` rescaled to ``sigma`` (one or one per pair)."""
    n_pairs = len(res.rows) - 1
    per_row = np.repeat(np.broadcast_to(np.asarray(sigma, dtype=float), (n_pairs,)),
                        np.diff(res.rows))
    J_a = None
    if res.J_a is not None:
        J_a = [ja / per_row[res.rows[p]:res.rows[p + 1], None] for p, ja in enumerate(res.J_a)]
    def scale(x):
        return (None if x is None else x / per_row[:, None])
    return FrameResidual(res.r / per_row, res.rows, scale(res.J_b), J_a, scale(res.J_k),
                         scale(res.J_delta))


def epipolar_frame_factor(
    keys_b: Sequence[int],
    keys_a: Sequence[Sequence[int]],
    segments: Sequence[Segment],
    tip_T_cam: FloatArray,
    world_T_base_b: FloatArray,
    world_T_base_a: Sequence[FloatArray],
    f_a: Sequence[FloatArray],
    f_b: Sequence[FloatArray],
    sigma: float | Sequence[float],
    loss: str = "huber",
    loss_scale: float = 1.345,
    psis: Sequence[float] | None = None,
    calibration_keys: Sequence[tuple[int, int]] | None = None,
    compress: bool = True,
) -> gtsam.CustomFactor:
    """One ``gtsam.CustomFactor`` for one camera between frame b and earlier frames ``a_p``.

    Args:
        keys_b: keys of ``theta[0..i]`` at frame b.
        keys_a: per pair, the keys of ``theta[0..i]`` at ``a_p``.
        segments, tip_T_cam, world_T_base_b, world_T_base_a, f_a, f_b, sigma, psis: as in
            :func:`epipolar_frame_residual`.
        loss: ``"huber"``, ``"cauchy"`` or ``"none"``, applied per correspondence.
        loss_scale: the m-estimator's threshold in whitened units (sigmas).
        calibration_keys: per segment ``(k key, delta_max key)``: calibration variables
            (their values replace the segments' k and delta_max); ``None`` keeps them fixed.
        compress: return the residual in ``K + 1`` rows (K keys) instead of one per
            correspondence: at a linearisation the triangular factor of ``[J | r]`` (QR), which
            gives gtsam the same Gauss-Newton system ``J^T J``, ``J^T r`` and the same error;
            without Jacobians ``(0, ..., 0, |r|)``, the same error. gtsam's cost per factor then
            no longer grows with the number of correspondences. ``False`` returns the
            per-correspondence residuals (for inspection and tests).

    Memoisation: the last linearisation is kept; gtsam asking again at the same point (iSAM2
    does, when it re-eliminates after a marginalisation) is answered without recomputing.

    Key order of the factor: each pair's ``keys_a`` (pair 0 first), then ``keys_b``, then the
    calibration keys (k and delta_max of segment 0, then segment 1, ...).
    """
    return EpipolarFrameFactor(keys_b, keys_a, segments, tip_T_cam, world_T_base_b,
                               world_T_base_a, f_a, f_b, sigma, loss, loss_scale, psis,
                               calibration_keys, compress).factor


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
    calibration_keys: Sequence[tuple[int, int]] | None = None,
    compress: bool = True,
) -> gtsam.CustomFactor:
    """A ``gtsam.CustomFactor`` for one camera and one frame pair (a, b).

    Key order: ``keys_a``, ``keys_b``, then the calibration keys (as
    :func:`epipolar_frame_factor`, of which this is the one-pair case).

    Args:
        keys_a, keys_b: keys of ``theta[0..i]`` at frames a and b.
        segments, tip_T_cam, world_T_base_a, world_T_base_b, f_a, f_b, sigma, psis: as in
            :func:`epipolar_residual`.
        loss: ``"huber"``, ``"cauchy"`` or ``"none"``, applied per correspondence.
        loss_scale: the m-estimator's threshold in whitened units (sigmas).
        calibration_keys: per segment ``(k key, delta_max key)``, or ``None``.
        compress: as in :func:`epipolar_frame_factor`.
    """
    return epipolar_frame_factor(keys_b, [keys_a], segments, tip_T_cam, world_T_base_b,
                                 [world_T_base_a], [f_a], [f_b], sigma, loss, loss_scale, psis,
                                 calibration_keys, compress)
