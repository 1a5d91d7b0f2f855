"""Generalized epipolar factors in joint space: the gtsam side of the epipolar residual.

The residual and its Jacobians are :mod:`apcc_graph.factors.epipolar_residual` (docs/estimation.md,
"Two frames" and "The epipolar model, kept for comparison"). Joint space against a Pose3 formulation
(:mod:`apcc_graph.factors.kinematic`): one unknown per segment and frame instead of an angle plus a
6-dof pose per segment, and the APCC chain holds exactly inside the residual rather than as a soft
constraint; the graph is much smaller and needs no pose initialisation.

Robust loss per correspondence: gtsam's robust noise models reweight a whole factor by one
weight, so the factor applies the m-estimator weight ``w(r_k)`` of each correspondence itself
(:func:`robust_weights`), exactly as ``noiseModel::Robust::WhitenSystem`` does for one residual:
residual and Jacobian rows scaled by ``sqrt(w(r_k))``, the weight held fixed while linearising
(iteratively reweighted least squares).

Two groupings of the same residual:

- :func:`epipolar_factor`: one camera, one frame pair (a, b);
- :func:`epipolar_frame_factor`: one camera, frame b against several earlier frames ``a_p``
  (all the pairs a new frame brings): one Python callback instead of one per pair, which is what
  makes the fixed-lag smoother fast (Python factors run serially).

:class:`EpipolarFrameFactor` adds what streaming needs: a gate at the first evaluation
(:func:`apcc_graph.frontend.geometry.slope_gate` for the slopes), QR compression of the
residual to one row per variable plus one (:func:`qr_compress`), and first-estimate linear
factors evaluated in C++. The tangent space of Vector1 is the identity, so GTSAM's right-hand
convention ``x + dx`` is plain addition.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import gtsam
import numpy as np
from numpy.typing import NDArray

from apcc_graph.factors.epipolar_residual import FrameResidual, epipolar_frame_residual, rescaled
from apcc_graph.frontend.geometry import slope_gate
from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.segment import Segment, calibrated

ROBUST_LOSSES = ("huber", "cauchy", "none")
_TINY = 1e-300


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
            keep = (np.abs(res.r[lo:hi]) < self.gate) & slope_gate(res.J_b[lo:hi, i])
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
            res = rescaled(res, self.sigma)
        assert self.mask is not None
        sw = np.sqrt(robust_weights(res.r, self.loss, self.loss_scale)) * self.mask
        r = res.r * sw
        if not jacobians:
            if self.compress:
                out = np.zeros(len(self.keys) + 1)
                out[-1] = math.sqrt(float(r @ r))
                r = out
            return r, None
        J = self._jacobian(res) * sw[:, None]
        return qr_compress(J, r) if self.compress else (r, J)

    def _jacobian(self, res: FrameResidual) -> FloatArray:
        """The residual's Jacobian ``(N, K)`` in the factor's key order."""
        assert res.J_b is not None and res.J_a is not None
        n = len(self.keys_b)
        J = np.zeros((self.n_rows, len(self.keys)))
        for p, ja in enumerate(res.J_a):
            lo, hi = res.rows[p], res.rows[p + 1]
            J[lo:hi, p * n:(p + 1) * n] = ja
        h = len(res.J_a) * n
        J[:, h:h + n] = res.J_b
        if self.cal_keys is not None:
            assert res.J_k is not None and res.J_delta is not None
            J[:, h + n::2] = res.J_k
            J[:, h + n + 1::2] = res.J_delta
        return J

    def linear_factor(self, values: gtsam.Values) -> gtsam.LinearContainerFactor:
        """The factor linearised at ``values`` (first-estimate Jacobians), evaluated in C++
        from then on: ``error(x) = 0.5 |J (x - x0) + r0|^2``."""
        point = gtsam.Values()
        for k in self.keys:
            point.insert(k, values.atVector(k))
        return gtsam.LinearContainerFactor(self.factor.linearize(point), point)


def qr_compress(J: FloatArray, r: FloatArray) -> tuple[FloatArray, FloatArray]:
    """``[J | r] = Q [R | Q^T r; 0 | c]``: the same Gauss-Newton system ``J^T J``, ``J^T r`` and
    the same error ``|r|^2`` in ``K + 1`` rows instead of one per correspondence.

    Returns:
        ``(r', J')``: ``(K + 1,)`` and ``(K + 1, K)``, zero-padded when there are fewer rows.
    """
    n_keys = J.shape[1]
    Rr = np.linalg.qr(np.column_stack([J, r]), mode="r")
    tri = np.zeros((n_keys + 1, n_keys + 1))
    tri[: Rr.shape[0]] = Rr
    return tri[:, n_keys].copy(), tri[:, :n_keys]


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
            :func:`~apcc_graph.factors.epipolar_residual.epipolar_frame_residual`.
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
            :func:`~apcc_graph.factors.epipolar_residual.epipolar_residual`.
        loss: ``"huber"``, ``"cauchy"`` or ``"none"``, applied per correspondence.
        loss_scale: the m-estimator's threshold in whitened units (sigmas).
        calibration_keys: per segment ``(k key, delta_max key)``, or ``None``.
        compress: as in :func:`epipolar_frame_factor`.
    """
    return epipolar_frame_factor(keys_b, [keys_a], segments, tip_T_cam, world_T_base_b,
                                 [world_T_base_a], [f_a], [f_b], sigma, loss, loss_scale, psis,
                                 calibration_keys, compress)
