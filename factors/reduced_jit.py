"""The projection factor's hot loops compiled: the reduced system, and the system of one frame
from known points.

The numpy reference is :mod:`apcc_graph.factors.reduced_system` (docs/estimation.md,
"Eliminating each track's point"); these kernels run the same steps in the same order, track
by track instead of vectorised over tracks, so both return the same systems to rounding
(``tests/test_reduced_jit.py``); the triangulation's kernels are
:mod:`apcc_graph.factors.triangulation_jit`. They exist because a projection factor's chunk
holds tens of tracks over tens of frames: numpy's per-call overhead, not arithmetic, dominated
its cost.

Layout as the reference: per-row arrays keep the row index last (``Rb`` ``(3, 3, N)``, ``ob``
``(3, N)``, ``xy`` ``(2, N)``, ``W`` ``(2, 2, N)``), points ``(3, T)``; every kernel lives in
this file (numba's cache checks only a kernel's own file).
"""

from __future__ import annotations

import math

import numpy as np

from apcc_graph.model.arrays import FloatArray, IntArray
from apcc_graph.model.kernel_cache import njit

MIN_DEPTH = 0.02  # as apcc_graph.factors.track_points.MIN_DEPTH (a test keeps them equal)


@njit(cache=True)
def _row_jacobians(k: int, p: FloatArray, xy: FloatArray, W: FloatArray, Rb: FloatArray,
                   ob: FloatArray, dP: FloatArray, weight: float, r: FloatArray,
                   Jp: FloatArray, Jt: FloatArray, scratch: FloatArray) -> tuple[float, bool]:
    """Row k at point ``p``: weighted whitened residual into ``r`` (2,), ``d r / d p`` into
    ``Jp`` (2, 3) and ``d r / d x`` into ``Jt`` (2, n) for pose derivatives ``dP``
    ``(4, 4, n, N)``; returns the unweighted residual norm and whether the point is in front
    (reference: ``reduced_system.reduced_system`` and ``_pose_jacobian``). ``scratch``
    ``(5, 3)``: work space."""
    d, q, dq, WA = scratch[0], scratch[1], scratch[2], scratch[3:5]
    for i in range(3):
        d[i] = p[i] - ob[i, k]
    for i in range(3):
        q[i] = d[0] * Rb[0, i, k] + d[1] * Rb[1, i, k] + d[2] * Rb[2, i, k]
    valid = q[2] > MIN_DEPTH
    iz = 1.0 / max(q[2], MIN_DEPTH)
    m0, m1 = q[0] * iz, q[1] * iz
    e0, e1 = m0 - xy[0, k], m1 - xy[1, k]
    r0 = W[0, 0, k] * e0 + W[0, 1, k] * e1
    r1 = W[1, 0, k] * e0 + W[1, 1, k] * e1
    norm = math.sqrt(r0 * r0 + r1 * r1)
    sw = math.sqrt(weight) if valid else 0.0
    r[0], r[1] = r0 * sw, r1 * sw
    for a in range(2):
        WA[a, 0] = W[a, 0, k] * iz * sw
        WA[a, 1] = W[a, 1, k] * iz * sw
        WA[a, 2] = -(W[a, 0, k] * m0 + W[a, 1, k] * m1) * iz * sw
        for j in range(3):
            Jp[a, j] = WA[a, 0] * Rb[j, 0, k] + WA[a, 1] * Rb[j, 1, k] + WA[a, 2] * Rb[j, 2, k]
    for j in range(Jt.shape[1]):
        for i in range(3):
            s = 0.0
            for b in range(3):
                s += dP[b, i, j, k] * d[b] - Rb[b, i, k] * dP[b, 3, j, k]
            dq[i] = s
        for a in range(2):
            Jt[a, j] = WA[a, 0] * dq[0] + WA[a, 1] * dq[1] + WA[a, 2] * dq[2]
    return norm, valid


@njit(cache=True)
def reduced(xy: FloatArray, W: FloatArray, tracks: IntArray, starts: IntArray, lf: IntArray,
            Rb: FloatArray, ob: FloatArray, dP: FloatArray, weights: FloatArray,
            points: FloatArray, n_frames: int, n: int
            ) -> tuple[FloatArray, FloatArray, float, FloatArray]:
    """The reduced Gauss-Newton system ``H`` ``(D, D)``, ``g`` ``(D,)``, the cost and the
    residual norms ``(N,)`` at the points ``(3, T)`` (reference:
    ``reduced_system.reduced_system``). ``dP`` ``(4, 4, n + C, N)``: the first ``n`` columns
    are the row's frame's (``D = n_frames n + C``), the last ``C`` the chunk's shared
    (calibration, mount) columns."""
    n_rows = tracks.shape[0]
    E = dP.shape[2]
    C = E - n
    D0 = n_frames * n
    H, g = np.zeros((D0 + C, D0 + C)), np.zeros(D0 + C)
    norms = np.empty(n_rows)
    cost = 0.0
    r, Jp, Jt = np.empty((2, n_rows)), np.empty((2, 3, n_rows)), np.empty((2, E, n_rows))
    scratch = np.empty((5, 3))
    for k in range(n_rows):
        norm, valid = _row_jacobians(k, points[:, tracks[k]], xy, W, Rb, ob, dP, weights[k],
                                     r[:, k], Jp[:, :, k], Jt[:, :, k], scratch)
        norms[k] = norm if valid else np.inf
        cost += r[0, k] ** 2 + r[1, k] ** 2
        # The row's own normal equations: its frame's columns, then the shared ones.
        for i in range(E):
            row = lf[k] * n + i if i < n else D0 + i - n
            g[row] += Jt[0, i, k] * r[0, k] + Jt[1, i, k] * r[1, k]
            for j in range(E):
                if i >= n and j < n:
                    continue  # the shared-by-frame block: the mirror of frame-by-shared
                col = lf[k] * n + j if j < n else D0 + j - n
                value = Jt[0, i, k] * Jt[0, j, k] + Jt[1, i, k] * Jt[1, j, k]
                H[row, col] += value
                if i < n and j >= n:
                    H[col, row] += value
    _eliminate_points(starts, lf, Jp, Jt, r, n, D0, H, g)
    return H, g, cost, norms


@njit(cache=True)
def _cholesky_inverse(C: FloatArray, L: FloatArray, Linv: FloatArray) -> None:
    """``L`` the Cholesky factor of the 3x3 ``C`` and ``Linv`` its inverse (both lower)."""
    L[:] = 0.0
    for i in range(3):
        for j in range(i + 1):
            s = C[i, j]
            for m in range(j):
                s -= L[i, m] * L[j, m]
            L[i, j] = math.sqrt(max(s, 1e-300)) if i == j else s / L[j, j]
    Linv[:] = 0.0
    for i in range(3):
        Linv[i, i] = 1.0 / L[i, i]
        for j in range(i):
            s = 0.0
            for m in range(j, i):
                s -= L[i, m] * Linv[m, j]
            Linv[i, j] = s / L[i, i]


@njit(cache=True)
def _eliminate_points(starts: IntArray, lf: IntArray, Jp: FloatArray, Jt: FloatArray,
                      r: FloatArray, n: int, D0: int, H: FloatArray, g: FloatArray) -> None:
    """Subtract each track's Schur complement from ``H`` and ``g`` in place (reference:
    ``reduced_system._point_elimination``): with ``C_t = L L^T``, each row's
    ``V_k = B_k L^-T`` and ``y = L^-1 b_t``, ``H -= V V^T`` and ``g -= V y`` over the
    track's rows, its shared columns summed over the track."""
    E = Jt.shape[1]
    S = E - n
    L, Linv, Ct, bt, y, B0 = (np.zeros((3, 3)), np.zeros((3, 3)), np.zeros((3, 3)),
                              np.zeros(3), np.zeros(3), np.zeros(3))
    longest = 0
    for t in range(starts.shape[0] - 1):
        longest = max(longest, starts[t + 1] - starts[t])
    V_all = np.zeros((longest, n, 3))  # per row of a track, its frame columns
    Vs = np.zeros((S, 3))  # the shared columns, summed over the track
    for t in range(starts.shape[0] - 1):
        a, b_end = starts[t], starts[t + 1]
        Ct[:] = 0.0
        bt[:] = 0.0
        for k in range(a, b_end):
            for i in range(3):
                bt[i] += Jp[0, i, k] * r[0, k] + Jp[1, i, k] * r[1, k]
                for j in range(3):
                    Ct[i, j] += Jp[0, i, k] * Jp[0, j, k] + Jp[1, i, k] * Jp[1, j, k]
        reg = 1e-12 * (Ct[0, 0] + Ct[1, 1] + Ct[2, 2]) + 1e-12
        for i in range(3):
            Ct[i, i] += reg
        _cholesky_inverse(Ct, L, Linv)
        for i in range(3):
            y[i] = Linv[i, 0] * bt[0] + Linv[i, 1] * bt[1] + Linv[i, 2] * bt[2]
        n_t = b_end - a
        V = V_all[:n_t]
        Vs[:] = 0.0
        for k in range(a, b_end):
            for i in range(E):
                for j in range(3):
                    B0[j] = Jt[0, i, k] * Jp[0, j, k] + Jt[1, i, k] * Jp[1, j, k]
                for c in range(3):  # (B L^-T)[c] = sum_j B[j] Linv[c, j]
                    v = B0[0] * Linv[c, 0] + B0[1] * Linv[c, 1] + B0[2] * Linv[c, 2]
                    if i < n:
                        V[k - a, i, c] = v
                    else:
                        Vs[i - n, c] += v
        for u in range(n_t):
            ru = lf[a + u] * n
            for i in range(n):
                g[ru + i] -= V[u, i, 0] * y[0] + V[u, i, 1] * y[1] + V[u, i, 2] * y[2]
                for w in range(n_t):
                    rw = lf[a + w] * n
                    for j in range(n):
                        H[ru + i, rw + j] -= (V[u, i, 0] * V[w, j, 0] + V[u, i, 1] * V[w, j, 1]
                                              + V[u, i, 2] * V[w, j, 2])
                for c in range(S):
                    s = V[u, i, 0] * Vs[c, 0] + V[u, i, 1] * Vs[c, 1] + V[u, i, 2] * Vs[c, 2]
                    H[ru + i, D0 + c] -= s
                    H[D0 + c, ru + i] -= s
        for c in range(S):
            g[D0 + c] -= Vs[c, 0] * y[0] + Vs[c, 1] * y[1] + Vs[c, 2] * y[2]
            for e in range(S):
                H[D0 + c, D0 + e] -= Vs[c, 0] * Vs[e, 0] + Vs[c, 1] * Vs[e, 1] + Vs[c, 2] * Vs[e, 2]


@njit(cache=True)
def known_points_system(points: FloatArray, xy: FloatArray, whiten: FloatArray,
                        pose: FloatArray, d_pose: FloatArray, scale: float, threshold: float
                        ) -> tuple[FloatArray, FloatArray, float, FloatArray]:
    """One frame's Gauss-Newton system in its vector from one camera's rows of known points
    (reference: ``apcc_graph.estimation.initial_guess._normal_equations``, row-first arrays).

    Args:
        points: ``(N, 3)`` world points; ``xy`` ``(N, 2)`` their normalised observations;
            ``whiten`` ``(N, 2, 2)``.
        pose: ``(4, 4)`` ``world_T_cam``; ``d_pose`` ``(k, 4, 4)`` its derivatives.
        scale: Cauchy scale of the row weights, or NaN for 0/1 weights at ``threshold``.
        threshold: inlier threshold on the whitened residual norm.

    Returns:
        ``H`` ``(k, k)``, ``g`` ``(k,)``, the weighted cost and each row's inlier flag (1.0:
        in front, norm within ``threshold``).
    """
    k = d_pose.shape[0]
    H, g, inliers = np.zeros((k, k)), np.zeros(k), np.zeros(points.shape[0])
    cost = 0.0
    d, q, dq, r, J = np.empty(3), np.empty(3), np.empty(3), np.empty(2), np.empty((2, k))
    WA = np.empty((2, 3))
    for n in range(points.shape[0]):
        for i in range(3):
            d[i] = points[n, i] - pose[i, 3]
        for i in range(3):
            q[i] = d[0] * pose[0, i] + d[1] * pose[1, i] + d[2] * pose[2, i]
        iz = 1.0 / max(q[2], 1e-3)
        m0, m1 = q[0] * iz, q[1] * iz
        e0, e1 = m0 - xy[n, 0], m1 - xy[n, 1]
        r[0] = whiten[n, 0, 0] * e0 + whiten[n, 0, 1] * e1
        r[1] = whiten[n, 1, 0] * e0 + whiten[n, 1, 1] * e1
        norm = math.sqrt(r[0] ** 2 + r[1] ** 2)
        valid = q[2] > 1e-3
        inliers[n] = 1.0 if (norm <= threshold and valid) else 0.0
        if math.isnan(scale):
            w = inliers[n]
        else:
            w = (1.0 if valid else 0.0) / (1.0 + (norm / scale) ** 2)
        sw = math.sqrt(w)
        for a in range(2):
            WA[a, 0] = whiten[n, a, 0] * iz
            WA[a, 1] = whiten[n, a, 1] * iz
            WA[a, 2] = -(whiten[n, a, 0] * m0 + whiten[n, a, 1] * m1) * iz
        for j in range(k):
            for i in range(3):  # dq/dx_j = dR_j^T d - R^T do_j
                s = 0.0
                for b in range(3):
                    s += d_pose[j, b, i] * d[b] - pose[b, i] * d_pose[j, b, 3]
                dq[i] = s
            for a in range(2):
                J[a, j] = (WA[a, 0] * dq[0] + WA[a, 1] * dq[1] + WA[a, 2] * dq[2]) * sw
        r[0] *= sw
        r[1] *= sw
        cost += r[0] ** 2 + r[1] ** 2
        for i in range(k):
            g[i] += J[0, i] * r[0] + J[1, i] * r[1]
            for j in range(k):
                H[i, j] += J[0, i] * J[0, j] + J[1, i] * J[1, j]
    return H, g, cost, inliers
