"""The 2-point solver: every bending vector of a spatial segment that two correspondences admit.

Problem (docs/estimation.md, "Two correspondences: the 2-point solver of a spatial segment").
Frame a's bend ``(theta_a, psi_a)``, the camera mounting and the base motion are known; frame
b's bend ``(theta_b, psi_b)`` is not. Each correspondence ``(f_a, f_b)`` gives one equation
``f_a . (t x R f_b) = 0`` with ``(R, t) = camA_T_camB(theta_b, psi_b)``; two of them fix the two
unknowns up to a finite set of roots, which this module finds.

Method.

1. Exact expansion (:mod:`~apcc_graph.frontend.spatial_basis`): in the bending vector ``b = (u,
   v) = theta (cos psi, sin psi)`` each constraint is ``g(b) = sum_k F_k(theta) P_k(u, v)``:
   nine even functions of theta, polynomials of degree <= 2 in ``(u, v)``.
2. Elimination of psi (:mod:`~apcc_graph.frontend.eliminant`): on the circle ``|b| = theta``
   each g is a trigonometric polynomial of degree 2 in psi, a quartic in ``tan(psi / 2)``; the
   two share a root exactly where a 4x4 Bezout determinant ``D(theta)`` vanishes.
3. Every root in theta (:mod:`~apcc_graph.frontend.pair_roots`): ``D`` is evaluated on a
   0.5 degree grid over ``[SMALL_BEND, theta_max]`` for every pair at once; the intervals
   around sign changes and local minima of ``|D|`` are sampled 16 times finer (at small motions
   roots come in clusters), every sign change is refined by Illinois regula falsi, and every
   local minimum of ``|D|`` without a sign change is searched for a hidden pair of roots. With a
   fixed base ``b = b_a`` solves every pair (``t = 0``), so ``D`` vanishes at ``|theta_a|``; it
   is divided by ``theta - |theta_a|`` (deflation), and the grid is anchored half a step off it.
4. psi back: the real root of H's quartic where both equations are smallest (the Bezout
   matrix's kernel ``(1, tau, tau^2, tau^3)`` is the cheaper alternative RANSAC uses).
5. Near straight the psi-dependence fades (D vanishes like ``theta^4``) and psi is undefined at
   ``theta = 0``; inside ``|b| < SMALL_BEND`` the equations are solved in ``b`` directly by
   Newton's method from ``b = 0``, which also finds an exactly straight ``b_b = 0``.
6. Every root is polished by Newton steps on the two equations in ``b`` (smooth through
   straight), checked (Sampson error, range), the trivial root ``b_a`` of a fixed base is
   dropped, and duplicates merged.

Parameterisation: ``(theta, psi)`` and ``(-theta, psi + pi)`` are the same bend (the double
cover). Roots are returned once each as ``theta >= 0`` and ``psi`` in ``(-pi, pi]`` (0 for an
exactly straight segment), the convention of :func:`~apcc_graph.model.bending.polar`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from apcc_graph.frontend.eliminant import common_psi, psi_from_roots
from apcc_graph.frontend.geometry import checked_bearings, sampson_terms, skew
from apcc_graph.frontend.pair_roots import (
    DEFAULT_GRID_STEP,
    SMALL_BEND,
    PairSetup,
    refine_theta,
    theta_brackets,
)
from apcc_graph.frontend.spatial_basis import bending_poses, spatial_coefficients
from apcc_graph.model.arrays import FloatArray, IntArray
from apcc_graph.model.bending import polar
from apcc_graph.model.segment import Segment

TRIVIAL_TOLERANCE = 1e-7
"""A root this close (radians, bending-vector distance) to ``b_a`` of a fixed base is the
trivial one and is dropped."""
ROOT_TOLERANCE = 1e-9
"""Largest Sampson error (radians) of a returned root on its two correspondences."""
STRAIGHT = 1e-12
"""A root this close to straight (radians) is returned as exactly straight, ``(0, 0)``."""


def _pair_residuals(setup: PairSetup, f_a: FloatArray, f_b: FloatArray, b: FloatArray,
                    derivative: bool) -> tuple[FloatArray, ...]:
    """``g`` ``(R, 2)`` of each root's two correspondences ``(R, 2, 3)`` (and the Jacobian
    ``(R, 2, 2)`` in ``(u, v)``, and the Sampson norms ``(R, 2)``)."""
    out = bending_poses(setup.view, b[:, 0], b[:, 1], derivative=derivative)
    pose = out[0] if derivative else out
    R, t = pose[:, :3, :3], pose[:, :3, 3]
    E = skew(t) @ R
    Efb = np.einsum("rij,rpj->rpi", E, f_b)
    g = np.einsum("rpi,rpi->rp", f_a, Efb)
    if not derivative:
        Etfa = np.einsum("rji,rpj->rpi", E, f_a)
        return g, np.einsum("rpi,rpi->rp", Efb, Efb) + np.einsum("rpi,rpi->rp", Etfa, Etfa)
    jac = np.empty(g.shape + (2,))
    for col, d in enumerate(out[1:]):
        dE = skew(d[:, :3, 3]) @ R + skew(t) @ d[:, :3, :3]
        jac[..., col] = np.einsum("rpi,rij,rpj->rp", f_a, dE, f_b)
    return g, jac


def newton_polish(setup: PairSetup, f_a: FloatArray, f_b: FloatArray, b: FloatArray,
                  steps: int) -> FloatArray:
    """Newton's method on the two equations in the bending vector, ``(R, 2)`` radians."""
    b = b.copy()
    for _ in range(steps):
        g, J = _pair_residuals(setup, f_a, f_b, b, derivative=True)
        det = J[:, 0, 0] * J[:, 1, 1] - J[:, 0, 1] * J[:, 1, 0]
        ok = np.abs(det) > 1e-300
        inv = 1.0 / np.where(ok, det, 1.0)
        du = (J[:, 1, 1] * g[:, 0] - J[:, 0, 1] * g[:, 1]) * inv
        dv = (J[:, 0, 0] * g[:, 1] - J[:, 1, 0] * g[:, 0]) * inv
        b[:, 0] -= np.where(ok, du, 0.0)
        b[:, 1] -= np.where(ok, dv, 0.0)
    return b


def root_errors(setup: PairSetup, f_a: FloatArray, f_b: FloatArray, b: FloatArray) -> FloatArray:
    """Largest Sampson error (radians) of each root ``(R, 2)`` on its two correspondences."""
    g, norms2 = _pair_residuals(setup, f_a, f_b, b, derivative=False)
    return np.max(np.abs(sampson_terms(g, norms2)), axis=1)


@dataclass(frozen=True)
class SolverOptions:
    """Effort of :func:`solve_pairs`: exact roots for the solver, cheap ones for RANSAC.

    Attributes:
        refine: Illinois iterations on ``D`` per bracket.
        polish: Newton steps in the bending vector per root (0: none, no checks).
        resolve_close: search dips of ``|D|`` for roots closer than a grid step.
        small: also search ``|b| < SMALL_BEND`` by Newton's method from ``b = 0``.
        exact_psi: psi from the real roots of a quartic (tells apart roots at almost the same
            theta) rather than from the Bezout kernel (cheaper).
    """

    refine: int = 40
    polish: int = 3
    resolve_close: bool = True
    small: bool = True
    exact_psi: bool = True


def solve_pairs(setup: PairSetup, coef: FloatArray, f_a: FloatArray, f_b: FloatArray,
                options: SolverOptions = SolverOptions()) -> tuple[IntArray, FloatArray]:
    """Every root of S pairs of correspondences at once.

    Args:
        setup: the frame pair.
        coef: ``(S, 2, 9, 6)`` the pairs' coefficients (any scale per correspondence).
        f_a, f_b: ``(S, 2, 3)`` the pairs' bearings.
        options: effort.

    Returns:
        ``(pair, b)``: for each root its pair index ``(R,)`` and its bending vector ``(R, 2)``
        (radians), the trivial root excluded, sorted by pair then ``|b|``.
    """
    scale = np.max(np.abs(coef), axis=(2, 3), keepdims=True)
    coef = coef / np.where(scale > 0.0, scale, 1.0)
    pair, lo, hi, flo, fhi = theta_brackets(setup, coef, options.resolve_close)
    theta, B, c = refine_theta(setup, coef[pair], lo, hi, flo, fhi, options.refine)
    if len(pair) == 0:
        psi = np.zeros(0)
    elif options.exact_psi:
        psi = psi_from_roots(c, theta)
    else:
        psi = common_psi(B)
    b = np.stack([theta * np.cos(psi), theta * np.sin(psi)], axis=-1)
    if options.small:
        disk = np.arange(len(coef))
        pair = np.concatenate([pair, disk])
        b = np.concatenate([b, np.zeros((len(disk), 2))])
        lo = np.concatenate([lo, np.zeros(len(disk))])
        hi = np.concatenate([hi, np.full(len(disk), SMALL_BEND)])
    if options.polish:
        b = newton_polish(setup, f_a[pair], f_b[pair], b, options.polish)
        keep = _admissible(setup, f_a[pair], f_b[pair], b, lo, hi)
        pair, b = pair[keep], b[keep]
    if setup.anchor is not None:
        keep = np.hypot(*(b - setup.b_a).T) > TRIVIAL_TOLERANCE
        pair, b = pair[keep], b[keep]
    return _unique(pair, b)


def _admissible(setup: PairSetup, f_a: FloatArray, f_b: FloatArray, b: FloatArray,
                lo: FloatArray, hi: FloatArray) -> FloatArray:
    """Polished roots that solve both equations, in range and near where they were found.

    A root found in a bracket ``[lo, hi]`` of theta must stay there (up to a hundredth of the
    bracket): Newton's method that wandered to another root leaves that root to its own
    bracket.
    """
    theta = np.hypot(b[:, 0], b[:, 1])
    slack = 0.01 * (hi - lo) + 1e-9
    inside = (theta >= lo - slack) & (theta <= hi + slack)
    inside &= theta <= setup.view.segment.theta_max * (1.0 + 1e-12)
    ok = np.all(np.isfinite(b), axis=1) & inside
    errors = np.full(len(b), np.inf)
    errors[ok] = root_errors(setup, f_a[ok], f_b[ok], b[ok])
    return ok & (errors < ROOT_TOLERANCE)


def _unique(pair: IntArray, b: FloatArray) -> tuple[IntArray, FloatArray]:
    """Roots sorted by pair then ``|b|``, one of each group closer than 1e-9 rad."""
    order = np.lexsort((np.hypot(b[:, 0], b[:, 1]), pair))
    pair, b = pair[order], b[order]
    if len(pair) < 2:
        return pair, b
    keep = np.ones(len(pair), dtype=bool)
    for i in range(1, len(pair)):  # few roots per pair: a short loop
        j = i - 1
        while j >= 0 and pair[j] == pair[i]:
            if keep[j] and np.hypot(*(b[i] - b[j])) < 1e-9:
                keep[i] = False
                break
            j -= 1
    return pair[keep], b[keep]


def two_point(
    theta_a: float,
    psi_a: float,
    segment: Segment,
    tip_T_cam: ArrayLike | None,
    baseA_T_baseB: ArrayLike | None,
    f_a: ArrayLike,
    f_b: ArrayLike,
    grid_step: float = DEFAULT_GRID_STEP,
) -> FloatArray:
    """Every admissible bend ``(theta_b, psi_b)`` of a spatial segment given two
    correspondences.

    Frames: ``f_a``, ``f_b`` are unit bearings in the camera at frames a and b; the camera is
    mounted by ``tip_T_cam`` (tip_T_cam maps camera points to the tip frame) and the segment's
    base moves by ``baseA_T_baseB`` (base at b to base at a) between the frames.

    Args:
        theta_a, psi_a: frame a's bend and bending-plane angle (radians; any sign of theta_a).
        segment: the segment (``theta_b`` is searched in ``[0, theta_max]``, all psi).
        tip_T_cam: camera mounting (None: identity).
        baseA_T_baseB: base motion from a to b (None: identity, a fixed base; then the trivial
            root ``b_b = b_a`` is excluded).
        f_a, f_b: ``(2, 3)`` the two correspondences' bearings.
        grid_step: bracketing grid step in theta (radians).

    Returns:
        ``(R, 2)`` roots ``(theta_b, psi_b)``, ``theta_b >= 0`` ascending, ``psi_b`` in
        ``(-pi, pi]`` (``(0, 0)`` within :data:`STRAIGHT` of straight); each solves both
        constraints to a Sampson error below :data:`ROOT_TOLERANCE` and has ``theta_b <=
        theta_max``. ``(0, 2)`` when none.

    Raises:
        ValueError: bearings not ``(2, 3)``, non-finite, or non-finite angles or grid step.
    """
    f_a, f_b = checked_bearings(f_a, f_b)
    if f_a.shape != (2, 3):
        raise ValueError(f"f_a and f_b have shape {f_a.shape}: expected (2, 3), two "
                         "correspondences (use two_point_ransac for more)")
    if not (np.all(np.isfinite(f_a)) and np.all(np.isfinite(f_b))):
        raise ValueError("f_a and f_b must be finite unit bearings")
    for name, value in (("theta_a", theta_a), ("psi_a", psi_a), ("grid_step", grid_step)):
        if not math.isfinite(value):
            raise ValueError(f"{name} = {value!r}: expected a finite number (radians)")
    if not grid_step > 0.0:
        raise ValueError(f"grid_step = {grid_step!r}: expected > 0 (radians)")
    setup = PairSetup.build(theta_a, psi_a, segment, tip_T_cam, baseA_T_baseB, grid_step)
    coef = spatial_coefficients(f_a, f_b, setup.view)[None]
    _, b = solve_pairs(setup, coef, f_a[None], f_b[None])
    b[np.hypot(b[:, 0], b[:, 1]) < STRAIGHT] = 0.0
    theta, psi = polar(b[:, 0], b[:, 1])
    return np.stack([theta, psi], axis=-1)
