"""Eliminating psi between two correspondences: a function of theta alone whose zeros are the
2-point solver's bends.

On the circle ``|b| = theta`` (``u = theta cos psi``, ``v = theta sin psi``) the expansion of
:mod:`~apcc_graph.frontend.spatial_basis`, ``g = c0 + c1 . (u, v) + c2 . (u^2, uv, v^2)``
with ``c = F(theta) W``, is a trigonometric polynomial of degree 2 in psi:

    g = A0 + A1 cos psi + B1 sin psi + A2 cos 2psi + B2 sin 2psi,
    A0 = c0 + theta^2 (c_uu + c_vv) / 2,  (A1, B1) = theta c1,
    (A2, B2) = theta^2 ((c_uu - c_vv) / 2, c_uv / 2).

(psi enters only by conjugating with ``Rz(psi)``, so never beyond the second harmonic.) With
``tau = tan(psi / 2)``, ``(1 + tau^2)^2 g`` is the quartic
``[A0 + A1 + A2, 2 B1 + 4 B2, 2 A0 - 6 A2, 2 B1 - 4 B2, A0 - A1 + A2]`` (ascending powers), and
two correspondences share a psi exactly when the resultant of their quartics vanishes: the
determinant of their 4x4 Bezout matrix, whose kernel is then ``(1, tau, tau^2, tau^3)``, which
gives psi back. A root at ``tau = infinity`` (psi = pi) is a common root too: the
resultant of the formal degree-4 quartics counts it.

Conditioning near straight. The harmonics scale as ``1, theta, theta^2``, so the resultant of
``g1, g2`` vanishes like ``theta^8`` and rounding swamps it below a few degrees. Two exact
changes of pair fix most of that: ``H = (A0_2 g1 - A0_1 g2) / theta`` has no constant term and
``O(1)`` harmonics, ``G = A0_1 g1 + A0_2 g2``; the pair has the same common roots (the change is
a rotation-scaling of determinant ``A0_1^2 + A0_2^2 >= 0``) and a resultant that vanishes like
``theta^4`` only (two of H's roots approach ``tau = +-i`` where ``(1 + tau^2)^2`` is small).
Below :data:`~apcc_graph.frontend.pair_roots.SMALL_BEND` the solver works in the bending vector
directly instead.
"""

from __future__ import annotations

import numpy as np

from apcc_graph.model.arrays import FloatArray


def _bezout_tensor(degree: int = 4) -> FloatArray:
    """``T`` with ``Bez(P, Q) = sum_mn P_m Q_n T[m, n]``, flattened to ``((d+1)^2, d^2)``.

    ``(P(x) Q(y) - P(y) Q(x)) / (x - y) = sum_ij Bez_ij x^i y^j``; the monomial pair
    ``x^m y^n - x^n y^m`` (m > n) divided by ``x - y`` is ``sum_l x^(n+l) y^(m-1-l)``,
    ``l = 0 .. m-n-1``.
    """
    T = np.zeros((degree + 1, degree + 1, degree, degree))
    for m in range(degree + 1):
        for n in range(m):
            for step in range(m - n):
                T[m, n, n + step, m - 1 - step] += 1.0
                T[n, m, n + step, m - 1 - step] -= 1.0
    return T.reshape((degree + 1) ** 2, degree * degree)


_BEZOUT = _bezout_tensor()


def _quartic_maps() -> tuple[FloatArray, FloatArray, FloatArray]:
    """Linear maps from the scaled monomial coefficients ``c * (1, t, t, t^2, t^2, t^2)`` to
    the quartic of g (``(6, 5)``), to that of g without its constant harmonic, and to A0."""
    harmonics = np.zeros((6, 5))  # rows c0, c_u, c_v, c_uu, c_uv, c_vv; cols A0, A1, B1, A2, B2
    harmonics[0, 0] = 1.0
    harmonics[1, 1] = harmonics[2, 2] = 1.0
    harmonics[3, 0] = harmonics[5, 0] = 0.5
    harmonics[3, 3], harmonics[5, 3] = 0.5, -0.5
    harmonics[4, 4] = 0.5
    # (1 + tau^2)^2 g, ascending in tau, from (A0, A1, B1, A2, B2).
    to_tau = np.array([[1.0, 0.0, 2.0, 0.0, 1.0], [1.0, 0.0, 0.0, 0.0, -1.0],
                       [0.0, 2.0, 0.0, 2.0, 0.0], [1.0, 0.0, -6.0, 0.0, 1.0],
                       [0.0, 4.0, 0.0, -4.0, 0.0]])
    varying = harmonics.copy()
    varying[:, 0] = 0.0
    return harmonics @ to_tau, varying @ to_tau, harmonics[:, 0]


_TO_QUARTIC, _TO_VARYING_QUARTIC, _TO_A0 = _quartic_maps()
_POWERS = np.array([0.0, 1.0, 1.0, 2.0, 2.0, 2.0])


def circle_quartics(c: FloatArray, theta: FloatArray) -> tuple[FloatArray, FloatArray]:
    """The quartics of ``H / theta`` and ``G`` (module docstring), each ``(..., 5)``.

    With ``c' = c * (1, t, t, t^2, t^2, t^2)`` the harmonics of each g are linear in ``c'``,
    and so is its quartic: ``Q = A0_1 q_1 + A0_2 q_2`` and, leaving out the constant harmonic
    (whose contribution to H cancels exactly), ``P = (A0_2 p_1 - A0_1 p_2) / theta``.

    Args:
        c: ``(..., 2, 6)`` the two correspondences' monomial coefficients at ``theta``
            (``F(theta) W``).
        theta: ``(...)`` bends, radians, > 0.
    """
    t = theta[..., None, None]
    scaled = (c * t**_POWERS).reshape(-1, 6)
    A0 = (scaled @ _TO_A0).reshape(c.shape[:-1])  # (..., 2)
    q = (scaled @ _TO_QUARTIC).reshape(c.shape[:-1] + (5,))  # (..., 2, 5)
    p = (scaled @ _TO_VARYING_QUARTIC).reshape(q.shape)
    a1, a2 = A0[..., 0, None], A0[..., 1, None]
    P = (a2 * p[..., 0, :] - a1 * p[..., 1, :]) / theta[..., None]
    return P, a1 * q[..., 0, :] + a2 * q[..., 1, :]


def bezout_matrices(c: FloatArray, theta: FloatArray) -> FloatArray:
    """The 4x4 Bezout matrices of the pair at each theta, ``(..., 4, 4)`` (symmetric)."""
    P, Q = circle_quartics(c, theta)
    outer = (P[..., :, None] * Q[..., None, :]).reshape(P.shape[:-1] + (25,))
    return (outer @ _BEZOUT).reshape(P.shape[:-1] + (4, 4))


def eliminant(c: FloatArray, theta: FloatArray) -> tuple[FloatArray, FloatArray]:
    """The resultant ``D(theta)`` ``(...)`` and the Bezout matrices ``(..., 4, 4)``.

    ``D`` vanishes exactly where the two correspondences share a psi on the circle of radius
    theta (and, without a sign change, where ``A0_1 = A0_2 = 0``).
    """
    B = bezout_matrices(c, theta)
    return np.linalg.det(B), B


def common_psi(B: FloatArray) -> FloatArray:
    """The shared psi (radians, in ``(-pi, pi]``) from nearly singular Bezout matrices ``(R, 4,
    4)``.

    Two steps of inverse iteration (a fixed start, a tiny shift so that an exactly singular
    matrix still solves) give the kernel ``~ (1, tau, tau^2, tau^3)``; ``(v0 + v2, v1 + v3) ~
    (1 + tau^2) (1, tau)`` has the direction ``psi / 2`` whatever the size of tau, so
    ``psi = 2 atan2(v1 + v3, v0 + v2)``.
    """
    if len(B) == 0:
        return np.zeros(0)
    scale = np.max(np.abs(B), axis=(1, 2))
    shifted = B + (1e-13 * np.where(scale > 0.0, scale, 1.0))[:, None, None] * np.eye(4)
    x = np.broadcast_to(np.array([0.6, 0.43, -0.51, 0.37]), (len(B), 4))[..., None]
    for _ in range(2):
        x = np.linalg.solve(shifted, x)
        x = x / np.max(np.abs(x), axis=(1, 2), keepdims=True)
    v = x[..., 0]
    psi = 2.0 * np.arctan2(v[:, 1] + v[:, 3], v[:, 0] + v[:, 2])
    return np.where(psi > np.pi, psi - 2.0 * np.pi, np.where(psi <= -np.pi, psi + 2.0 * np.pi,
                                                             psi))


def circle_residuals(c: FloatArray, theta: FloatArray, psi: FloatArray) -> FloatArray:
    """``|g1| + |g2|`` at ``b = theta (cos psi, sin psi)`` from the monomial coefficients
    ``c`` ``(R, 2, 6)``; ``psi`` is ``(R, K)``, the result ``(R, K)``."""
    u = (theta[:, None] * np.cos(psi))[:, None]
    v = (theta[:, None] * np.sin(psi))[:, None]
    c = c[:, :, None, :]
    g = (c[..., 0] + c[..., 1] * u + c[..., 2] * v + c[..., 3] * u * u + c[..., 4] * u * v
         + c[..., 5] * v * v)
    return np.abs(g).sum(axis=1)


def psi_from_roots(c: FloatArray, theta: FloatArray) -> FloatArray:
    """The shared psi (radians, ``(-pi, pi]``) at exact roots ``theta`` ``(R,)``.

    The real roots of ``H``'s quartic (companion eigenvalues; of the reversed quartic in
    ``1 / tau`` when its leading coefficient is the smaller end, so that psi near pi is
    accurate) are the candidates, and the one where both equations are smallest wins. Unlike
    :func:`common_psi` this tells apart two roots at almost the same theta.
    """
    if len(theta) == 0:
        return np.zeros(0)
    P, _ = circle_quartics(c, theta)
    reverse = np.abs(P[:, 4]) < np.abs(P[:, 0])
    P = np.where(reverse[:, None], P[:, ::-1], P)
    lead = np.where(P[:, 4] != 0.0, P[:, 4], 1e-300)
    companion = np.zeros((len(P), 4, 4))
    companion[:, 1:, :3] = np.eye(3)
    companion[:, :, 3] = -P[:, :4] / lead[:, None]
    roots = np.linalg.eigvals(companion).real
    half = np.where(reverse[:, None], np.arctan2(1.0, roots), np.arctan(roots))
    psi = 2.0 * half
    best = np.argmin(circle_residuals(c, theta, psi), axis=1)
    psi = psi[np.arange(len(psi)), best]
    return np.where(psi > np.pi, psi - 2.0 * np.pi, psi)
