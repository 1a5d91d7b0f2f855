"""Triangulation compiled: each track's point by Levenberg-Marquardt in inverse depth.

The numpy reference is :func:`apcc_graph.factors.triangulation.triangulate_rows`
(docs/estimation.md, "Eliminating each track's point"); these kernels run the same steps in
the same order, track by track instead of vectorised over tracks, and return the same points to
rounding, except where a converged step's cost ties the previous one to rounding (one engine may
then take it and the other not: the points differ by less than the stopping tolerance;
``tests/test_reduced_jit.py``). Layout as :mod:`apcc_graph.factors.reduced_jit`; every kernel
lives in this file (numba's cache checks only a kernel's own file).
"""

from __future__ import annotations

import math

import numpy as np

from apcc_graph.model.arrays import FloatArray, IntArray
from apcc_graph.model.kernel_cache import njit

MIN_DEPTH = 0.02  # as apcc_graph.factors.track_points.MIN_DEPTH (a test keeps them equal)
MIN_INVERSE_DEPTH = 1e-3  # as apcc_graph.factors.triangulation.MIN_INVERSE_DEPTH
DEFAULT_DEPTH = 3.0  # as apcc_graph.factors.triangulation.DEFAULT_DEPTH


@njit(cache=True)
def _solve_spd(A: FloatArray, b: FloatArray, n: int) -> FloatArray:
    """``A[:n, :n]^-1 b[:n]`` for a symmetric positive definite ``A`` (Cholesky)."""
    L = np.zeros((n, n))
    for i in range(n):
        for j in range(i + 1):
            s = A[i, j]
            for k in range(j):
                s -= L[i, k] * L[j, k]
            L[i, j] = math.sqrt(max(s, 1e-300)) if i == j else s / L[j, j]
    y = np.empty(n)
    for i in range(n):
        s = b[i]
        for k in range(i):
            s -= L[i, k] * y[k]
        y[i] = s / L[i, i]
    x = np.empty(n)
    for i in range(n - 1, -1, -1):
        s = y[i]
        for k in range(i + 1, n):
            s -= L[k, i] * x[k]
        x[i] = s / L[i, i]
    return x


@njit(cache=True)
def initial_points(xy: FloatArray, starts: IntArray, Rb: FloatArray, ob: FloatArray,
                   weights: FloatArray) -> FloatArray:
    """``(3, T)`` each track's weighted ray midpoint pulled weakly toward DEFAULT_DEPTH along
    its mean ray (reference: ``triangulation._initial_points``)."""
    T = starts.shape[0] - 1
    out = np.empty((3, T))
    A, b, mean, centre, ray = np.empty((3, 3)), np.empty(3), np.empty(3), np.empty(3), np.empty(3)
    for t in range(T):
        A[:] = 0.0
        b[:] = 0.0
        mean[:] = 0.0
        centre[:] = 0.0
        wsum = 0.0
        for k in range(starts[t], starts[t + 1]):
            for i in range(3):
                ray[i] = Rb[i, 0, k] * xy[0, k] + Rb[i, 1, k] * xy[1, k] + Rb[i, 2, k]
            norm = math.sqrt(ray[0] ** 2 + ray[1] ** 2 + ray[2] ** 2)
            ray /= norm
            w = weights[k] if weights[k] > 0.0 else 1e-3
            for i in range(3):
                Po = 0.0
                for j in range(3):
                    P = (1.0 if i == j else 0.0) - ray[i] * ray[j]
                    A[i, j] += w * P
                    Po += P * ob[j, k]
                b[i] += w * Po
                mean[i] += w * ray[i]
                centre[i] += w * ob[i, k]
            wsum += w
        mnorm = max(math.sqrt(mean[0] ** 2 + mean[1] ** 2 + mean[2] ** 2), 1e-12)
        lam = 1e-4 * (A[0, 0] + A[1, 1] + A[2, 2])
        for i in range(3):
            b[i] += lam * (centre[i] / wsum + DEFAULT_DEPTH * mean[i] / mnorm)
            A[i, i] += lam
        out[:, t] = _solve_spd(A, b, 3)
    return out


@njit(cache=True)
def _track_cost(t: int, prm: FloatArray, xy: FloatArray, W: FloatArray, starts: IntArray,
                Rb: FloatArray, ob: FloatArray, sw: FloatArray, live: FloatArray,
                p: FloatArray, N: FloatArray, g: FloatArray, jacobian: bool) -> float:
    """Track t's weighted cost at inverse-depth parameters ``prm`` (3,), its point into ``p``
    and, with ``jacobian``, ``J^T J`` and ``J^T r`` into ``N``, ``g`` (reference:
    ``triangulation._InverseDepth.evaluate``)."""
    a = starts[t]
    rho = prm[2]
    Rray = np.empty(3)
    for i in range(3):
        Rray[i] = Rb[i, 0, a] * prm[0] + Rb[i, 1, a] * prm[1] + Rb[i, 2, a]
        p[i] = ob[i, a] + Rray[i] / rho
    if jacobian:
        N[:] = 0.0
        g[:] = 0.0
    cost = 0.0
    q, r, WA, Jp, J = np.empty(3), np.empty(2), np.empty((2, 3)), np.empty((2, 3)), np.empty((2, 3))
    for k in range(a, starts[t + 1]):
        for i in range(3):
            q[i] = ((p[0] - ob[0, k]) * Rb[0, i, k] + (p[1] - ob[1, k]) * Rb[1, i, k]
                    + (p[2] - ob[2, k]) * Rb[2, i, k])
        iz = 1.0 / max(q[2], MIN_DEPTH)
        m0, m1 = q[0] * iz, q[1] * iz
        e0, e1 = m0 - xy[0, k], m1 - xy[1, k]
        for i in range(2):
            r[i] = (W[i, 0, k] * e0 + W[i, 1, k] * e1) * sw[k]
        cost += r[0] ** 2 + r[1] ** 2
        if not q[2] > MIN_DEPTH and live[k] > 0.0:
            cost += 1e12
        if not jacobian:
            continue
        for i in range(2):
            WA[i, 0] = W[i, 0, k] * iz * sw[k]
            WA[i, 1] = W[i, 1, k] * iz * sw[k]
            WA[i, 2] = -(W[i, 0, k] * m0 + W[i, 1, k] * m1) * iz * sw[k]
            for j in range(3):
                Jp[i, j] = WA[i, 0] * Rb[j, 0, k] + WA[i, 1] * Rb[j, 1, k] + WA[i, 2] * Rb[j, 2, k]
            # J = Jp dp, dp = [Ra[:, 0] / rho, Ra[:, 1] / rho, -Rray / rho^2]
            for c in range(2):
                J[i, c] = (Jp[i, 0] * Rb[0, c, a] + Jp[i, 1] * Rb[1, c, a]
                           + Jp[i, 2] * Rb[2, c, a]) / rho
            J[i, 2] = -(Jp[i, 0] * Rray[0] + Jp[i, 1] * Rray[1] + Jp[i, 2] * Rray[2]) / rho**2
        for c in range(3):
            g[c] += J[0, c] * r[0] + J[1, c] * r[1]
            for d in range(3):
                N[c, d] += J[0, c] * J[0, d] + J[1, c] * J[1, d]
    return cost


@njit(cache=True)
def _bounded_step(prm: FloatArray, N: FloatArray, g: FloatArray, lam: float) -> FloatArray:
    """The damped Gauss-Newton step of one track, inverse depth kept above
    MIN_INVERSE_DEPTH (reference: ``triangulation._bounded_step``)."""
    A = N.copy()
    for i in range(3):
        A[i, i] += lam * max(N[i, i], 1e-12)
    step = -_solve_spd(A, g, 3)
    if prm[2] + step[2] < MIN_INVERSE_DEPTH:
        d_rho = MIN_INVERSE_DEPTH - prm[2]
        rhs = np.empty(2)
        for i in range(2):
            rhs[i] = g[i] + A[i, 2] * d_rho
        s2 = _solve_spd(A, rhs, 2)
        step[0], step[1], step[2] = -s2[0], -s2[1], d_rho
    return step


@njit(cache=True)
def triangulate(xy: FloatArray, W: FloatArray, starts: IntArray, Rb: FloatArray,
                ob: FloatArray, weights: FloatArray, points: FloatArray, iterations: int,
                tolerance: float) -> FloatArray:
    """``(3, T)`` each track's point from ``points`` ``(3, T)`` by Levenberg-Marquardt in
    inverse depth (reference: ``triangulation.triangulate_rows``: the same iterations,
    damping and stopping rule, which looks at every track's step)."""
    T = starts.shape[0] - 1
    sw = np.sqrt(weights)
    live = (weights > 0.0) * 1.0
    prm = np.empty((3, T))
    for t in range(T):
        a = starts[t]
        v = np.empty(3)
        for i in range(3):
            v[i] = ((points[0, t] - ob[0, a]) * Rb[0, i, a]
                    + (points[1, t] - ob[1, a]) * Rb[1, i, a]
                    + (points[2, t] - ob[2, a]) * Rb[2, i, a])
        if not v[2] > MIN_DEPTH:
            v[0], v[1], v[2] = xy[0, a] * DEFAULT_DEPTH, xy[1, a] * DEFAULT_DEPTH, DEFAULT_DEPTH
        prm[0, t], prm[1, t], prm[2, t] = v[0] / v[2], v[1] / v[2], 1.0 / v[2]
    pts, cost, lam = np.empty((3, T)), np.empty(T), np.full(T, 1e-3)
    N, g = np.empty((T, 3, 3)), np.empty((T, 3))
    trial_p = np.empty(3)
    for t in range(T):
        cost[t] = _track_cost(t, prm[:, t], xy, W, starts, Rb, ob, sw, live, pts[:, t], N[t],
                              g[t], True)
    for _ in range(iterations):
        largest = 0.0
        for t in range(T):
            step = _bounded_step(prm[:, t], N[t], g[t], lam[t])
            for i in range(3):
                largest = max(largest, abs(step[i]))
            trial = prm[:, t] + step
            new_cost = _track_cost(t, trial, xy, W, starts, Rb, ob, sw, live, trial_p, N[t],
                                   g[t], False)
            if new_cost <= cost[t]:
                prm[:, t] = trial
                pts[:, t] = trial_p
                cost[t] = new_cost
                lam[t] = min(max(lam[t] * 0.3, 1e-9), 1e9)
            else:
                lam[t] = min(max(lam[t] * 10.0, 1e-9), 1e9)
        if largest < tolerance:
            break
        for t in range(T):  # a rejected step leaves that track's system as it was
            _track_cost(t, prm[:, t], xy, W, starts, Rb, ob, sw, live, trial_p, N[t], g[t],
                        True)
    return pts
