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

Two engines run these steps on the same pairs (one draw per call, :func:`_draws`): the numpy
functions here, the reference, and the same steps compiled by numba
(:mod:`~apcc_graph.frontend.ransac_jit`), the default, ten to fifteen times faster: a numpy
call spent its time in the fixed cost of a few hundred small array operations. They return the
same estimate to rounding. The straight hypothesis ``b = 0`` is scored with the first batch
only: its score never changes, so it could not beat a best score later.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from apcc_graph.frontend.eliminant import common_psi
from apcc_graph.frontend.geometry import checked_bearings
from apcc_graph.frontend.pair_roots import SMALL_BEND, PairSetup, _sign_changes, grid_eliminant
from apcc_graph.frontend.ransac import RansacInfo, _outcome, _refusal, _required_iterations
from apcc_graph.frontend.spatial_basis import (
    bending_sampson,
    bending_sampson_gradient,
    spatial_coefficients,
)
from apcc_graph.frontend.two_point import TRIVIAL_TOLERANCE
from apcc_graph.model.arrays import FloatArray, IntArray
from apcc_graph.model.camera import is_rigid, validate_pose
from apcc_graph.model.segment import Segment

RANSAC_GRID_STEP = math.radians(2.0)
"""The hypotheses' bracketing grid step (radians): coarser than the solver's, since a root
missed in one sample is found in another."""
ENGINES = ("numba", "numpy")
""":func:`two_point_ransac`'s implementations: compiled kernels, and the numpy reference."""


def quick_roots(setup: PairSetup, coef: FloatArray, straight: bool = True) -> FloatArray:
    """Approximate roots ``(M, 2)`` (bending vectors, radians) of S pairs ``(S, 2, 9, 6)``.

    Grid sign changes only (no search for close pairs, no polishing), the secant for theta,
    the kernel of the interpolated Bezout matrix for psi, ordered by grid interval then pair;
    roots within ``SMALL_BEND`` of straight are represented by the hypothesis ``b = 0``, added
    last if ``straight``, and the trivial root of a fixed base is dropped.
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
                        np.zeros((int(straight), 2))])
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
                     segment: Segment, max_iterations: int, batch: int, engine: str) -> None:
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
    if engine not in ENGINES:
        raise ValueError(f"engine = {engine!r}: expected one of {', '.join(ENGINES)}")


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
    engine: str = "numba",
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
        rng: random generator (default ``numpy.random.default_rng(0)``: deterministic); one
            draw of ``max_iterations`` pairs per call.
        max_iterations: cap on pairs drawn.
        batch: pairs per step (the stopping rule is checked between steps).
        min_inliers: fewer inliers than this is a failure.
        engine: ``"numba"``, the compiled kernels (:mod:`~apcc_graph.frontend.ransac_jit`;
            the first call in a fresh environment compiles them, some seconds, then they are
            loaded from numba's cache), or ``"numpy"``, the reference; both give the same
            result to rounding.

    Returns:
        ``(bend, info)``: ``bend = (theta_b, psi_b)`` with ``theta_b >= 0`` and ``psi_b`` in
        ``(-pi, pi]`` (radians; NaN on failure), and the
        :class:`~apcc_graph.frontend.ransac.RansacInfo` (``info.errors`` are Sampson errors in
        radians at the estimate).

    Raises:
        ValueError: bearings not ``(N, 3)`` alike, or a non-finite angle, a threshold that is not
            positive, a confidence outside (0, 1), iteration counts below 1, an unknown engine,
            or a transform that is not rigid (named).
        TypeError: ``segment`` is not a :class:`~apcc_graph.model.segment.Segment`.
    """
    f_a, f_b = checked_bearings(f_a, f_b)
    _check_arguments(threshold, confidence, theta_a, psi_a, segment, max_iterations, batch,
                     engine)
    rng = np.random.default_rng(0) if rng is None else rng
    run = _ransac_numpy if engine == "numpy" else _ransac_compiled
    for name, value in (("tip_T_cam", tip_T_cam), ("baseA_T_baseB", baseA_T_baseB)):
        if value is not None and not is_rigid(value):
            validate_pose(name, value)  # raises, naming what is wrong
    b, errors, idx, iterations, hypotheses = run(
        theta_a, psi_a, segment, tip_T_cam, baseA_T_baseB, f_a, f_b, threshold, confidence,
        rng, max_iterations, batch, min_inliers)
    nan = np.full(2, np.nan)
    if isinstance(b, RansacInfo):  # refused
        return nan, b
    if b is None:
        return nan, RansacInfo(False, "no-consensus", "no pair of correspondences gave an "
                               "admissible root", np.zeros(len(f_a), dtype=bool), iterations,
                               math.inf, 0, hypotheses)
    theta, psi = math.hypot(b[0], b[1]), math.atan2(b[1], b[0])
    value, info = _outcome(theta, errors, idx, len(f_a), threshold, min_inliers, iterations,
                           hypotheses)
    return (nan if math.isnan(value) else np.array([theta, psi])), info


#: What :func:`two_point_ransac`'s engines return: the best bending vector (None: no
#: hypothesis; a RansacInfo: refused), the Sampson errors of the valid rows there, those rows,
#: the pairs drawn and the hypotheses scored.
_Run = tuple[FloatArray | RansacInfo | None, FloatArray, IntArray, int, int]


def _ransac_numpy(theta_a: float, psi_a: float, segment: Segment, tip_T_cam: ArrayLike | None,
                  baseA_T_baseB: ArrayLike | None, f_a: FloatArray, f_b: FloatArray,
                  threshold: float, confidence: float, rng: np.random.Generator,
                  max_iterations: int, batch: int, min_inliers: int) -> _Run:
    """The reference engine: numpy arrays throughout (:func:`two_point_ransac`)."""
    setup = PairSetup.build(theta_a, psi_a, segment, tip_T_cam, baseA_T_baseB,
                            RANSAC_GRID_STEP)
    draws = _draws(rng, max_iterations)
    valid = np.all(np.isfinite(f_a), axis=1) & np.all(np.isfinite(f_b), axis=1)
    idx = np.flatnonzero(valid)
    fa, fb = f_a[idx], f_b[idx]
    refusal = _refusal(fa, fb, len(f_a), setup.view, threshold, max(2, min_inliers))
    if refusal is not None:
        return refusal, np.zeros(0), idx, 0, 0
    pairs = _pairs(draws, len(fa))
    coef = spatial_coefficients(fa, fb, setup.view)
    b, iterations, hypotheses = _sample_consensus(setup, coef, fa, fb, threshold, confidence,
                                                  pairs, batch)
    if b is None:
        return None, np.zeros(0), idx, iterations, hypotheses
    b, errors = _local_optimisation(setup, fa, fb, b, threshold)
    return b, errors, idx, iterations, hypotheses


_IDENTITY = np.eye(4)  # never written (read-only arrays would be another compiled signature)


def _transform(value: ArrayLike | None) -> FloatArray:
    """A 4x4 transform as a contiguous float array (None: the identity)."""
    out = _IDENTITY if value is None else np.ascontiguousarray(value, dtype=float)
    if out.shape != (4, 4) or not np.isfinite(out).all():
        raise ValueError("tip_T_cam and baseA_T_baseB must be finite 4x4 transforms")
    return out


def _ransac_compiled(theta_a: float, psi_a: float, segment: Segment,
                     tip_T_cam: ArrayLike | None, baseA_T_baseB: ArrayLike | None,
                     f_a: FloatArray, f_b: FloatArray, threshold: float, confidence: float,
                     rng: np.random.Generator, max_iterations: int, batch: int,
                     min_inliers: int) -> _Run:
    """The compiled engine (:func:`~apcc_graph.frontend.ransac_jit.ransac`): the same steps on
    the same pairs, in one call; the refusals are the reference's, asked only when the kernel
    says that one may apply."""
    from apcc_graph.frontend import ransac_jit
    from apcc_graph.frontend.spatial_jit import segment_parameters

    tip, base = _transform(tip_T_cam), _transform(baseA_T_baseB)
    f_a, f_b = np.ascontiguousarray(f_a), np.ascontiguousarray(f_b)
    least = max(2, min_inliers)
    options = np.array([theta_a, psi_a, threshold, confidence, batch, least, SMALL_BEND,
                        RANSAC_GRID_STEP, TRIVIAL_TOLERANCE, 0.0], dtype=float)
    args = (f_a, f_b, tip, base, segment_parameters(segment), _draws(rng, max_iterations),
            options)
    outcome, u, v, idx, errors, iterations, hypotheses = ransac_jit.ransac(*args)
    if outcome == ransac_jit.MAY_REFUSE:
        view = PairSetup.build(theta_a, psi_a, segment, tip, base, RANSAC_GRID_STEP).view
        refusal = _refusal(f_a[idx], f_b[idx], len(f_a), view, threshold, least)
        if refusal is not None:
            return refusal, np.zeros(0), idx, 0, 0
        options[-1] = 1.0  # screened: run after all
        outcome, u, v, idx, errors, iterations, hypotheses = ransac_jit.ransac(*args)
    b = np.array([u, v]) if outcome == ransac_jit.FOUND else None
    return b, errors, idx, iterations, hypotheses


def _draws(rng: np.random.Generator, count: int) -> IntArray:
    """``(count,)`` uniform 62-bit integers, one per pair of correspondences (:func:`_pairs`
    turns them into pairs): one generator call, before the number of valid rows is known."""
    return rng.integers(0, 1 << 62, count)


def _pairs(draws: IntArray, n: int) -> IntArray:
    """``(count, 2)`` pairs of distinct indices below n from :func:`_draws`: ``k = draw mod
    n (n - 1)`` (uniform to within ``n^2 / 2^62``), ``k = (n - 1) i + r`` is the pair ``(i, (i
    + 1 + r) mod n)``."""
    first, offset = np.divmod(draws % (n * (n - 1)), n - 1)
    return np.stack([first, (first + 1 + offset) % n], axis=-1)


def _sample_consensus(setup: PairSetup, coef: FloatArray, fa: FloatArray, fb: FloatArray,
                      threshold: float, confidence: float, pairs: IntArray,
                      batch: int) -> tuple[FloatArray | None, int, int]:
    """The best-scoring hypothesis (None if none), the pairs used and hypotheses scored.

    The drawn ``pairs`` are taken ``batch`` at a time until the stopping rule is met. The
    straight hypothesis ``b = 0`` is scored with the first batch only: its score never
    changes, so it could never beat a best score again.
    """
    thr2 = threshold * threshold
    best_score, best, hypotheses, iterations = math.inf, None, 0, 0
    total = len(pairs)
    needed = float(total)
    while iterations < min(needed, total):
        take = int(min(batch, total - iterations))
        b = quick_roots(setup, coef[pairs[iterations:iterations + take]], iterations == 0)
        iterations += take
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
