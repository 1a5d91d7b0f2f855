"""The compiled 2-point RANSAC: hypotheses of a batch of pairs, MSAC with early exit, the
adaptive stopping rule and LO refinement, in one call.

The numpy reference is :mod:`~apcc_graph.frontend.spatial_ransac` (docs/estimation.md, "Two
correspondences: the 2-point solver of a spatial segment"); this module runs the same steps on
the same pairs in the same order, so both return the same estimate (to rounding). The one
liberty: a hypothesis' score is abandoned as soon as its running sum exceeds the best score so
far (of the call and of the batch), since it can then neither be the batch's best nor beat the
call's; the winner of every batch is unchanged.

Conventions as :mod:`~apcc_graph.frontend.spatial_jit` (radians; ``seg`` from
:func:`~apcc_graph.frontend.spatial_jit.segment_parameters`; ``anchor`` NaN for a moving base).
"""

from __future__ import annotations

import math

import numpy as np

from apcc_graph.frontend.pair_jit import (
    bezout_matrix,
    coefficients,
    common_psi,
    grid_functions,
    grid_nodes,
    left_part,
    pair_on_grid,
)
from apcc_graph.frontend.spatial_jit import (
    CHUNK,
    bend_matrices,
    essential_matrices,
    msac_score,
    refine,
)
from apcc_graph.model.arrays import FloatArray, IntArray
from apcc_graph.model.kernel_cache import njit

DEPENDS = "68f2c3aeb276160a"
"""Digest of :mod:`~apcc_graph.frontend.pair_jit` and :mod:`~apcc_graph.frontend.spatial_jit`,
whose kernels this module's cached kernels compile in (``tests/test_spatial_ransac_fast.py``).
numba's cache checks the text of each kernel's own file only, so a kernel compiled with
stale callees could load from it; a test keeps this line current, which changes this
file whenever those sources change."""


@njit(cache=True)
def _grid_eliminant(pairs: IntArray, fa: FloatArray, fb: FloatArray, left: FloatArray,
                    right: FloatArray, grid: FloatArray, Ft: FloatArray, anchor: float
                    ) -> tuple[FloatArray, FloatArray]:
    """``D`` ``(S, G)`` (deflated by ``theta - anchor`` unless NaN) and the Bezout matrices
    ``(S, 10, G)`` (:func:`~apcc_graph.frontend.pair_jit.pair_on_grid`) of S pairs on the
    grid (``Ft``: the functions there, ``(9, G)``)."""
    S, G = pairs.shape[0], grid.shape[0]
    W1, W2 = np.empty((9, 6)), np.empty((9, 6))
    D = np.empty((S, G))
    B = np.empty((S, 10, G))
    for s in range(S):
        coefficients(fa[pairs[s, 0]], fb[pairs[s, 0]], left, right, W1)
        coefficients(fa[pairs[s, 1]], fb[pairs[s, 1]], left, right, W2)
        pair_on_grid(W1, W2, Ft, grid, D[s], B[s])
        if anchor == anchor:
            for g in range(G):
                D[s, g] /= grid[g] - anchor
    return D, B


@njit(cache=True)
def batch_hypotheses(pairs: IntArray, fa: FloatArray, fb: FloatArray, left: FloatArray,
                     right: FloatArray, grid: FloatArray, Ft: FloatArray, anchor: float,
                     b_a: FloatArray, straight: bool, trivial: float) -> FloatArray:
    """Approximate roots ``(M, 2)`` (bending vectors) of S pairs of correspondence indices, as
    :func:`~apcc_graph.frontend.spatial_ransac.quick_roots`: ordered by grid interval then
    pair, then ``b = 0`` if ``straight``; within ``trivial`` of ``b_a`` dropped (fixed base)."""
    D, B = _grid_eliminant(pairs, fa, fb, left, right, grid, Ft, anchor)
    S, G = D.shape
    out = np.empty((S * (G - 1) + 1, 2))
    Bx = np.empty(10)
    m = 0
    for g in range(G - 1):
        for s in range(S):
            lo, hi = D[s, g], D[s, g + 1]
            if not (np.isfinite(lo) and np.isfinite(hi) and (lo > 0.0) != (hi > 0.0)):
                continue
            lam = lo / (lo - hi)
            theta = grid[g] + lam * (grid[g + 1] - grid[g])
            for k in range(10):
                Bx[k] = (1.0 - lam) * B[s, k, g] + lam * B[s, k, g + 1]
            psi = common_psi(bezout_matrix(Bx))
            out[m, 0], out[m, 1] = theta * math.cos(psi), theta * math.sin(psi)
            m += 1
    if straight:
        out[m] = 0.0
        m += 1
    if anchor != anchor:
        return out[:m]
    keep = 0
    for i in range(m):
        if math.hypot(out[i, 0] - b_a[0], out[i, 1] - b_a[1]) > trivial:
            out[keep] = out[i]
            keep += 1
    return out[:keep]


@njit(cache=True)
def required_iterations(inlier_ratio: float, confidence: float) -> float:
    """Samples for ``confidence`` of one all-inlier sample at a sample inlier ratio
    (:func:`~apcc_graph.frontend.ransac._required_iterations`)."""
    if inlier_ratio <= 0.0:
        return math.inf
    if inlier_ratio >= 1.0:
        return 1.0
    return math.log(1.0 - confidence) / math.log(1.0 - inlier_ratio)


@njit(cache=True)
def _best_of(hyps: FloatArray, ca: FloatArray, cb: FloatArray, left: FloatArray,
             right: FloatArray, seg: FloatArray, thr2: float, best_score: float
             ) -> tuple[int, float]:
    """The first hypothesis of least MSAC score on the bearings' columns ``(3, N)`` and that
    score, ``(-1, inf)`` if every score exceeds ``best_score`` (scores abandoned above both it
    and the batch's best so far)."""
    j, low = -1, math.inf
    scratch = np.empty(CHUNK)
    for h in range(hyps.shape[0]):
        E = essential_matrices(left, right, bend_matrices(hyps[h, 0], hyps[h, 1], seg,
                                                          False))[0]
        bound = min(best_score, low)
        score = msac_score(E, ca, cb, thr2, bound, scratch)
        if score <= bound and score < low:
            j, low = h, score
    return j, low


@njit(cache=True)
def pairs_of(draws: IntArray, n: int) -> IntArray:
    """``(count, 2)`` pairs of distinct indices below n from non-negative draws
    (:func:`~apcc_graph.frontend.spatial_ransac._pairs`)."""
    out = np.empty((draws.shape[0], 2), dtype=np.int64)
    for i in range(draws.shape[0]):
        k = draws[i] % (n * (n - 1))
        first, offset = k // (n - 1), k % (n - 1)
        out[i, 0], out[i, 1] = first, (first + 1 + offset) % n
    return out


@njit(cache=True)
def consensus(fa: FloatArray, fb: FloatArray, ca: FloatArray, cb: FloatArray,
              left: FloatArray, right: FloatArray, seg: FloatArray, grid: FloatArray,
              Ft: FloatArray, anchor: float, b_a: FloatArray, draws: IntArray,
              threshold: float, confidence: float, batch: int, trivial: float
              ) -> tuple[bool, float, float, int, int]:
    """The sampling loop of :func:`~apcc_graph.frontend.spatial_ransac._sample_consensus` over
    the drawn pairs (:func:`pairs_of`), on the bearings as rows ``fa, fb`` ``(N, 3)`` and as
    columns ``ca, cb`` ``(3, N)``: ``(found, u, v, pairs used, hypotheses)``."""
    thr2 = threshold * threshold
    best_score, u, v, found = math.inf, math.nan, math.nan, False
    hypotheses, iterations, total = 0, 0, draws.shape[0]
    needed = float(total)
    while iterations < min(needed, total):
        take = min(batch, total - iterations)
        pairs = pairs_of(draws[iterations:iterations + take], fa.shape[0])
        hyps = batch_hypotheses(pairs, fa, fb, left, right, grid, Ft, anchor, b_a,
                                iterations == 0, trivial)
        iterations += take
        if hyps.shape[0] == 0:
            continue
        hypotheses += hyps.shape[0]
        j, low = _best_of(hyps, ca, cb, left, right, seg, thr2, best_score)
        if j >= 0 and low < best_score:
            # LO-RANSAC: a new best is refined at once by one robust Gauss-Newton step.
            u, v, e = refine(left, right, seg, ca, cb, hyps[j, 0], hyps[j, 1], threshold, 1)
            found = True
            refined, inliers = 0.0, 0
            for i in range(e.shape[0]):
                refined += min(e[i] * e[i], thr2)
                inliers += abs(e[i]) < threshold
            best_score = min(low, refined)
            ratio = inliers / e.shape[0]
            needed = required_iterations(ratio * ratio, confidence)
    return found, u, v, iterations, hypotheses


@njit(cache=True)
def screen_rows(f_a: FloatArray, f_b: FloatArray, base: FloatArray, threshold: float
                ) -> tuple[IntArray, bool, float]:
    """The rows without NaN, whether ``base`` is the identity (to 1e-12: a fixed base), and the
    fraction of those rows with a parallax ``|f_a x f_b|`` below ``threshold``."""
    idx = np.empty(f_a.shape[0], dtype=np.int64)
    n, still = 0, 0
    for i in range(f_a.shape[0]):
        finite = True
        for k in range(3):
            finite &= math.isfinite(f_a[i, k]) and math.isfinite(f_b[i, k])
        if not finite:
            continue
        idx[n] = i
        n += 1
        c0 = f_a[i, 1] * f_b[i, 2] - f_a[i, 2] * f_b[i, 1]
        c1 = f_a[i, 2] * f_b[i, 0] - f_a[i, 0] * f_b[i, 2]
        c2 = f_a[i, 0] * f_b[i, 1] - f_a[i, 1] * f_b[i, 0]
        still += math.sqrt(c0 * c0 + c1 * c1 + c2 * c2) < threshold
    fixed = True
    for i in range(4):
        for j in range(4):
            fixed &= abs(base[i, j] - (1.0 if i == j else 0.0)) < 1e-12
    return idx[:n], fixed, still / max(n, 1)


#: :func:`ransac`'s outcomes.
FOUND, NO_HYPOTHESIS, MAY_REFUSE = 0, 1, 2


@njit(cache=True)
def ransac(f_a: FloatArray, f_b: FloatArray, tip: FloatArray, base: FloatArray,
           seg: FloatArray, draws: IntArray, options: FloatArray
           ) -> tuple[int, float, float, IntArray, FloatArray, int, int]:
    """The whole RANSAC on ``(N, 3)`` bearings: the rows without NaN, the frame pair's fixed
    parts and grid, :func:`consensus` and the final LO refinement (two robust Gauss-Newton
    steps).

    Args:
        options: ``[theta_a, psi_a, threshold, confidence, batch, least, grid low end, grid
            step, trivial tolerance, screened]``: unless ``screened`` is 1, fewer than
            ``least`` valid rows, or a fixed base with most rows showing no parallax, stop
            at once with :data:`MAY_REFUSE` (the caller decides).

    Returns:
        ``(outcome, u, v, valid rows, their Sampson errors, pairs used, hypotheses)``, the
        outcome one of :data:`FOUND`, :data:`NO_HYPOTHESIS`, :data:`MAY_REFUSE`.
    """
    theta_a, psi_a, threshold, confidence = options[0], options[1], options[2], options[3]
    idx, fixed, still = screen_rows(f_a, f_b, base, threshold)
    if options[9] != 1.0 and (idx.shape[0] < options[5] or (fixed and still >= 0.5)):
        return MAY_REFUSE, math.nan, math.nan, idx, np.zeros(0), 0, 0
    fa, fb = f_a[idx], f_b[idx]
    ca, cb = np.ascontiguousarray(fa.T), np.ascontiguousarray(fb.T)
    left = left_part(theta_a, psi_a, seg, tip, base)
    anchor = abs(theta_a) if fixed else math.nan
    grid = grid_nodes(options[6], seg[4], anchor, options[7])
    b_a = np.array([theta_a * math.cos(psi_a), theta_a * math.sin(psi_a)])
    found, u, v, iterations, hypotheses = consensus(
        fa, fb, ca, cb, left, tip, seg, grid, grid_functions(grid, seg), anchor, b_a, draws,
        threshold, confidence, int(options[4]), options[8])
    if not found:
        return NO_HYPOTHESIS, u, v, idx, np.zeros(0), iterations, hypotheses
    u, v, errors = refine(left, tip, seg, ca, cb, u, v, threshold, 2)
    return FOUND, u, v, idx, errors, iterations, hypotheses
