"""1-point RANSAC around the 1-point solver, and robust 1-D refinement of a segment's angle.

Hypotheses come from single correspondences (:func:`~apcc_graph.frontend.roots.solve_roots`,
every root of each), are scored on all correspondences at once through the basis expansion of
the Sampson error (:class:`~apcc_graph.frontend.basis.EpipolarBasis`), and the best is refined
on its inliers by Huber-weighted Gauss-Newton (:func:`refine_theta`; docs/estimation.md, "Two
frames").
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from apcc_graph.frontend.basis import EpipolarBasis
from apcc_graph.frontend.geometry import SegmentTwoView, checked_bearings, epipolar_errors
from apcc_graph.frontend.roots import DEFAULT_GRID_STEP, ConstraintFunction, solve_roots
from apcc_graph.model.arrays import FloatArray, IntArray
from apcc_graph.model.segment import Segment


@dataclass(frozen=True)
class RansacInfo:
    """Outcome of :func:`one_point_ransac`.

    Attributes:
        success: whether theta_b was estimated.
        status: ``"ok"``, ``"too-few-correspondences"``, ``"no-motion"`` or ``"no-consensus"``.
        message: a sentence for people.
        inliers: ``(N,)`` inlier mask of the returned estimate (all False on failure).
        iterations: samples drawn.
        score: MSAC score of the best hypothesis (sum of ``min(e^2, threshold^2)``, radians^2).
        n_inliers: number of inliers.
        hypotheses: number of hypotheses scored.
        errors: ``(N,)`` Sampson errors at the best hypothesis (NaN for invalid input rows).
    """

    success: bool
    status: str
    message: str
    inliers: NDArray[np.bool_]
    iterations: int
    score: float
    n_inliers: int = 0
    hypotheses: int = 0
    errors: FloatArray = field(default_factory=lambda: np.zeros(0), repr=False)


def _required_iterations(inlier_ratio: float, confidence: float) -> float:
    if inlier_ratio <= 0.0:
        return math.inf
    if inlier_ratio >= 1.0:
        return 1.0
    return math.log(1.0 - confidence) / math.log(1.0 - inlier_ratio)


def refine_theta(
    f_a: FloatArray, f_b: FloatArray, view: SegmentTwoView, theta_b: float, threshold: float,
    iterations: int = 5,
) -> float:
    """Robust 1-D Gauss-Newton on the Sampson error (Huber weights, scale = threshold).

    Iteratively reweighted least squares; 1-D, so each step is a ratio of sums and cheaper than a
    general solver call inside RANSAC's inner loop.
    """
    return _huber_gauss_newton(
        lambda t: epipolar_errors(f_a, f_b, view, t, derivative=True),
        theta_b, view.segment.theta_max, threshold, iterations)


def _huber_gauss_newton(errors: Callable[[float], tuple[FloatArray, FloatArray]],
                        theta_b: float, lim: float, threshold: float, iterations: int) -> float:
    """IRLS on a 1-D robust least squares: ``errors(theta) -> (e, de/dtheta)``, Huber weights."""
    theta = float(theta_b)
    for _ in range(iterations):
        e, de = errors(theta)
        r = np.abs(e)
        weight = np.where(r <= threshold, 1.0, threshold / np.maximum(r, 1e-300))
        hess = float(np.sum(weight * de * de))
        if hess <= 0.0:
            break
        delta = float(np.sum(weight * de * e)) / hess
        theta = min(max(theta - delta, -lim), lim)
        if abs(delta) < 1e-9:  # radians; far below any measurable change
            break
    return theta


def _refine_with_basis(basis: EpipolarBasis, mask: NDArray[np.bool_], theta_b: float,
                       threshold: float, iterations: int = 5) -> float:
    """:func:`refine_theta` on the rows in ``mask``, with errors from the basis expansion."""

    def errors(theta: float) -> tuple[FloatArray, FloatArray]:
        e, de = basis.errors(theta, derivative=True)
        return e[0, mask], de[0, mask]

    return _huber_gauss_newton(errors, theta_b, basis.view.segment.theta_max, threshold,
                               iterations)


def one_point_ransac(
    f_a: ArrayLike,
    f_b: ArrayLike,
    theta_a: float,
    segment: Segment,
    tip_T_cam: ArrayLike | None = None,
    baseA_T_baseB: ArrayLike | None = None,
    threshold: float = 1.0 / 500.0,
    confidence: float = 0.999,
    rng: np.random.Generator | None = None,
    psi: float = 0.0,
    max_iterations: int = 1000,
    batch: int = 8,
    min_inliers: int = 5,
) -> tuple[float, RansacInfo]:
    """Estimate theta_b from correspondences with outliers: 1-point RANSAC plus local refinement.

    Hypotheses come from single correspondences (``batch`` samples per numpy call, every root of
    each), all hypotheses of a batch are scored on all correspondences in one array operation
    (MSAC: truncated squared Sampson error), the number of samples adapts to the best inlier
    ratio, and the best hypothesis is refined on its inliers by robust 1-D least squares.

    Args:
        f_a, f_b: ``(N, 3)`` unit bearings.
        theta_a: the bend at frame a (radians).
        segment: the segment.
        tip_T_cam: camera mounting (default identity).
        baseA_T_baseB: base motion a -> b (default identity, fixed base).
        threshold: inlier threshold on the Sampson error in radians (pixels / focal length).
        confidence: probability of drawing at least one all-inlier sample.
        rng: random generator (default ``numpy.random.default_rng(0)``: deterministic).
        psi: bending-plane angle (radians).
        max_iterations: cap on samples.
        batch: samples per vectorised step.
        min_inliers: fewer inliers than this is a failure.

    Returns:
        ``(theta_b, info)``; on failure theta_b is NaN and ``info.status`` says why.
    """
    f_a, f_b = checked_bearings(f_a, f_b)
    rng = np.random.default_rng(0) if rng is None else rng
    view = SegmentTwoView.build(theta_a, segment, tip_T_cam, baseA_T_baseB, psi)
    valid = np.all(np.isfinite(f_a), axis=1) & np.all(np.isfinite(f_b), axis=1)
    idx = np.flatnonzero(valid)
    fa, fb = f_a[idx], f_b[idx]
    refusal = _refusal(fa, fb, len(f_a), view, threshold, min_inliers)
    if refusal is not None:
        return math.nan, refusal
    basis = EpipolarBasis(fa, fb, view)
    theta, iterations, hypotheses = _sample_consensus(basis, threshold, confidence, rng,
                                                      max_iterations, batch)
    if not math.isfinite(theta):
        return math.nan, RansacInfo(False, "no-consensus", "no correspondence gave an admissible "
                                    "root", np.zeros(len(f_a), dtype=bool), iterations, math.inf,
                                    0, hypotheses)
    theta, errors = _local_optimisation(basis, theta, threshold)
    return _outcome(theta, errors, idx, len(f_a), threshold, min_inliers, iterations, hypotheses)


def _refusal(fa: FloatArray, fb: FloatArray, n: int, view: SegmentTwoView, threshold: float,
             min_inliers: int) -> RansacInfo | None:
    """Why there is nothing to estimate from the valid rows ``fa, fb`` of ``n``, or None."""
    none = np.zeros(n, dtype=bool)
    if len(fa) < max(1, min_inliers):
        return RansacInfo(False, "too-few-correspondences", f"{len(fa)} valid correspondences, "
                          f"need at least {max(1, min_inliers)}", none, 0, math.inf)
    if view.fixed_base:
        # Zero segment motion: the bearings coincide. Trivial root excluded, nothing to estimate.
        parallax = np.linalg.norm(np.cross(fa, fb), axis=1)
        if np.mean(parallax < threshold) >= 0.5:
            return RansacInfo(
                False, "no-motion", "most correspondences show no parallax: the camera did not "
                "move, theta_b = theta_a is the only consistent reading and is not a measurement",
                none, 0, math.inf)
    return None


def _sample_consensus(basis: EpipolarBasis, threshold: float, confidence: float,
                      rng: np.random.Generator, max_iterations: int, batch: int
                      ) -> tuple[float, int, int]:
    """The best-scoring hypothesis (NaN if none), the samples drawn and hypotheses scored."""
    view = basis.view
    fn = ConstraintFunction(view)
    thr2 = threshold * threshold
    best_score, best_theta, hypotheses, iterations = math.inf, math.nan, 0, 0
    needed = float(max_iterations)
    while iterations < min(needed, max_iterations):
        take = int(min(batch, max_iterations - iterations))
        sample = rng.integers(0, basis.n, take)
        iterations += take
        roots = solve_roots(basis.coef[sample], view, DEFAULT_GRID_STEP, fn).ravel()
        roots = roots[np.isfinite(roots)]
        if len(roots) == 0:
            continue
        hypotheses += len(roots)
        errors = basis.errors(roots)  # (M, N): all hypotheses scored in one array operation
        scores = np.minimum(errors * errors, thr2).sum(axis=1)
        j = int(np.argmin(scores))
        if scores[j] < best_score:
            best_score, best_theta = float(scores[j]), float(roots[j])
            ratio = float(np.mean(np.abs(errors[j]) < threshold))
            needed = _required_iterations(ratio, confidence)
    return best_theta, iterations, hypotheses


def _local_optimisation(basis: EpipolarBasis, theta: float,
                        threshold: float) -> tuple[float, FloatArray]:
    """LO-RANSAC: refine on the inliers, re-select them, refine again; the errors there."""
    errors = basis.errors(theta)[0]
    for steps in (3, 2):
        inl = np.abs(errors) < threshold
        if inl.sum() < 2:
            break
        theta = _refine_with_basis(basis, inl, theta, threshold, steps)
        errors = basis.errors(theta)[0]
    return theta, errors


def _outcome(theta: float, errors: FloatArray, idx: IntArray, n: int, threshold: float,
             min_inliers: int, iterations: int, hypotheses: int) -> tuple[float, RansacInfo]:
    """The estimate and its :class:`RansacInfo` from the errors of the valid rows ``idx``."""
    inl = np.abs(errors) < threshold
    count = int(inl.sum())
    score = float(np.minimum(errors * errors, threshold * threshold).sum())
    inliers = np.zeros(n, dtype=bool)
    inliers[idx[inl]] = True
    all_errors = np.full(n, np.nan)
    all_errors[idx] = errors
    if count < min_inliers:
        return math.nan, RansacInfo(False, "no-consensus", f"best hypothesis has {count} "
                                    f"inliers, need {min_inliers}", np.zeros(n, dtype=bool),
                                    iterations, score, count, hypotheses, all_errors)
    return theta, RansacInfo(True, "ok", f"{count} of {n} inliers", inliers, iterations, score,
                             count, hypotheses, all_errors)
