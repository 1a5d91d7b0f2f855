"""Planar rods whose curvature varies along the arc: shapes that PCC cannot represent exactly.

A real segment under a tip force or a distributed load does not bend with constant curvature
(docs/estimation.md, "Calibrating a segment"). This module integrates planar curves with a curvature
profile, to make test and benchmark data for calibration and to simulate model mismatch. Frames as
everywhere: base at the origin, base axis +z, bending toward +x for positive angles; metres and
radians.

The profile used here grows linearly along the arc, with the total bend fixed:
``kappa(s) = theta / L * (1 + g s / L) / (1 + g / 2)``, so the tangent angle is
``a(s) = theta / (1 + g / 2) * (u + g u^2 / 2)`` with ``u = s / L``. ``g = 0`` is constant
curvature; ``g > 0`` bends more toward the tip (tip curvature ``1 + g`` times the base's).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.kinematics import plane_to_transform


def growing_curvature_tip(
    theta: ArrayLike, length: float, growth: float, n_nodes: int = 64
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Tip of a planar rod whose curvature grows linearly along the arc.

    The position integral ``int_0^L (sin a(s), cos a(s)) ds`` is evaluated by Gauss-Legendre
    quadrature; with 64 nodes it is exact to machine precision for bends up to pi.

    Args:
        theta: total bend(s), i.e. tip tangent angle(s), radians, any shape.
        length: arc length L (metres).
        growth: g, the relative growth of the curvature from base to tip (g > -1; 0 = PCC).
        n_nodes: quadrature nodes.

    Returns:
        ``(x, z, tip_angle)`` arrays with the shape of ``theta``; ``tip_angle`` equals ``theta``.
    """
    if not growth > -1.0:
        raise ValueError(f"growth = {growth!r}: expected g > -1 (curvature keeps its sign)")
    theta = np.asarray(theta, dtype=float)
    nodes, weights = np.polynomial.legendre.leggauss(n_nodes)
    u = 0.5 * (nodes + 1.0)  # arc fraction in [0, 1]
    angle = theta[..., None] / (1.0 + 0.5 * growth) * (u + 0.5 * growth * u * u)
    w = 0.5 * length * weights
    return np.sin(angle) @ w, np.cos(angle) @ w, theta.copy()


def growing_curvature_transform(
    theta: ArrayLike, length: float, growth: float, psi: ArrayLike = 0.0
) -> FloatArray:
    """``base_T_tip`` of a rod with linearly growing curvature, ``(..., 4, 4)``.

    The tip tangent is at ``theta`` (no separate deviation: the shape itself departs from an
    arc); ``psi`` turns the bending plane about the base z axis as for the APCC model.
    """
    x, z, angle = growing_curvature_tip(theta, length, growth)
    return plane_to_transform(angle, x, z, psi)
