"""Compiled kernels of the 2-point RANSAC: the bend, the relative pose, MSAC scores and the
robust Gauss-Newton refinement, on scalars and plain arrays.

The same mathematics as the numpy reference (docs/estimation.md, "Two correspondences: the
2-point solver of a spatial segment"): :func:`~apcc_graph.frontend.spatial_basis.bend_transform`
for ``base_T_tip`` of a bending vector and its derivatives,
:func:`~apcc_graph.frontend.spatial_basis.bending_sampson` for the Sampson errors and
:func:`~apcc_graph.frontend.spatial_ransac.refine_bending` for the refinement. Written as loops
over correspondences for numba (``@njit(cache=True)``: compiled on first use, then loaded from
the cache), so that a RANSAC call costs arithmetic, not interpreter overhead; the tests hold
every kernel to its numpy counterpart.

Conventions: radians; ``seg`` is the segment as :func:`segment_parameters` packs it; ``left``
and ``right`` are the fixed parts of ``camA_T_camB = left @ T(b) @ right``
(:class:`~apcc_graph.frontend.geometry.SegmentTwoView`); bearings are ``(3, N)`` columns
(``f_a.T``), so that the loops over correspondences read contiguous memory and vectorise.
"""

from __future__ import annotations

import math

import numpy as np

from apcc_graph.frontend import spatial_basis
from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.kernel_cache import njit
from apcc_graph.model.segment import Segment

DEPENDS = "3c0ef2668d98d0fe"
"""Digest of the code this module's cached kernels compile in from other files (the three series
of :mod:`~apcc_graph.frontend.spatial_basis` wrapped below; ``tests/test_spatial_ransac_fast.py``).
numba's cache checks the text of each kernel's own file only, so a kernel compiled with
stale callees could load from it; a test keeps this line current, which changes this
file whenever those sources change."""

_sinc = njit(cache=True)(spatial_basis._sinc)
_odd_ratio = njit(cache=True)(spatial_basis._odd_ratio)
_even_ratio = njit(cache=True)(spatial_basis._even_ratio)


def segment_parameters(segment: Segment) -> FloatArray:
    """``[l1, l2, c, 1 - delta_max / theta_max, theta_max]`` (metres, radians): what the
    kernels read of a segment."""
    return np.array([segment.l1, segment.l2, segment.link_ratio,
                     1.0 - segment.deviation_rate, segment.theta_max])


@njit(cache=True)
def bend_terms(theta: float, seg: FloatArray) -> tuple[float, float, float, float, float]:
    """``(cos beta, sigma, kappa, rho, pz)`` of :mod:`~apcc_graph.frontend.spatial_basis` at a
    bend ``theta >= 0``."""
    y = 0.5 * theta
    s, h = math.sin(y), math.cos(y)
    chord = seg[0] * math.sqrt(1.0 - (seg[2] * s) ** 2) + seg[1] * h
    rate = seg[3]
    x = rate * theta
    kappa = 0.5 * rate * rate * _sinc(0.5 * x) ** 2
    return math.cos(x), rate * _sinc(x), kappa, 0.5 * chord * _sinc(y), chord * h


@njit(cache=True)
def _fill_bend(T: FloatArray, cb: float, sigma: float, kappa: float, u: float, v: float,
               p0: float, p1: float, p2: float, one: float) -> None:
    """``T = [[cb I + sigma [m]x + kappa m m^T, p], [0, one]]`` with ``m = (-v, u, 0)``."""
    T[0, 0], T[0, 1], T[0, 2], T[0, 3] = cb + kappa * v * v, -kappa * u * v, sigma * u, p0
    T[1, 0], T[1, 1], T[1, 2], T[1, 3] = -kappa * u * v, cb + kappa * u * u, sigma * v, p1
    T[2, 0], T[2, 1], T[2, 2], T[2, 3] = -sigma * u, -sigma * v, cb, p2
    T[3, 0], T[3, 1], T[3, 2], T[3, 3] = 0.0, 0.0, 0.0, one


@njit(cache=True)
def bend_matrices(u: float, v: float, seg: FloatArray, derivative: bool) -> FloatArray:
    """``base_T_tip`` of a bending vector and, with ``derivative``, ``dT/du`` and ``dT/dv``:
    ``(3, 4, 4)`` (else ``(1, 4, 4)``), exact through ``b = 0``."""
    theta = math.hypot(u, v)
    cb, sigma, kappa, rho, pz = bend_terms(theta, seg)
    T = np.empty((3 if derivative else 1, 4, 4))
    _fill_bend(T[0], cb, sigma, kappa, u, v, rho * u, rho * v, pz, 1.0)
    if not derivative:
        return T
    y = 0.5 * theta
    sy, h = _sinc(y), math.cos(y)
    l2, c, rate = seg[1], seg[2], seg[3]
    root = math.sqrt(1.0 - (c * math.sin(y)) ** 2)
    chord = seg[0] * root + l2 * h
    dchord = -0.25 * sy * l2 * (c * h / root + 1.0)  # chord' / theta
    d_rho = 0.5 * dchord * sy - 0.125 * chord * _odd_ratio(y)
    d_pz = dchord * h - 0.25 * chord * sy
    x = rate * theta
    d_cb, d_sigma, d_kappa = -rate * sigma, -rate**3 * _odd_ratio(x), rate**4 * _even_ratio(x)
    _fill_bend(T[1], d_cb * u, d_sigma * u, d_kappa * u, u, v, d_rho * u * u + rho,
               d_rho * u * v, d_pz * u, 0.0)
    _fill_bend(T[2], d_cb * v, d_sigma * v, d_kappa * v, u, v, d_rho * u * v,
               d_rho * v * v + rho, d_pz * v, 0.0)
    # The derivative of m = (-v, u, 0) itself, in [m]x and m m^T.
    T[1, 0, 2] += sigma
    T[1, 2, 0] -= sigma
    T[1, 1, 1] += 2.0 * kappa * u
    T[1, 0, 1] -= kappa * v
    T[1, 1, 0] -= kappa * v
    T[2, 1, 2] += sigma
    T[2, 2, 1] -= sigma
    T[2, 0, 0] += 2.0 * kappa * v
    T[2, 0, 1] -= kappa * u
    T[2, 1, 0] -= kappa * u
    return T


@njit(cache=True)
def _sandwich(left: FloatArray, T: FloatArray, right: FloatArray) -> FloatArray:
    """The top three rows of ``(left @ T) @ right``, ``(3, 4)``."""
    LT = np.zeros((3, 4))
    for i in range(3):
        for j in range(4):
            for m in range(4):
                LT[i, j] += left[i, m] * T[m, j]
    P = np.zeros((3, 4))
    for i in range(3):
        for j in range(4):
            for m in range(4):
                P[i, j] += LT[i, m] * right[m, j]
    return P


@njit(cache=True)
def _add_cross(P: FloatArray, Q: FloatArray, E: FloatArray) -> None:
    """``E += [t]x R`` with ``t = P[:, 3]`` and ``R = Q[:, :3]`` (rows of poses)."""
    for i in range(3):
        i1, i2 = (i + 1) % 3, (i + 2) % 3
        for j in range(3):
            E[i, j] += P[i1, 3] * Q[i2, j] - P[i2, 3] * Q[i1, j]


@njit(cache=True)
def essential_matrices(left: FloatArray, right: FloatArray, T: FloatArray) -> FloatArray:
    """``E = [t]x R`` of ``left @ T[k] @ right`` for ``(K, 4, 4)`` bends, and with ``K = 3``
    (:func:`bend_matrices` with derivatives) ``dE/du``, ``dE/dv`` after it (product rule,
    ``[dt]x R + [t]x dR``): ``(K, 3, 3)``."""
    K = T.shape[0]
    P0 = _sandwich(left, T[0], right)
    E = np.zeros((K, 3, 3))
    _add_cross(P0, P0, E[0])
    for k in range(1, K):
        Pk = _sandwich(left, T[k], right)
        _add_cross(Pk, P0, E[k])
        _add_cross(P0, Pk, E[k])
    return E


CHUNK = 32
"""Correspondences scored between two checks of an MSAC score against its bound."""


Six = tuple[float, float, float, float, float, float]


@njit(cache=True)
def _products(E: FloatArray, a0: float, a1: float, a2: float, b0: float, b1: float,
              b2: float) -> Six:
    """``E f_b`` and ``E^T f_a`` of one correspondence (six numbers)."""
    return (E[0, 0] * b0 + E[0, 1] * b1 + E[0, 2] * b2,
            E[1, 0] * b0 + E[1, 1] * b1 + E[1, 2] * b2,
            E[2, 0] * b0 + E[2, 1] * b1 + E[2, 2] * b2,
            E[0, 0] * a0 + E[1, 0] * a1 + E[2, 0] * a2,
            E[0, 1] * a0 + E[1, 1] * a1 + E[2, 1] * a2,
            E[0, 2] * a0 + E[1, 2] * a1 + E[2, 2] * a2)


@njit(cache=True)
def _terms(E: FloatArray, fa: FloatArray, fb: FloatArray, i: int) -> tuple[float, float]:
    """``(num, den^2)`` of column i's Sampson error ``e = num / den``: ``num = f_a . E f_b``,
    ``den^2 = |E f_b|^2 + |E^T f_a|^2 - 2 num^2`` (not floored)."""
    a0, a1, a2 = fa[0, i], fa[1, i], fa[2, i]
    x0, x1, x2, y0, y1, y2 = _products(E, a0, a1, a2, fb[0, i], fb[1, i], fb[2, i])
    num = a0 * x0 + a1 * x1 + a2 * x2
    return num, x0 * x0 + x1 * x1 + x2 * x2 + y0 * y0 + y1 * y1 + y2 * y2 - 2.0 * num * num


@njit(cache=True, error_model="numpy")
def _msac_terms(E: FloatArray, fa: FloatArray, fb: FloatArray, start: int, stop: int,
                thr2: float, out: FloatArray) -> None:
    """``out[:stop - start] = min(e^2, thr2)`` of the columns ``start:stop`` (0 where ``E f``
    vanishes): one branch-free loop, which the compiler vectorises."""
    for i in range(start, stop):
        num, den2 = _terms(E, fa, fb, i)
        sq = num * num
        ratio = sq / den2 if den2 > 0.0 else 0.0
        out[i - start] = ratio if ratio < thr2 else thr2


@njit(cache=True)
def msac_score(E: FloatArray, fa: FloatArray, fb: FloatArray, thr2: float, bound: float,
               scratch: FloatArray) -> float:
    """MSAC score ``sum min(e^2, thr2)`` of one essential matrix, abandoned (returning the
    partial sum) once it exceeds ``bound`` at a check, every :data:`CHUNK` correspondences:
    such a hypothesis cannot win. ``scratch`` holds :data:`CHUNK` numbers."""
    total = 0.0
    n = fa.shape[1]
    for start in range(0, n, CHUNK):
        stop = min(start + CHUNK, n)
        _msac_terms(E, fa, fb, start, stop, thr2, scratch)
        for k in range(stop - start):
            total += scratch[k]
        if total > bound:
            return total
    return total


@njit(cache=True, error_model="numpy")
def sampson_errors(E: FloatArray, fa: FloatArray, fb: FloatArray) -> FloatArray:
    """Sampson errors ``(N,)`` (radians) of one essential matrix; 0 where ``E f`` vanishes
    (:func:`~apcc_graph.frontend.geometry.sampson_terms`)."""
    out = np.empty(fa.shape[1])
    for i in range(fa.shape[1]):
        num, den2 = _terms(E, fa, fb, i)
        den = math.sqrt(max(den2, 0.0))
        out[i] = num / den if den > 1e-300 else 0.0
    return out


@njit(cache=True)
def bend_errors(left: FloatArray, right: FloatArray, seg: FloatArray, u: float, v: float,
                fa: FloatArray, fb: FloatArray) -> FloatArray:
    """Sampson errors ``(N,)`` (radians) at one bending vector."""
    return sampson_errors(essential_matrices(left, right, bend_matrices(u, v, seg, False))[0],
                          fa, fb)


@njit(cache=True, error_model="numpy")
def _error_gradients(E: FloatArray, fa: FloatArray, fb: FloatArray
                     ) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Sampson errors ``(N,)`` and their derivatives in u and v from ``E, dE/du, dE/dv``
    ``(3, 3, 3)`` (:func:`~apcc_graph.frontend.geometry.sampson_terms`' differential: ``de =
    a dn - b ds / 2``, ``ds / 2 = E f_b . dE f_b + E^T f_a . dE^T f_a``)."""
    n = fa.shape[1]
    e, du, dv = np.empty(n), np.empty(n), np.empty(n)
    for i in range(n):
        a0, a1, a2, b0, b1, b2 = fa[0, i], fa[1, i], fa[2, i], fb[0, i], fb[1, i], fb[2, i]
        x0, x1, x2, y0, y1, y2 = _products(E[0], a0, a1, a2, b0, b1, b2)
        u0, u1, u2, p0, p1, p2 = _products(E[1], a0, a1, a2, b0, b1, b2)
        v0, v1, v2, q0, q1, q2 = _products(E[2], a0, a1, a2, b0, b1, b2)
        num = a0 * x0 + a1 * x1 + a2 * x2
        den2 = x0 * x0 + x1 * x1 + x2 * x2 + y0 * y0 + y1 * y1 + y2 * y2 - 2.0 * num * num
        den = math.sqrt(max(den2, 0.0))
        inv = 1.0 / den if den > 1e-300 else 0.0
        err = num * inv
        cb = err * inv * inv
        ca = inv + 2.0 * num * cb
        e[i] = err
        du[i] = ca * (a0 * u0 + a1 * u1 + a2 * u2) - cb * (
            x0 * u0 + x1 * u1 + x2 * u2 + y0 * p0 + y1 * p1 + y2 * p2)
        dv[i] = ca * (a0 * v0 + a1 * v1 + a2 * v2) - cb * (
            x0 * v0 + x1 * v1 + x2 * v2 + y0 * q0 + y1 * q1 + y2 * q2)
    return e, du, dv


@njit(cache=True)
def _huber_weight(r: float, threshold: float) -> float:
    """Huber's weight of a residual ``|e| = r``: 1 below ``threshold``, ``threshold / r``
    below three thresholds, 0 beyond."""
    if r <= threshold:
        return 1.0
    return threshold / max(r, 1e-300) if r < 3.0 * threshold else 0.0


@njit(cache=True)
def _normal_equations(E: FloatArray, fa: FloatArray, fb: FloatArray, threshold: float
                      ) -> tuple[float, float, float, float, float]:
    """``(H00, H01, H11, g0, g1)`` of one Huber-weighted Gauss-Newton step from ``E, dE/du,
    dE/dv`` ``(3, 3, 3)``."""
    e, du, dv = _error_gradients(E, fa, fb)
    H00 = H01 = H11 = g0 = g1 = 0.0
    for i in range(e.shape[0]):
        w = _huber_weight(abs(e[i]), threshold)
        H00 += w * du[i] * du[i]
        H01 += w * du[i] * dv[i]
        H11 += w * dv[i] * dv[i]
        g0 += w * du[i] * e[i]
        g1 += w * dv[i] * e[i]
    return H00, H01, H11, g0, g1


@njit(cache=True)
def refine(left: FloatArray, right: FloatArray, seg: FloatArray, fa: FloatArray,
           fb: FloatArray, u: float, v: float, threshold: float, iterations: int
           ) -> tuple[float, float, FloatArray]:
    """Robust Gauss-Newton in the bending vector from ``(u, v)``: the refined ``(u, v)`` and
    the Sampson errors ``(N,)`` there (the kernel of
    :func:`~apcc_graph.frontend.spatial_ransac.refine_bending`)."""
    lim = seg[4]
    for _ in range(iterations):
        E = essential_matrices(left, right, bend_matrices(u, v, seg, True))
        H00, H01, H11, g0, g1 = _normal_equations(E, fa, fb, threshold)
        det = H00 * H11 - H01 * H01
        if not det > 0.0:
            break
        s0, s1 = (H11 * g0 - H01 * g1) / det, (H00 * g1 - H01 * g0) / det
        u, v = u - s0, v - s1
        norm = math.hypot(u, v)
        if norm > lim:
            u, v = u * (lim / norm), v * (lim / norm)
        if math.hypot(s0, s1) < 1e-10:  # radians: far below any measurable change
            break
    return u, v, bend_errors(left, right, seg, u, v, fa, fb)
