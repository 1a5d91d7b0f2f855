"""The epipolar constraint of a spatial segment, exactly, in its bending vector.

Set-up (docs/estimation.md, "Two correspondences: the 2-point solver of a spatial segment").
Frame a's bend ``b_a`` is known; frame b's bending vector ``b = (u, v) = theta (cos psi, sin
psi)`` (:mod:`~apcc_graph.model.bending`) is the unknown. As for the 1-point solver
(:mod:`~apcc_graph.frontend.basis`), write ``camA_T_camB = [Rc | tc] T(b) [Rm | tm]`` with the
fixed parts of :class:`~apcc_graph.frontend.geometry.SegmentTwoView` (built with ``psi =
psi_a``), and ``a = Rc^T f_a``, ``w = Rm f_b``, ``d = Rc^T tc``. Then

    g = f_a . (t x R f_b) = a . R_b (tm x w) + (a x d) . R_b w + (a x p) . R_b w.

In the bending vector the segment's rotation and tip are (with ``m = (-v, u, 0)``, the bending
axis times theta, and ``q = (u, v, 0)``)

    R_b = cos(beta) I + sigma [m]x + kappa m m^T,    p = rho q + pz e_z,
    sigma = sin(beta) / theta,  kappa = (1 - cos beta) / theta^2,  rho = px / theta,

all four even, smooth functions of theta (``beta = theta - delta(theta)``). ``x . R_b y`` is
then ``cos(beta) x.y + sigma mu(y x x) + kappa mu(x) mu(y)`` with the linear form ``mu(z) = m . z
= u z_y - v z_x``; in the last term ``(a x q) . m = a_z theta^2`` and ``q . m = 0`` remove the
cubic terms. So, exactly,

    g(b) = sum_k F_k(theta) P_k(u, v),

nine even functions ``F = [cb, pz cb, sigma, pz sigma, rho cb, rho, kappa, pz kappa, rho
sigma]`` (:func:`spatial_functions`; ``cb = cos beta``) times fixed polynomials: constants for the
first two, linear forms for the next four, quadratic forms for the last three. Their
coefficients on the monomials ``(1, u, v, u^2, uv, v^2)`` are :func:`spatial_coefficients`, 19
numbers per correspondence (cheap vector algebra). Nothing is approximated, and nothing divides
by theta: the expansion holds through straight.

Scoring hypotheses (:func:`bending_sampson`) uses the relative pose itself, through
:func:`~apcc_graph.model.bending.bending_transform` and the Sampson error of
:func:`~apcc_graph.frontend.geometry.sampson_terms`.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from apcc_graph.frontend.geometry import SegmentTwoView, sampson_terms, skew
from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.bending import bending_transform
from apcc_graph.model.kinematics import sinc
from apcc_graph.model.segment import Segment

#: Which monomials ``(1, u, v, u^2, uv, v^2)`` each of the nine functions multiplies.
CONSTANT, LINEAR, QUADRATIC = slice(0, 2), slice(2, 6), slice(6, 9)


def spatial_functions(theta: ArrayLike, segment: Segment) -> FloatArray:
    """The nine even functions ``F_k(theta)`` of the expansion, ``theta.shape + (9,)``.

    ``[cos b, pz cos b, sigma, pz sigma, rho cos b, rho, kappa, pz kappa, rho sigma]`` with
    ``b = beta(theta)`` (radians), ``sigma = sin(b) / theta``, ``kappa = (1 - cos b) / theta^2``,
    ``rho = px / theta`` (metres per radian), ``pz`` (metres); finite at ``theta = 0``.
    """
    theta = np.asarray(theta, dtype=float)
    half = 0.5 * theta
    c = segment.link_ratio
    s, h = np.sin(half), np.cos(half)
    chord = segment.l1 * np.sqrt(1.0 - (c * s) ** 2) + segment.l2 * h
    pz = chord * h
    rho = 0.5 * chord * sinc(half)
    rate = 1.0 - segment.deviation_rate
    x = rate * theta
    cb = np.cos(x)
    sigma = rate * sinc(x)
    kappa = 0.5 * rate * rate * sinc(0.5 * x) ** 2
    return np.stack([cb, pz * cb, sigma, pz * sigma, rho * cb, rho, kappa, pz * kappa,
                     rho * sigma], axis=-1)


def _cross(x: FloatArray, y: FloatArray) -> FloatArray:
    """Cross products of ``(3, N)`` columns (either may be ``(3, 1)``)."""
    return np.stack([x[1] * y[2] - x[2] * y[1], x[2] * y[0] - x[0] * y[2],
                     x[0] * y[1] - x[1] * y[0]])


def _mu(z: FloatArray) -> FloatArray:
    """Coefficients of ``mu(z) = u z_y - v z_x`` on ``(u, v)`` of ``(3, N)`` columns,
    ``(N, 2)``."""
    return np.stack([z[1], -z[0]], axis=-1)


def _mu_mu(x: FloatArray, y: FloatArray) -> FloatArray:
    """Coefficients of ``mu(x) mu(y)`` on ``(u^2, uv, v^2)`` of ``(3, N)`` columns, ``(N,
    3)``."""
    return np.stack([x[1] * y[1], -(x[1] * y[0] + x[0] * y[1]), x[0] * y[0]], axis=-1)


def spatial_coefficients(f_a: FloatArray, f_b: FloatArray, view: SegmentTwoView) -> FloatArray:
    """Coefficients ``W`` with ``g(b) = sum_k F_k(theta) W[k] . (1, u, v, u^2, uv, v^2)``.

    Args:
        f_a, f_b: ``(N, 3)`` unit bearings in cameras a and b.
        view: the fixed parts (frame a's bend with its ``psi``, mounting, base motion).

    Returns:
        ``(N, 9, 6)``, mostly zeros (19 numbers per row); ``g`` is in metres.
    """
    Rc, tc = view.left[:3, :3], view.left[:3, 3]
    Rm, tm = view.right[:3, :3], view.right[:3, 3]
    a = Rc.T @ f_a.T  # (3, N) columns: Rc^T f_a
    w = Rm @ f_b.T  # Rm f_b
    d = Rc.T @ tc
    s0 = _cross(tm[:, None], w)
    a2 = _cross(a, d[:, None])
    a3 = np.stack([a[1], -a[0], np.zeros_like(a[0])])  # a x e_z
    az = a[2]
    wa = _cross(w, a)
    W = np.zeros((len(f_a), 9, 6))
    W[:, 0, 0] = (a * s0).sum(axis=0) + (a2 * w).sum(axis=0)
    W[:, 1, 0] = (a3 * w).sum(axis=0)
    W[:, 2, 1:3] = _mu(_cross(s0, a) + _cross(w, a2))
    W[:, 3, 1:3] = _mu(_cross(w, a3))
    W[:, 4, 1:3] = (wa[:2] - az * _mu(w).T).T  # nu(w x a) - a_z mu(w), nu(z) = u z_x + v z_y
    W[:, 5, 1:3] = (az * _mu(w).T).T
    W[:, 6, 3:6] = _mu_mu(a, s0) + _mu_mu(a2, w)
    W[:, 7, 3:6] = _mu_mu(a3, w)
    # mu(a) nu(w) = (u a_y - v a_x)(u w_x + v w_y)
    W[:, 8, 3] = a[1] * w[0]
    W[:, 8, 4] = a[1] * w[1] - a[0] * w[0]
    W[:, 8, 5] = -a[0] * w[1]
    return W


def monomials(u: ArrayLike, v: ArrayLike) -> FloatArray:
    """``(1, u, v, u^2, uv, v^2)`` of bending vectors, ``shape + (6,)``."""
    u, v = np.broadcast_arrays(np.asarray(u, dtype=float), np.asarray(v, dtype=float))
    return np.stack([np.ones_like(u), u, v, u * u, u * v, v * v], axis=-1)


def spatial_constraint(coef: FloatArray, u: ArrayLike, v: ArrayLike,
                       segment: Segment) -> FloatArray:
    """``g(b)`` (metres) of each row of ``coef`` ``(N, 9, 6)`` at bending vectors broadcast
    against ``(N,)`` (radians)."""
    u, v = np.broadcast_arrays(np.asarray(u, dtype=float), np.asarray(v, dtype=float))
    F = spatial_functions(np.hypot(u, v), segment)
    return np.einsum("...k,...kj,...j->...", F, coef, monomials(u, v))


def _odd_ratio(x: float) -> float:
    """``(sin x - x cos x) / x^3`` (``-sinc'(x) / x``), by its series below ``|x| = 1``."""
    if abs(x) >= 1.0:
        return (math.sin(x) - x * math.cos(x)) / x**3
    x2 = x * x
    return 1.0 / 3.0 + x2 * (-1.0 / 30.0 + x2 * (1.0 / 840.0 + x2 * (-1.0 / 45360.0 + x2 * (
        1.0 / 3991680.0 - x2 / 518918400.0))))


def _even_ratio(x: float) -> float:
    """``(x sin x - 2 (1 - cos x)) / x^4`` (``K'(x) / x`` of ``K = (1 - cos x) / x^2``), by
    its series ``sum_n (-1)^(n+1) (2n - 2) x^(2n-4) / (2n)!`` below ``|x| = 1``."""
    if abs(x) >= 1.0:
        return (x * math.sin(x) - 2.0 * (1.0 - math.cos(x))) / x**4
    x2 = x * x
    return -1.0 / 12.0 + x2 * (1.0 / 180.0 + x2 * (-1.0 / 6720.0 + x2 * (
        1.0 / 453600.0 + x2 * (-1.0 / 47900160.0 + x2 / 7264857600.0))))


def _sinc(x: float) -> float:
    return 1.0 - x * x / 6.0 + x**4 / 120.0 if abs(x) < 1e-3 else math.sin(x) / x


def _bend_matrix(cb: float, sigma: float, kappa: float, u: float, v: float,
                 p: tuple[float, float, float], one: float) -> FloatArray:
    """``[[cb I + sigma [m]x + kappa m m^T, p], [0, one]]`` with ``m = (-v, u, 0)``."""
    return np.array([[cb + kappa * v * v, -kappa * u * v, sigma * u, p[0]],
                     [-kappa * u * v, cb + kappa * u * u, sigma * v, p[1]],
                     [-sigma * u, -sigma * v, cb, p[2]],
                     [0.0, 0.0, 0.0, one]])


def bend_transform(u: float, v: float, segment: Segment) -> tuple[FloatArray, ...]:
    """``base_T_tip`` of one bending vector ``(u, v)`` (radians) and ``dT/du``, ``dT/dv`` (per
    radian), each ``(4, 4)``, exact through ``b = 0``.

    The transform of :func:`~apcc_graph.model.bending.bending_transform`, in the module's even
    functions: ``R = cos(beta) I + sigma [m]x + kappa m m^T``, ``p = rho (u, v, 0) + pz e_z``.
    A function ``f(theta)`` differentiates as ``df/du = (f'(theta) / theta) u``, and ``f' /
    theta`` is smooth for an even f (series near 0), so nothing divides by theta. Plain
    ``math`` on scalars: the fast path of Gauss-Newton and Newton steps.
    """
    theta = math.hypot(u, v)
    y = 0.5 * theta
    s, h = math.sin(y), math.cos(y)
    c = segment.link_ratio
    root = math.sqrt(1.0 - (c * s) ** 2)
    chord = segment.l1 * root + segment.l2 * h
    sy = _sinc(y)
    pz, rho = chord * h, 0.5 * chord * sy
    rate = 1.0 - segment.deviation_rate
    x = rate * theta
    cb, sigma = math.cos(x), rate * _sinc(x)
    kappa = 0.5 * rate * rate * _sinc(0.5 * x) ** 2
    T = _bend_matrix(cb, sigma, kappa, u, v, (rho * u, rho * v, pz), 1.0)
    dchord = -0.25 * sy * segment.l2 * (c * h / root + 1.0)  # chord' / theta
    d_rho = 0.5 * dchord * sy - 0.125 * chord * _odd_ratio(y)
    d_pz = dchord * h - 0.25 * chord * sy
    d_cb, d_sigma, d_kappa = -rate * sigma, -rate**3 * _odd_ratio(x), rate**4 * _even_ratio(x)
    dTu = _bend_matrix(d_cb * u, d_sigma * u, d_kappa * u, u, v,
                       (d_rho * u * u + rho, d_rho * u * v, d_pz * u), 0.0)
    dTv = _bend_matrix(d_cb * v, d_sigma * v, d_kappa * v, u, v,
                       (d_rho * u * v, d_rho * v * v + rho, d_pz * v), 0.0)
    # The derivative of m = (-v, u, 0) itself, in [m]x and m m^T.
    dTu[0, 2] += sigma
    dTu[2, 0] -= sigma
    dTu[1, 1] += 2.0 * kappa * u
    dTu[0, 1] -= kappa * v
    dTu[1, 0] -= kappa * v
    dTv[1, 2] += sigma
    dTv[2, 1] -= sigma
    dTv[0, 0] += 2.0 * kappa * v
    dTv[0, 1] -= kappa * u
    dTv[1, 0] -= kappa * u
    return T, dTu, dTv


def bending_poses(view: SegmentTwoView, u: ArrayLike, v: ArrayLike,
                  derivative: bool = False) -> FloatArray | tuple[FloatArray, ...]:
    """``camA_T_camB`` at bending vectors ``(M,)`` (and ``d/du``, ``d/dv``), ``(M, 4, 4)``."""
    if not derivative:
        T = bending_transform(u, v, view.segment)
        return view.left @ T @ view.right
    u, v = np.atleast_1d(u), np.atleast_1d(v)
    T, dTu, dTv = (np.stack(m) for m in zip(*(bend_transform(float(a), float(b), view.segment)
                                             for a, b in zip(u, v, strict=True)), strict=True))
    return (view.left @ T @ view.right, view.left @ dTu @ view.right,
            view.left @ dTv @ view.right)


def bending_sampson(f_a: FloatArray, f_b: FloatArray, view: SegmentTwoView, u: ArrayLike,
                    v: ArrayLike) -> FloatArray:
    """Sampson errors (radians) ``(M, N)`` of ``(N, 3)`` correspondences for ``(M,)`` bending
    vectors (:func:`~apcc_graph.frontend.geometry.sampson_terms`)."""
    pose = bending_poses(view, u, v)
    E = skew(pose[:, :3, 3]) @ pose[:, :3, :3]
    m = len(E)
    Efb = (E.reshape(3 * m, 3) @ f_b.T).reshape(m, 3, -1)  # (M, 3, N): E f_b
    Etfa = (np.swapaxes(E, 1, 2).reshape(3 * m, 3) @ f_a.T).reshape(m, 3, -1)
    num = (Efb * f_a.T).sum(axis=1)
    return sampson_terms(num, (Efb * Efb).sum(axis=1) + (Etfa * Etfa).sum(axis=1))


def _skew(t: FloatArray) -> FloatArray:
    """``[t]x`` of one vector (3,)."""
    x, y, z = float(t[0]), float(t[1]), float(t[2])
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def bending_sampson_gradient(f_a: FloatArray, f_b: FloatArray, view: SegmentTwoView, u: float,
                             v: float) -> tuple[FloatArray, FloatArray]:
    """Sampson errors ``(N,)`` (radians) at one bending vector and their gradient ``(2, N)``
    in ``(u, v)`` (per radian), through :func:`bend_transform`'s exact derivatives."""
    poses = view.left @ np.stack(bend_transform(u, v, view.segment)) @ view.right
    R, t = poses[0, :3, :3], poses[0, :3, 3]
    St = _skew(t)
    stack = np.stack([St @ R, _skew(poses[1, :3, 3]) @ R + St @ poses[1, :3, :3],
                      _skew(poses[2, :3, 3]) @ R + St @ poses[2, :3, :3]])  # E, dE/du, dE/dv
    X = (stack.reshape(9, 3) @ f_b.T).reshape(3, 3, -1)  # (E, dE/du, dE/dv) f_b
    Y = (np.swapaxes(stack, 1, 2).reshape(9, 3) @ f_a.T).reshape(3, 3, -1)
    nums = (X * f_a.T).sum(axis=1)  # f_a^T E f_b and its two derivatives
    norms2 = (X[0] * X[0]).sum(axis=0) + (Y[0] * Y[0]).sum(axis=0)
    e, ca, cb = sampson_terms(nums[0], norms2, differential=True)
    half_ds = (X[0] * X[1:]).sum(axis=1) + (Y[0] * Y[1:]).sum(axis=1)
    return e, ca * nums[1:] - cb * half_ds
