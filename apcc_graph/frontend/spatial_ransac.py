"""2-point RANSAC around the 2-point solver, and robust refinement of a spatial segment's bending
vector.

Hypotheses come from pairs of correspondences (docs/estimation.md, "Two correspondences: the
2-point solver of a spatial segment"): the eliminant of a batch of pairs is evaluated on the
grid in one array operation (:func:`~apcc_graph.frontend.pair_roots.grid_eliminant`), every sign
change gives a root by the secant through its two nodes, and psi comes from the kernel of the
Bezout matrix interpolated there (:func:`~apcc_graph.frontend.eliminant.common_psi`). Such a
root is accurate to a small fraction of a degree, plenty to score: all hypotheses of a batch
are scored on all correspondences at once (MSAC, the truncated squared Sampson error), the
number of samples adapts to the best inlier ratio, and the best hypothesis is refined on its
inliers by Huber-weighted Gauss-Newton in the bending vector ``b = (u, v)``
(:func:`refine_bending`), smooth through straight, so the exact root is never needed.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from apcc_graph.frontend.eliminant import common_psi
from apcc_graph.frontend.geometry import checked_bearings
from apcc_graph.frontend.pair_roots import PairSetup, _sign_changes, grid_eliminant
from apcc_graph.frontend.ransac import RansacInfo, _outcome, _refusal, _required_iterations
from apcc_graph.frontend.spatial_basis import (
    bending_sampson,
    bending_sampson_gradient,
    spatial_coefficients,
)
from apcc_graph.frontend.two_point import TRIVIAL_TOLERANCE
from apcc_graph.model.arrays import FloatArray, IntArray
from apcc_graph.model.bending import polar
from apcc_graph.model.segment import Segment

RANSAC_GRID_STEP = math.radians(2.0)
"""The hypotheses' bracketing grid step (radians): coarser than the solver's, since a root
missed in one sample is found in another."""


def quick_roots(setup: PairSetup, coef: FloatArray) -> FloatArray:
    """Approximate roots ``(M, 2)`` (bending vectors, radians) of S pairs ``(S, 2, 9, 6)``.

    Grid sign changes only (no search for close pairs, no polishing), the secant for theta,
    the kernel of the interpolated Bezout matrix for psi; roots within ``SMALL_BEND`` of
    straight are represented by the hypothesis ``b = 0``, added once, and the trivial root of
    a fixed base is dropped.
    """
    scale = np.max(np.abs(coef), axis=(2, 3), keepdims=True)
    coef = coef / np.where(scale > 0.0, scale, 1.0)
    grid = setup.grid
    D, B = grid_eliminant(setup, coef)
    nodes = np.broadcast_to(grid[:, None], D.shape)
    cols, lo, hi, flo, fhi = _sign_changes(nodes, D)
    rows = np.searchsorted(grid, lo)
    lam = flo / (flo - fhi)
    theta = lo + lam * (hi - lo)
    Bx = (1.0 - lam)[:, None, None] * B[rows, cols] + lam[:, None, None] * B[rows + 1, cols]
    psi = common_psi(Bx)
    b = np.concatenate([np.stack([theta * np.cos(psi), theta * np.sin(psi)], axis=-1),
                        np.zeros((1, 2))])
    if setup.anchor is not None:
        b = b[np.hypot(*(b - setup.b_a).T) > TRIVIAL_TOLERANCE]
    return b


def refine_bending(f_a: FloatArray, f_b: FloatArray, setup: PairSetup, b: FloatArray,
                   threshold: float, iterations: int = 3) -> tuple[FloatArray, FloatArray]:
    """Robust Gauss-Newton on the Sampson errors in the bending vector, ``(2,)`` radians.

    Each step takes the correspondences with a Sampson error below ``3 threshold`` at the
    current estimate, weights them by Huber's function (scale ``threshold``, radians) and
    solves the 2x2 normal equations; the bend is kept within ``theta_max``. Through straight
    nothing changes: ``(u, v)`` are smooth coordinates.

    Returns:
        the refined bending vector and the Sampson errors ``(N,)`` there.
    """
    b = np.array(b, dtype=float)
    lim = setup.view.segment.theta_max
    for _ in range(iterations):
        e, grad = bending_sampson_gradient(f_a, f_b, setup.view, b[0], b[1])
        r = np.abs(e)
        w = np.where(r <= threshold, 1.0, np.where(r < 3.0 * threshold,
                                                    threshold / np.maximum(r, 1e-300), 0.0))
        wg = w * grad
        H = wg @ grad.T
        g = wg @ e
        det = H[0, 0] * H[1, 1] - H[0, 1] * H[1, 0]
        if not det > 0.0:
            break
        step = np.array([H[1, 1] * g[0] - H[0, 1] * g[1], H[0, 0] * g[1] - H[1, 0] * g[0]]) / det
        b = b - step
        norm = math.hypot(b[0], b[1])
        if norm > lim:
            b *= lim / norm
        if math.hypot(step[0], step[1]) < 1e-10:  # radians: far below any measurable change
            break
    return b, bending_sampson(f_a, f_b, setup.view, b[:1], b[1:])[0]


def _check_arguments(threshold: float, confidence: float, theta_a: float, psi_a: float,
                     segment: Segment, max_iterations: int, batch: int) -> None:
    """Refuse arguments that cannot describe an estimate, naming them and the expectation."""
    if not isinstance(segment, Segment):
        raise TypeError(f"segment is a {type(segment).__name__}: expected a Segment")
    for name, value in (("theta_a", theta_a), ("psi_a", psi_a)):
        if not (isinstance(value, (int, float, np.floating)) and math.isfinite(value)):
            raise ValueError(f"{name} = {value!r}: expected a finite angle in radians")
    if not (isinstance(threshold, (int, float, np.floating)) and math.isfinite(threshold)
            and threshold > 0.0):
        raise ValueError(f"threshold = {threshold!r}: expected a Sampson error > 0 in radians "
                         "(pixels / focal length)")
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence = {confidence!r}: expected a probability in (0, 1)")
    if max_iterations < 1 or batch < 1:
        raise ValueError(f"max_iterations = {max_iterations!r} and batch = {batch!r}: expected "
                         "at least 1 each")


def two_point_ransac(
    theta_a: float,
    psi_a: float,
    segment: Segment,
    tip_T_cam: ArrayLike | None,
    baseA_T_baseB: ArrayLike | None,
    f_a: ArrayLike,
    f_b: ArrayLike,
    threshold: float = 1.0 / 500.0,
    confidence: float = 0.999,
    rng: np.random.Generator | None = None,
    max_iterations: int = 500,
    batch: int = 8,
    min_inliers: int = 5,
) -> tuple[FloatArray, RansacInfo]:
    """Estimate a spatial segment's bend at frame b from correspondences with outliers.

    Frames and conventions as :func:`~apcc_graph.frontend.two_point.two_point`: bearings in the
    camera at frames a and b, ``tip_T_cam`` the mounting, ``baseA_T_baseB`` the base motion
    (None: fixed base, whose trivial solution ``b_b = b_a`` is never a hypothesis).

    Args:
        theta_a, psi_a: frame a's bend (radians).
        segment: the segment.
        tip_T_cam, baseA_T_baseB: camera mounting and base motion (None: identity).
        f_a, f_b: ``(N, 3)`` unit bearings; rows with NaN are ignored.
        threshold: inlier threshold on the Sampson error in radians (pixels / focal length).
        confidence: probability of drawing at least one all-inlier pair.
        rng: random generator (default ``numpy.random.default_rng(0)``: deterministic).
        max_iterations: cap on pairs drawn.
        batch: pairs per vectorised step.
        min_inliers: fewer inliers than this is a failure.

    Returns:
        ``(bend, info)``: ``bend = (theta_b, psi_b)`` with ``theta_b >= 0`` and ``psi_b`` in
        ``(-pi, pi]`` (radians; NaN on failure), and the
        :class:`~apcc_graph.frontend.ransac.RansacInfo` (``info.errors`` are Sampson errors in
        radians at the estimate).

    Raises:
        ValueError: bearings not ``(N, 3)`` alike, or a non-finite angle, a threshold that is not
            positive, a confidence outside (0, 1), or iteration counts below 1.
        TypeError: ``segment`` is not a :class:`~apcc_graph.model.segment.Segment`.
    """
    f_a, f_b = checked_bearings(f_a, f_b)
    _check_arguments(threshold, confidence, theta_a, psi_a, segment, max_iterations, batch)
    rng = np.random.default_rng(0) if rng is None else rng
    setup = PairSetup.build(theta_a, psi_a, segment, tip_T_cam, baseA_T_baseB,
                            RANSAC_GRID_STEP)
    valid = np.all(np.isfinite(f_a), axis=1) & np.all(np.isfinite(f_b), axis=1)
    idx = np.flatnonzero(valid)
    fa, fb = f_a[idx], f_b[idx]
    refusal = _refusal(fa, fb, len(f_a), setup.view, threshold, max(2, min_inliers))
    nan = np.full(2, np.nan)
    if refusal is not None:
        return nan, refusal
    coef = spatial_coefficients(fa, fb, setup.view)
    b, iterations, hypotheses = _sample_consensus(setup, coef, fa, fb, threshold, confidence,
                                                  rng, max_iterations, batch)
    if b is None:
        return nan, RansacInfo(False, "no-consensus", "no pair of correspondences gave an "
                               "admissible root", np.zeros(len(f_a), dtype=bool), iterations,
                               math.inf, 0, hypotheses)
    b, errors = _local_optimisation(setup, fa, fb, b, threshold)
    theta, psi = polar(b[0], b[1])
    value, info = _outcome(float(theta), errors, idx, len(f_a), threshold, min_inliers,
                           iterations, hypotheses)
    return (nan if math.isnan(value) else np.array([float(theta), float(psi)])), info


def _pairs(rng: np.random.Generator, n: int, count: int) -> IntArray:
    """``(count, 2)`` random pairs of distinct indices below n."""
    first = rng.integers(0, n, count)
    return np.stack([first, (first + rng.integers(1, n, count)) % n], axis=-1)


def _sample_consensus(setup: PairSetup, coef: FloatArray, fa: FloatArray, fb: FloatArray,
                      threshold: float, confidence: float, rng: np.random.Generator,
                      max_iterations: int, batch: int) -> tuple[FloatArray | None, int, int]:
    """The best-scoring hypothesis (None if none), the pairs drawn and hypotheses scored."""
    thr2 = threshold * threshold
    best_score, best, hypotheses, iterations = math.inf, None, 0, 0
    needed = float(max_iterations)
    while iterations < min(needed, max_iterations):
        take = int(min(batch, max_iterations - iterations))
        pairs = _pairs(rng, len(fa), take)
        iterations += take
        b = quick_roots(setup, coef[pairs])
        if len(b) == 0:
            continue
        hypotheses += len(b)
        errors = bending_sampson(fa, fb, setup.view, b[:, 0], b[:, 1])  # (M, N) at once
        scores = np.minimum(errors * errors, thr2).sum(axis=1)
        j = int(np.argmin(scores))
        if scores[j] < best_score:
            # LO-RANSAC: a new best is refined at once (one robust Gauss-Newton step), so that
            # the stopping rule counts the inliers of a polished hypothesis, not of a rough one.
            best, e = refine_bending(fa, fb, setup, b[j], threshold, 1)
            best_score = min(float(scores[j]), float(np.minimum(e * e, thr2).sum()))
            ratio = float(np.mean(np.abs(e) < threshold))
            needed = _required_iterations(ratio * ratio, confidence)
    return best, iterations, hypotheses


def _local_optimisation(setup: PairSetup, fa: FloatArray, fb: FloatArray, b: FloatArray,
                        threshold: float) -> tuple[FloatArray, FloatArray]:
    """LO-RANSAC: robust Gauss-Newton on all correspondences, re-selecting the inliers at every
    step (:func:`refine_bending`); the estimate and its Sampson errors."""
    return refine_bending(fa, fb, setup, b, threshold, 2)
