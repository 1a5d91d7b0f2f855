"""The epipolar constraint of one segment expanded on nine basis functions of its angle.

Expansion (docs/estimation.md, "Two frames"). Write ``camA_T_camB = [Rc | tc] . T(theta_b) .
[Rm | tm]`` (:class:`~apcc_graph.frontend.geometry.SegmentTwoView`) and ``a = Rc^T f_a``,
``w = Rm f_b``, ``d = Rc^T tc``. The segment's rotation turns about a fixed axis ``n`` by
``beta = theta_b - delta(theta_b)``, so by Rodrigues ``u . R_beta v`` is linear in
``(1, cos beta, sin beta)``, and its tip is ``px(theta_b) e1 + pz(theta_b) e3``. Hence exactly

    g(theta) = f_a . (t x R f_b) = sum_k c_k phi_k(theta),
    phi = [1, cos b, sin b] x [1, px(theta), pz(theta)]

nine basis functions shared by all correspondences (:func:`basis_functions`), and nine
coefficients per correspondence (:func:`constraint_coefficients`, cheap vector algebra). Nothing
is approximated: ``phi`` are the model's own functions. The essential matrix expands the same
way, ``E(theta) = sum_k phi_k(theta) E_k``, which scores many hypotheses at once
(:class:`EpipolarBasis`).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from apcc_graph.frontend.geometry import SegmentTwoView, sampson_terms, skew
from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.kinematics import apcc_in_plane
from apcc_graph.model.segment import Segment


def basis_functions(theta: FloatArray, segment: Segment) -> tuple[FloatArray, FloatArray]:
    """``phi_k(theta)`` and ``phi_k'(theta)``, each ``theta.shape + (9,)``."""
    planar = apcc_in_plane(theta, segment)
    cb, sb = np.cos(planar.beta), np.sin(planar.beta)
    rate = planar.dbeta
    one = np.ones_like(cb)
    zero = np.zeros_like(cb)
    rot = (one, cb, sb)
    drot = (zero, -rate * sb, rate * cb)
    S, H, dS, dH = planar.px, planar.pz, planar.dpx, planar.dpz
    phi = np.stack([*rot, *(S * r for r in rot), *(H * r for r in rot)], axis=-1)
    dphi = np.stack([*drot, *(dS * r + S * q for r, q in zip(rot, drot, strict=True)),
                     *(dH * r + H * q for r, q in zip(rot, drot, strict=True))], axis=-1)
    return phi, dphi


def _cross(u: FloatArray, v: FloatArray) -> FloatArray:
    """Row-wise cross products of ``(N, 3)`` arrays (or one row and ``(N, 3)``)."""
    u0, u1, u2 = u[..., 0], u[..., 1], u[..., 2]
    v0, v1, v2 = v[..., 0], v[..., 1], v[..., 2]
    return np.stack([u1 * v2 - u2 * v1, u2 * v0 - u0 * v2, u0 * v1 - u1 * v0], axis=-1)


def _rodrigues_terms(u: FloatArray, v: FloatArray, n: FloatArray) -> FloatArray:
    """Coefficients of ``u . R_beta v`` on ``(1, cos beta, sin beta)``, ``(N, 3)``.

    ``R_beta v = (n.v) n + cos(beta) (v - (n.v) n) + sin(beta) (n x v)``, and
    ``u . (n x v) = (u x n) . v``.
    """
    un, vn = u @ n, v @ n
    out = np.empty((len(u), 3))
    out[:, 0] = un * vn
    out[:, 1] = np.einsum("ij,ij->i", u, v) - out[:, 0]
    out[:, 2] = np.einsum("ij,ij->i", _cross(u, n), v)
    return out


def _plane_axes(psi: float) -> tuple[FloatArray, FloatArray, FloatArray]:
    """The bending axis ``n`` and the tip's in-plane directions ``e1``, ``e3``."""
    cp, sp = math.cos(psi), math.sin(psi)
    return np.array([-sp, cp, 0.0]), np.array([cp, sp, 0.0]), np.array([0.0, 0.0, 1.0])


def constraint_coefficients(f_a: FloatArray, f_b: FloatArray, view: SegmentTwoView) -> FloatArray:
    """The nine coefficients ``c`` of ``g(theta) = c . phi(theta)`` per correspondence, ``(N, 9)``.

    ``g`` is ``f_a . (t x R f_b)`` in metres (the scale of t).
    """
    Rc, tc = view.left[:3, :3], view.left[:3, 3]
    Rm, tm = view.right[:3, :3], view.right[:3, 3]
    a = f_a @ Rc  # Rc^T f_a
    w = f_b @ Rm.T  # Rm f_b
    d = Rc.T @ tc
    n, e1, e3 = _plane_axes(view.psi)
    coef = np.empty((len(a), 9))
    coef[:, 0:3] = (_rodrigues_terms(a, _cross(tm, w), n)
                    + _rodrigues_terms(_cross(a, d), w, n))
    coef[:, 3:6] = _rodrigues_terms(_cross(a, e1), w, n)
    coef[:, 6:9] = _rodrigues_terms(_cross(a, e3), w, n)
    return coef


def _sq(x: FloatArray) -> FloatArray:
    """Squared norms of ``(M, 3, N)`` vectors (component axis 1), ``(M, N)``."""
    return x[:, 0] * x[:, 0] + x[:, 1] * x[:, 1] + x[:, 2] * x[:, 2]


def _dot(x: FloatArray, y: FloatArray) -> FloatArray:
    """Dot products of ``(M, 3, N)`` vectors (component axis 1), ``(M, N)``."""
    return x[:, 0] * y[:, 0] + x[:, 1] * y[:, 1] + x[:, 2] * y[:, 2]


class EpipolarBasis:
    """Sampson errors of many hypotheses theta_b through the same nine basis functions.

    ``E(theta) = sum_k phi_k(theta) E_k`` exactly: with ``camA_T_camB = [Rc|tc] T [Rm|tm]``,
    ``E = Rc [R_b tm + px e1 + pz e3 + d]x R_b Rm`` and ``R_b = n n^T + cos(b) (I - n n^T) +
    sin(b) [n]x``, using ``[R x]x R = R [x]x``. The products ``E_k f_b`` and ``E_k^T f_a`` are
    computed once per call; scoring M hypotheses is then two ``(M, 9) @ (9, 3N)`` products, and
    the error itself is :func:`~apcc_graph.frontend.geometry.sampson_terms`.

    Args:
        f_a, f_b: ``(N, 3)`` unit bearings.
        view: the two-view set-up.

    Attributes:
        coef: ``(N, 9)`` the constraint's coefficients (as :func:`constraint_coefficients`).
    """

    def __init__(self, f_a: FloatArray, f_b: FloatArray, view: SegmentTwoView) -> None:
        self.view = view
        Rc, tc = view.left[:3, :3], view.left[:3, 3]
        Rm, tm = view.right[:3, :3], view.right[:3, 3]
        d = Rc.T @ tc
        n, e1, e3 = _plane_axes(view.psi)
        rot = [np.outer(n, n), np.eye(3) - np.outer(n, n), skew(n)]
        mats = ([A @ skew(tm) + skew(d) @ A for A in rot]
                + [skew(e1) @ A for A in rot] + [skew(e3) @ A for A in rot])
        E_k = Rc @ np.stack(mats) @ Rm  # (9, 3, 3)
        self.n = len(f_a)
        # Layout (9, 3, N): each vector component is a contiguous block of N values.
        self.Efb = (E_k.reshape(27, 3) @ f_b.T).reshape(9, -1)  # rows: E_k f_b
        self.Etfa = (np.swapaxes(E_k, 1, 2).reshape(27, 3) @ f_a.T).reshape(9, -1)
        self.coef = (self.Efb.reshape(9, 3, self.n) * f_a.T).sum(axis=1).T  # (N, 9)

    def errors(self, theta: ArrayLike, derivative: bool = False
               ) -> FloatArray | tuple[FloatArray, FloatArray]:
        """Sampson errors ``(M, N)`` (radians) for ``(M,)`` hypotheses (and d/dtheta)."""
        theta = np.atleast_1d(np.asarray(theta, dtype=float))
        phi, dphi = basis_functions(theta, self.view.segment)
        m = len(theta)
        Efb = (phi @ self.Efb).reshape(m, 3, self.n)
        Etfa = (phi @ self.Etfa).reshape(m, 3, self.n)
        num = phi @ self.coef.T
        norms2 = _sq(Efb) + _sq(Etfa)
        if not derivative:
            return sampson_terms(num, norms2)
        e, a, b = sampson_terms(num, norms2, differential=True)
        dEfb = (dphi @ self.Efb).reshape(m, 3, self.n)
        dEtfa = (dphi @ self.Etfa).reshape(m, 3, self.n)
        dnum = dphi @ self.coef.T
        return e, a * dnum - b * (_dot(Efb, dEfb) + _dot(Etfa, dEtfa))
