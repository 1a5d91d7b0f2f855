"""Compiled kernels of the 2-point RANSAC's hypotheses: the frame pair's fixed parts, the grid,
the pairs' coefficients, the eliminant on the grid and the roots it brackets.

The numpy reference of each (docs/estimation.md, "Two correspondences: the 2-point solver of a
spatial segment"): :class:`~apcc_graph.frontend.geometry.SegmentTwoView` (``left``),
:func:`~apcc_graph.frontend.pair_roots._grid`,
:func:`~apcc_graph.frontend.spatial_basis.spatial_functions` and
:func:`~apcc_graph.frontend.spatial_basis.spatial_coefficients` (each correspondence scaled to
a largest coefficient of 1), :func:`~apcc_graph.frontend.eliminant.circle_quartics` and
:func:`~apcc_graph.frontend.eliminant.bezout_matrices` on the grid (:func:`pair_on_grid`), and
:func:`~apcc_graph.frontend.eliminant.common_psi` (psi from the kernel of a Bezout matrix).
Two liberties, both exact up to rounding: the Bezout matrix is symmetric, so only its ten
distinct entries are formed, and its determinant is the sum of the products of complementary
2x2 minors of rows (0, 1) and (2, 3) (no factorisation, no branch: the loop over the grid
vectorises); the small solves and inverses are LU factorisations with partial pivoting, written
out.

Conventions: radians; ``anchor`` is NaN without a deflation (a moving base); the nine functions
of theta on the grid are ``Ft`` ``(9, G)``; a correspondence's coefficients ``W`` are ``(9,
6)``: the nine functions by the monomials ``(1, u, v, u^2, uv, v^2)``.
"""

from __future__ import annotations

import math

import numpy as np

from apcc_graph.frontend.spatial_jit import bend_matrices, bend_terms
from apcc_graph.model.arrays import FloatArray, IntArray
from apcc_graph.model.kernel_cache import njit

DEPENDS = "0bad9c6fb126b9a6"
"""Digest of :mod:`~apcc_graph.frontend.spatial_jit`, whose kernels this module's cached kernels
compile in (``tests/test_spatial_ransac_fast.py``).
numba's cache checks the text of each kernel's own file only, so a kernel compiled with
stale callees could load from it; a test keeps this line current, which changes this
file whenever those sources change."""

#: The start vector of :func:`~apcc_graph.frontend.eliminant.common_psi`'s inverse iteration.
_START = (0.6, 0.43, -0.51, 0.37)


@njit(cache=True)
def _lu(A: FloatArray, piv: IntArray) -> float:
    """In-place LU factorisation with partial pivoting of a square ``A``; the permutation's
    sign (rows swapped as ``piv`` says). A zero pivot column is left as it is."""
    n = A.shape[0]
    sign = 1.0
    for k in range(n):
        p = k
        for i in range(k + 1, n):
            if abs(A[i, k]) > abs(A[p, k]):
                p = i
        piv[k] = p
        if p != k:
            sign = -sign
            for j in range(n):
                A[k, j], A[p, j] = A[p, j], A[k, j]
        if A[k, k] == 0.0:
            continue
        inv = 1.0 / A[k, k]
        for i in range(k + 1, n):
            A[i, k] *= inv
            for j in range(k + 1, n):
                A[i, j] -= A[i, k] * A[k, j]
    return sign


@njit(cache=True)
def _lu_solve(LU: FloatArray, piv: IntArray, x: FloatArray) -> None:
    """``x <- A^-1 x`` in place from :func:`_lu`'s factors."""
    n = LU.shape[0]
    for k in range(n):
        p = piv[k]
        x[k], x[p] = x[p], x[k]
    for i in range(n):
        for j in range(i):
            x[i] -= LU[i, j] * x[j]
    for i in range(n - 1, -1, -1):
        for j in range(i + 1, n):
            x[i] -= LU[i, j] * x[j]
        x[i] /= LU[i, i]


@njit(cache=True)
def _matmul(A: FloatArray, B: FloatArray) -> FloatArray:
    """``A @ B`` of small matrices."""
    out = np.zeros((A.shape[0], B.shape[1]))
    for i in range(A.shape[0]):
        for j in range(B.shape[1]):
            for m in range(A.shape[1]):
                out[i, j] += A[i, m] * B[m, j]
    return out


@njit(cache=True)
def _inverse(A: FloatArray) -> FloatArray:
    """``A^-1`` of a small invertible matrix, column by column."""
    n = A.shape[0]
    LU = A.copy()
    piv = np.empty(n, dtype=np.int64)
    _lu(LU, piv)
    out = np.empty((n, n))
    col = np.empty(n)
    for j in range(n):
        col[:] = 0.0
        col[j] = 1.0
        _lu_solve(LU, piv, col)
        out[:, j] = col
    return out


@njit(cache=True)
def left_part(theta_a: float, psi_a: float, seg: FloatArray, tip: FloatArray,
              base: FloatArray) -> FloatArray:
    """``cam_T_tip . T(b_a)^-1 . baseA_T_baseB`` ``(4, 4)``: the fixed part left of the
    unknown bend (:class:`~apcc_graph.frontend.geometry.SegmentTwoView`'s ``left``)."""
    Ta = bend_matrices(theta_a * math.cos(psi_a), theta_a * math.sin(psi_a), seg, False)[0]
    return _matmul(_matmul(_inverse(tip), _inverse(Ta)), base)


@njit(cache=True)
def grid_nodes(lo: float, hi: float, anchor: float, step: float) -> FloatArray:
    """Nodes from lo to hi about ``step`` apart, none within a third of a step of the anchor
    (NaN: none), as :func:`~apcc_graph.frontend.pair_roots._grid`."""
    if not lo < anchor < hi:
        count = max(2, math.ceil((hi - lo) / step) + 1)
        delta = (hi - lo) / (count - 1)
        out = np.empty(count)
        for i in range(count):
            out[i] = i * delta + lo
        out[count - 1] = hi
        if anchor == anchor:  # an anchor at an end (a bend held at its limit) moves that end in
            shift = step / 3.0 if anchor < 0.5 * (lo + hi) else -step / 3.0
            for i in range(count):
                if abs(out[i] - anchor) < step / 3.0:
                    out[i] = anchor + shift
        return out
    k0, k1 = math.floor((lo - anchor) / step) - 1, math.ceil((hi - anchor) / step) + 1
    buf = np.empty(k1 - k0 + 2)
    n = 0
    for k in range(k0, k1):
        x = anchor + (k + 0.5) * step
        if lo < x < hi:
            buf[n] = x
            n += 1
    for end in (lo, hi):
        if abs(end - anchor) > step / 3.0:
            buf[n] = end
            n += 1
    return np.sort(buf[:n])


@njit(cache=True)
def grid_functions(grid: FloatArray, seg: FloatArray) -> FloatArray:
    """The nine functions of :func:`~apcc_graph.frontend.spatial_basis.spatial_functions` on
    the grid, transposed: ``(9, G)``."""
    F = np.empty((9, grid.shape[0]))
    for g in range(grid.shape[0]):
        cb, sigma, kappa, rho, pz = bend_terms(grid[g], seg)
        F[0, g], F[1, g], F[2, g], F[3, g] = cb, pz * cb, sigma, pz * sigma
        F[4, g], F[5, g], F[6, g], F[7, g] = rho * cb, rho, kappa, pz * kappa
        F[8, g] = rho * sigma
    return F


Vec = tuple[float, float, float]


@njit(cache=True)
def _cross(x: Vec, y: Vec) -> Vec:
    return (x[1] * y[2] - x[2] * y[1], x[2] * y[0] - x[0] * y[2], x[0] * y[1] - x[1] * y[0])


@njit(cache=True)
def _dot(x: Vec, y: Vec) -> float:
    return x[0] * y[0] + x[1] * y[1] + x[2] * y[2]


@njit(cache=True)
def _mu_mu(x: Vec, y: Vec, W: FloatArray, k: int) -> None:
    """``W[k, 3:6] += `` the coefficients of ``mu(x) mu(y)`` on ``(u^2, uv, v^2)``."""
    W[k, 3] += x[1] * y[1]
    W[k, 4] += -(x[1] * y[0] + x[0] * y[1])
    W[k, 5] += x[0] * y[0]


@njit(cache=True)
def _column(M: FloatArray, j: int) -> Vec:
    return (M[0, j], M[1, j], M[2, j])


@njit(cache=True)
def coefficients(f_a: FloatArray, f_b: FloatArray, left: FloatArray, right: FloatArray,
                 W: FloatArray) -> None:
    """One correspondence's ``W`` ``(9, 6)``, written into ``W``: the terms of
    :func:`~apcc_graph.frontend.spatial_basis.spatial_coefficients`, divided by their largest
    magnitude."""
    fa = (f_a[0], f_a[1], f_a[2])
    a = (_dot(_column(left, 0), fa), _dot(_column(left, 1), fa), _dot(_column(left, 2), fa))
    d = (_dot(_column(left, 0), _column(left, 3)), _dot(_column(left, 1), _column(left, 3)),
         _dot(_column(left, 2), _column(left, 3)))
    w = (right[0, 0] * f_b[0] + right[0, 1] * f_b[1] + right[0, 2] * f_b[2],
         right[1, 0] * f_b[0] + right[1, 1] * f_b[1] + right[1, 2] * f_b[2],
         right[2, 0] * f_b[0] + right[2, 1] * f_b[1] + right[2, 2] * f_b[2])
    s0 = _cross(_column(right, 3), w)
    a2 = _cross(a, d)
    a3 = (a[1], -a[0], 0.0)
    az = a[2]
    wa = _cross(w, a)
    W[:] = 0.0
    W[0, 0] = _dot(a, s0) + _dot(a2, w)
    W[1, 0] = _dot(a3, w)
    z1, z2 = _cross(s0, a), _cross(w, a2)
    W[2, 1], W[2, 2] = z1[1] + z2[1], -(z1[0] + z2[0])
    z1 = _cross(w, a3)
    W[3, 1], W[3, 2] = z1[1], -z1[0]
    W[4, 1], W[4, 2] = wa[0] - az * w[1], wa[1] + az * w[0]
    W[5, 1], W[5, 2] = az * w[1], -az * w[0]
    _mu_mu(a, s0, W, 6)
    _mu_mu(a2, w, W, 6)
    _mu_mu(a3, w, W, 7)
    W[8, 3], W[8, 4], W[8, 5] = a[1] * w[0], a[1] * w[1] - a[0] * w[0], -a[0] * w[1]
    scale = 0.0
    for k in range(9):
        for j in range(6):
            scale = max(scale, abs(W[k, j]))
    if scale > 0.0:
        W /= scale


Quintic = tuple[float, float, float, float, float]


@njit(cache=True)
def _quartics(W: FloatArray, Ft: FloatArray, g: int, t: float) -> tuple[float, Quintic, Quintic]:
    """One correspondence's g on the circle of radius ``t = grid[g]``: its constant harmonic A0
    and its quartics in ``tan(psi / 2)`` with (``q``) and without (``p``) that harmonic,
    ascending (:func:`~apcc_graph.frontend.eliminant.circle_quartics`); ``Ft`` is ``(9, G)``."""
    t2 = t * t
    c0 = Ft[0, g] * W[0, 0] + Ft[1, g] * W[1, 0]
    c1 = (Ft[2, g] * W[2, 1] + Ft[3, g] * W[3, 1] + Ft[4, g] * W[4, 1] + Ft[5, g] * W[5, 1]) * t
    c2 = (Ft[2, g] * W[2, 2] + Ft[3, g] * W[3, 2] + Ft[4, g] * W[4, 2] + Ft[5, g] * W[5, 2]) * t
    c3 = (Ft[6, g] * W[6, 3] + Ft[7, g] * W[7, 3] + Ft[8, g] * W[8, 3]) * t2
    c4 = (Ft[6, g] * W[6, 4] + Ft[7, g] * W[7, 4] + Ft[8, g] * W[8, 4]) * t2
    c5 = (Ft[6, g] * W[6, 5] + Ft[7, g] * W[7, 5] + Ft[8, g] * W[8, 5]) * t2
    # Harmonics A0 = c0 + (c3 + c5) / 2, (A1, B1) = (c1, c2), (A2, B2) = (c3 - c5, c4) / 2,
    # times (1 + tau^2)^2 (the map of eliminant._quartic_maps, written out).
    q = (c0 + c1 + c3, 2.0 * c2 + 2.0 * c4, 2.0 * c0 - 2.0 * c3 + 4.0 * c5,
         2.0 * c2 - 2.0 * c4, c0 - c1 + c3)
    p = (c1 + 0.5 * c3 - 0.5 * c5, q[1], 3.0 * c5 - 3.0 * c3, q[3], -c1 + 0.5 * c3 - 0.5 * c5)
    return c0 + 0.5 * c3 + 0.5 * c5, q, p


@njit(cache=True, error_model="numpy")
def pair_on_grid(W1: FloatArray, W2: FloatArray, Ft: FloatArray, grid: FloatArray,
                 D: FloatArray, B: FloatArray) -> None:
    """A pair's Bezout matrices of ``H / theta`` and ``G`` on the grid, their ten distinct
    entries ``(B00, B01, B02, B03, B11, B12, B13, B22, B23, B33)`` into ``B`` ``(10, G)``, and
    their determinants (not deflated) into ``D`` ``(G,)``.

    ``(P(x) Q(y) - P(y) Q(x)) / (x - y)``: the monomial pair ``x^m y^n - x^n y^m`` (m > n)
    gives ``x^(n+l) y^(m-1-l)``, ``l = 0 .. m-n-1``, so with ``d_mn = P_m Q_n - P_n Q_m`` the
    matrix is symmetric and ``B11 = d21 + d30``, ``B12 = d31 + d40``, ``B22 = d32 + d41``, the
    other entries one ``d`` each. D is the sum of products of complementary 2x2 minors of rows
    (0, 1) and (2, 3). One branch-free loop over the nodes, which the compiler vectorises.
    """
    for g in range(grid.shape[0]):
        t = grid[g]
        a1, q1, p1 = _quartics(W1, Ft, g, t)
        a2, q2, p2 = _quartics(W2, Ft, g, t)
        P0, P1 = (a2 * p1[0] - a1 * p2[0]) / t, (a2 * p1[1] - a1 * p2[1]) / t
        P2, P3 = (a2 * p1[2] - a1 * p2[2]) / t, (a2 * p1[3] - a1 * p2[3]) / t
        P4 = (a2 * p1[4] - a1 * p2[4]) / t
        Q0, Q1, Q2 = a1 * q1[0] + a2 * q2[0], a1 * q1[1] + a2 * q2[1], a1 * q1[2] + a2 * q2[2]
        Q3, Q4 = a1 * q1[3] + a2 * q2[3], a1 * q1[4] + a2 * q2[4]
        b00, b01 = P1 * Q0 - P0 * Q1, P2 * Q0 - P0 * Q2
        b02, b03 = P3 * Q0 - P0 * Q3, P4 * Q0 - P0 * Q4
        b11 = (P2 * Q1 - P1 * Q2) + b02
        b12 = (P3 * Q1 - P1 * Q3) + b03
        b13 = P4 * Q1 - P1 * Q4
        b22, b23, b33 = (P3 * Q2 - P2 * Q3) + b13, P4 * Q2 - P2 * Q4, P4 * Q3 - P3 * Q4
        B[0, g], B[1, g], B[2, g], B[3, g], B[4, g] = b00, b01, b02, b03, b11
        B[5, g], B[6, g], B[7, g], B[8, g], B[9, g] = b12, b13, b22, b23, b33
        # Rows 0, 1: (b00 b01 b02 b03), (b01 b11 b12 b13); rows 2, 3: (b02 b12 b22 b23),
        # (b03 b13 b23 b33).
        s01, s02, s03 = b00 * b11 - b01 * b01, b00 * b12 - b02 * b01, b00 * b13 - b03 * b01
        s12, s13, s23 = b01 * b12 - b02 * b11, b01 * b13 - b03 * b11, b02 * b13 - b03 * b12
        c01, c02, c03 = b02 * b13 - b12 * b03, b02 * b23 - b22 * b03, b02 * b33 - b23 * b03
        c12, c13, c23 = b12 * b23 - b22 * b13, b12 * b33 - b23 * b13, b22 * b33 - b23 * b23
        D[g] = s01 * c23 - s02 * c13 + s03 * c12 + s12 * c03 - s13 * c02 + s23 * c01


@njit(cache=True)
def bezout_matrix(B: FloatArray) -> FloatArray:
    """The symmetric 4x4 matrix of :func:`pair_on_grid`'s ten entries ``(10,)``."""
    out = np.empty((4, 4))
    k = 0
    for i in range(4):
        for j in range(i, 4):
            out[i, j] = out[j, i] = B[k]
            k += 1
    return out


@njit(cache=True)
def common_psi(B: FloatArray) -> float:
    """The shared psi (radians, ``(-pi, pi]``) of a nearly singular Bezout matrix: two steps of
    inverse iteration from a fixed start (shifted by ``1e-13`` of its largest entry), as
    :func:`~apcc_graph.frontend.eliminant.common_psi`."""
    scale = np.max(np.abs(B))
    LU = B.copy()
    for k in range(4):
        LU[k, k] += 1e-13 * (scale if scale > 0.0 else 1.0)
    piv = np.empty(4, dtype=np.int64)
    _lu(LU, piv)
    x = np.array(_START)
    for _ in range(2):
        _lu_solve(LU, piv, x)
        x /= np.max(np.abs(x))
    psi = 2.0 * math.atan2(x[1] + x[3], x[0] + x[2])
    if psi > math.pi:
        return psi - 2.0 * math.pi
    return psi + 2.0 * math.pi if psi <= -math.pi else psi
