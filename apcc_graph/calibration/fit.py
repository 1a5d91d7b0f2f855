"""Least-squares calibration of one segment over a recorded sweep of tip poses
(docs/estimation.md, "Calibrating a segment").

Tip poses are measured as for :mod:`~apcc_graph.calibration.closed_form`: ``(x, z)`` in the
bending plane with the base at the origin and the base axis along +z (metres), and the tip
tangent angle from that axis (radians).

- :func:`fit_segment`: k, the deviation rate ``delta_max / theta_max`` and one theta per pose,
  with standard deviations of k and delta_max, and the residuals of the APCC fit and of the best
  PCC fit on the same data.
- :func:`fit_thetas`: the per-pose angles that best explain a sweep for a fixed model (a
  calibrated :class:`Segment` or PCC), to validate a calibration on other data.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.optimize
import scipy.sparse
from numpy.typing import ArrayLike

from apcc_graph.calibration.closed_form import MIN_BEND, finite_array, positive_number
from apcc_graph.model.arrays import FloatArray, rms
from apcc_graph.model.kinematics import apcc_in_plane, pcc_in_plane
from apcc_graph.model.segment import Segment

REACH_SLACK = 0.05
"""A swept tip may lie up to this fraction beyond L (measurement noise near straight poses)."""


@dataclass(frozen=True)
class ThetaFit:
    """Per-pose bending angles fitted for a fixed model, and the residuals.

    Attributes:
        thetas: ``(N,)`` fitted bends (radians).
        position_residuals: ``(N,)`` distance model tip to measured tip (metres).
        angle_residuals: ``(N,)`` model tip angle minus measured tip angle (radians).
    """

    thetas: FloatArray
    position_residuals: FloatArray
    angle_residuals: FloatArray

    @property
    def rms_position(self) -> float:
        """RMS tip position error (metres)."""
        return float(rms(self.position_residuals, axis=None))

    @property
    def rms_angle(self) -> float:
        """RMS tip angle error (radians)."""
        return float(rms(self.angle_residuals, axis=None))


@dataclass(frozen=True)
class SweepCalibration:
    """Result of :func:`fit_segment` (metres, radians).

    Attributes:
        k: deviation coefficient.
        delta_max: tip-angle deviation at ``theta_max``.
        theta_max: bending limit (given, or the largest fitted ``|theta|`` of the sweep).
        length: segment length.
        k_std: standard deviation of k (from the fit's Jacobian and residual scale).
        delta_max_std: standard deviation of delta_max.
        apcc: the APCC fit (per-pose thetas and residuals).
        pcc: the best PCC fit on the same data.
    """

    k: float
    delta_max: float
    theta_max: float
    length: float
    k_std: float
    delta_max_std: float
    apcc: ThetaFit
    pcc: ThetaFit

    @property
    def segment(self) -> Segment:
        """The calibrated segment."""
        return Segment(self.length, k=self.k, delta_max=self.delta_max, theta_max=self.theta_max)

    @property
    def thetas(self) -> FloatArray:
        """Per-pose fitted bends of the APCC fit (radians)."""
        return self.apcc.thetas


def _check_sweep(
    tip_positions: ArrayLike, tip_angles: ArrayLike, length: float
) -> tuple[FloatArray, FloatArray, float]:
    pos = finite_array("tip_positions", tip_positions, (None, 2))
    ang = finite_array("tip_angles", tip_angles, (None,))
    length = positive_number("length", length)
    if len(pos) != len(ang):
        raise ValueError(
            f"tip_positions has {len(pos)} poses but tip_angles has {len(ang)}: expected one "
            "angle per pose"
        )
    if len(pos) == 0:
        raise ValueError("tip_positions: expected at least one pose")
    reach = np.hypot(pos[:, 0], pos[:, 1])
    far = np.flatnonzero(reach > (1.0 + REACH_SLACK) * length)
    if len(far):
        i = int(far[0])
        raise ValueError(
            f"tip_positions[{i}] = ({pos[i, 0]:g}, {pos[i, 1]:g}) is {reach[i]:g} m from the base, "
            f"beyond the reach of a segment of length {length:g} m; check the units (metres)"
        )
    return pos, ang, length


def _default_sigmas(
    length: float, position_sigma: float | None, angle_sigma: float | None
) -> tuple[float, float]:
    if position_sigma is not None:
        position_sigma = positive_number("position_sigma", position_sigma)
    if angle_sigma is not None:
        angle_sigma = positive_number("angle_sigma", angle_sigma)
    return (0.002 * length if position_sigma is None else position_sigma,
            math.radians(0.5) if angle_sigma is None else angle_sigma)


def _model_tips(
    thetas: FloatArray, length: float, k: float | None, rate: float
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Tip ``(x, z, angle)`` of PCC (``k is None``) or APCC with deviation rate ``rate``."""
    if k is None:
        px, pz = pcc_in_plane(thetas, length)
        return px, pz, thetas
    planar = apcc_in_plane(thetas, Segment(length, k=k, theta_max=math.pi))
    return planar.px, planar.pz, thetas * (1.0 - rate)


def _residuals_of(
    thetas: FloatArray,
    pos: FloatArray,
    ang: FloatArray,
    length: float,
    k: float | None,
    rate: float,
) -> ThetaFit:
    px, pz, angle = _model_tips(thetas, length, k, rate)
    return ThetaFit(
        thetas=thetas,
        position_residuals=np.hypot(px - pos[:, 0], pz - pos[:, 1]),
        angle_residuals=angle - ang,
    )


def _initial_thetas(pos: FloatArray) -> FloatArray:
    return 2.0 * np.arctan2(pos[:, 0], pos[:, 1])


def _solve_thetas(
    pos: FloatArray,
    ang: FloatArray,
    length: float,
    k: float | None,
    rate: float,
    sigmas: tuple[float, float],
) -> FloatArray:
    """Per-pose least squares for theta with the model fixed (block-diagonal, one solve)."""
    n = len(pos)
    sp, sa = sigmas

    def residuals(thetas: FloatArray) -> FloatArray:
        px, pz, angle = _model_tips(thetas, length, k, rate)
        return np.concatenate([(px - pos[:, 0]) / sp, (pz - pos[:, 1]) / sp, (angle - ang) / sa])

    # Several poses: a sparse Jacobian (its trust-region solver is lsmr, which steps in a 2-D
    # subspace). One pose: a dense one (tr_solver "exact"); with a single unknown that subspace
    # is 1-D and scipy's solve_trust_region_2d fails with IndexError (seen with scipy 1.17).
    sparsity = scipy.sparse.vstack([scipy.sparse.identity(n)] * 3) if n > 1 else None
    res = scipy.optimize.least_squares(
        residuals,
        _initial_thetas(pos),
        jac="3-point",
        jac_sparsity=sparsity,
        bounds=(-math.pi, math.pi),
        x_scale=1.0,
        method="trf",
        xtol=1e-14,
        ftol=1e-14,
        gtol=1e-14,
    )
    return res.x


def fit_thetas(
    model: Segment | None,
    tip_positions: ArrayLike,
    tip_angles: ArrayLike,
    length: float | None = None,
    position_sigma: float | None = None,
    angle_sigma: float | None = None,
) -> ThetaFit:
    """Best per-pose bends for a fixed model, and its residuals on a sweep.

    Args:
        model: a calibrated :class:`Segment` (APCC), or ``None`` for PCC (then give ``length``).
        tip_positions: ``(N, 2)`` measured tips ``(x, z)`` (metres).
        tip_angles: ``(N,)`` measured tip tangent angles (radians).
        length: segment length for PCC; ignored (taken from the segment) for APCC.
        position_sigma: position noise (metres) weighting the fit; default ``0.002 L``.
        angle_sigma: angle noise (radians) weighting the fit; default 0.5 degrees.

    Returns:
        Fitted thetas and residuals.
    """
    if model is None:
        if length is None:
            raise ValueError("fit_thetas: give length for the PCC model (model=None)")
        k, rate = None, 0.0
    else:
        length, k, rate = model.length, model.k, model.deviation_rate
    pos, ang, length = _check_sweep(tip_positions, tip_angles, length)
    sigmas = _default_sigmas(length, position_sigma, angle_sigma)
    thetas = _solve_thetas(pos, ang, length, k, rate, sigmas)
    return _residuals_of(thetas, pos, ang, length, k, rate)


def _sweep_start(pos: FloatArray, ang: FloatArray) -> FloatArray:
    """Start of the sweep fit: ``(k, rate, theta_1..theta_N)`` with each theta on its chord.

    Raises:
        ValueError: no pose is bent by at least :data:`MIN_BEND`.
    """
    theta0 = _initial_thetas(pos)
    if np.max(np.abs(theta0)) < MIN_BEND:
        raise ValueError(
            "every pose of the sweep is bent less than 1 deg: k and delta_max are not observable; "
            "record poses across the bending range"
        )
    bent = np.abs(theta0) >= MIN_BEND
    rate0 = float(np.clip(np.median((theta0[bent] - ang[bent]) / theta0[bent]), -0.9, 0.9))
    return np.concatenate([[0.25, rate0], theta0])


def _solve_sweep(
    pos: FloatArray,
    ang: FloatArray,
    length: float,
    x0: FloatArray,
    sigmas: tuple[float, float],
) -> scipy.optimize.OptimizeResult:
    """Least squares for ``(k, rate, thetas)``, with the sparse Jacobian structure: each pose
    depends on its own theta and the two globals."""
    n = len(pos)
    sp, sa = sigmas

    def residuals(params: FloatArray) -> FloatArray:
        k, rate, thetas = params[0], params[1], params[2:]
        px, pz, angle = _model_tips(thetas, length, k, rate)
        return np.concatenate([(px - pos[:, 0]) / sp, (pz - pos[:, 1]) / sp, (angle - ang) / sa])

    per_pose = scipy.sparse.identity(n, format="csr")
    sparsity = scipy.sparse.hstack(
        [np.ones((3 * n, 2)), scipy.sparse.vstack([per_pose] * 3)], format="csr"
    )
    lower = np.concatenate([[1e-4, -0.999], np.full(n, -math.pi)])
    upper = np.concatenate([[0.5 - 1e-4, 0.999], np.full(n, math.pi)])
    return scipy.optimize.least_squares(
        residuals,
        x0,
        jac="3-point",
        jac_sparsity=sparsity,
        bounds=(lower, upper),
        method="trf",
        x_scale="jac",
        xtol=1e-15,
        ftol=1e-15,
        gtol=1e-12,
        max_nfev=200,
    )


def _global_covariance(res: scipy.optimize.OptimizeResult, n: int) -> FloatArray:
    """``(2, 2)`` marginal covariance of ``(k, rate)``: the Schur complement of the per-pose
    theta blocks of the normal equations, scaled by the residual variance.

    Raises:
        ValueError: the Schur complement is singular (k and delta_max not observable).
    """
    jac = res.jac.tocsr()
    globals_ = np.asarray(jac[:, :2].todense())  # (3N, 2)
    rows = np.arange(3 * n)
    a = np.asarray(jac[rows, 2 + rows % n]).reshape(3, n).T  # d residual / d theta_j, (N, 3)
    g = globals_.reshape(3, n, 2).transpose(1, 0, 2)  # (N, 3, 2)
    aa = np.einsum("ni,ni->n", a, a)
    ag = np.einsum("ni,nij->nj", a, g)
    schur = np.einsum("nij,nik->jk", g, g) - np.einsum(
        "nj,nk,n->jk", ag, ag, 1.0 / np.maximum(aa, 1e-300)
    )
    dof = max(3 * n - (n + 2), 1)
    scale = float(np.sum(res.fun**2)) / dof
    if np.linalg.cond(schur) > 1e12:
        raise ValueError(
            "k and delta_max are not observable from this sweep (singular normal equations); "
            "record poses across the bending range"
        )
    return np.linalg.inv(schur) * max(scale, 1e-30)


def _sweep_theta_max(thetas: FloatArray, theta_max: float | None) -> float:
    """The given bending limit, checked, or the largest fitted ``|theta|``."""
    if theta_max is None:
        theta_max = float(np.max(np.abs(thetas)))
    else:
        theta_max = positive_number("theta_max", theta_max)
    if theta_max > math.pi:
        raise ValueError(f"theta_max = {theta_max!r}: expected theta_max <= pi")
    return theta_max


def fit_segment(
    tip_positions: ArrayLike,
    tip_angles: ArrayLike,
    length: float,
    theta_max: float | None = None,
    position_sigma: float | None = None,
    angle_sigma: float | None = None,
) -> SweepCalibration:
    """Least-squares calibration of k and delta_max over a recorded sweep of tip poses.

    Unknowns: k, the deviation rate ``delta_max / theta_max`` and one theta per pose. Residuals:
    tip position (``/ position_sigma``) and tip angle (``/ angle_sigma``) of each pose. Solved by
    scipy's trust-region least squares with the sparse Jacobian structure (each pose depends on
    its own theta and the two globals). Uncertainty of the globals comes from the Schur complement
    of the normal equations, scaled by the residual variance.

    Args:
        tip_positions: ``(N, 2)`` tips ``(x, z)`` in the bending plane (metres), N >= 2.
        tip_angles: ``(N,)`` tip tangent angles (radians).
        length: segment length L (metres).
        theta_max: the segment's bending limit (radians); default the largest fitted ``|theta|``.
        position_sigma: position noise (metres); default ``0.002 L``.
        angle_sigma: angle noise (radians); default 0.5 degrees.

    Returns:
        The calibration, its uncertainty, and the APCC and PCC fits on the same data.

    Raises:
        ValueError: bad shapes or values, fewer than 2 poses, a tip beyond reach, or a sweep from
            which k and delta_max cannot be told apart (no pose bent more than 1 degree).
    """
    pos, ang, length = _check_sweep(tip_positions, tip_angles, length)
    if len(pos) < 2:
        raise ValueError(
            f"fit_segment needs at least 2 poses, got {len(pos)}: with one pose use "
            "calibrate_from_tip"
        )
    x0 = _sweep_start(pos, ang)
    sigmas = _default_sigmas(length, position_sigma, angle_sigma)
    res = _solve_sweep(pos, ang, length, x0, sigmas)
    k, rate, thetas = float(res.x[0]), float(res.x[1]), res.x[2:]
    cov = _global_covariance(res, len(pos))
    theta_max = _sweep_theta_max(thetas, theta_max)
    pcc_thetas = _solve_thetas(pos, ang, length, None, 0.0, sigmas)
    return SweepCalibration(
        k=k,
        delta_max=rate * theta_max,
        theta_max=theta_max,
        length=length,
        k_std=float(np.sqrt(cov[0, 0])),
        delta_max_std=float(np.sqrt(cov[1, 1]) * theta_max),
        apcc=_residuals_of(thetas, pos, ang, length, k, rate),
        pcc=_residuals_of(pcc_thetas, pos, ang, length, None, 0.0),
    )
