"""The 1-point solver: every angle of a segment that one correspondence admits.

Problem (docs/estimation.md, "Two frames"). With frame a's angle ``theta_a``, the camera mounting
and the base motion known, one correspondence ``(f_a, f_b)`` gives one equation in the unknown
``theta_b``:
``g(theta_b) = f_a . (t x R f_b) = 0`` with ``(R, t) = camA_T_camB(theta_b)``.

Method (works for every 0 < k < 0.5 and keeps delta exactly): ``g`` is exactly a combination of
nine basis functions of ``theta_b`` shared by all correspondences, with nine coefficients per
correspondence (:mod:`~apcc_graph.frontend.basis`); all its roots are bracketed on a grid over
``[-theta_max, theta_max]`` and refined to machine precision, the trivial root ``theta_b =
theta_a`` of a fixed base deflated away (:mod:`~apcc_graph.frontend.roots`). RANSAC around the
solver is :mod:`~apcc_graph.frontend.ransac`.

Returns follow PoseLib's convention: all admissible roots, padded with NaN.
"""

from __future__ import annotations

from numpy.typing import ArrayLike

from apcc_graph.frontend.basis import constraint_coefficients
from apcc_graph.frontend.geometry import SegmentTwoView, checked_bearings
from apcc_graph.frontend.roots import DEFAULT_GRID_STEP, solve_roots
from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.segment import Segment


def one_point(
    f_a: ArrayLike,
    f_b: ArrayLike,
    theta_a: float,
    segment: Segment,
    tip_T_cam: ArrayLike | None = None,
    baseA_T_baseB: ArrayLike | None = None,
    psi: float = 0.0,
    grid_step: float = DEFAULT_GRID_STEP,
) -> FloatArray:
    """Every admissible root theta_b of each correspondence's epipolar constraint.

    Args:
        f_a, f_b: ``(N, 3)`` unit bearings in the camera at frames a and b.
        theta_a: the segment's bend at frame a (radians).
        segment: the segment the camera rides on (any 0 < k < 0.5, delta kept exactly).
        tip_T_cam: camera mounting (default identity).
        baseA_T_baseB: motion of the segment's base from a to b (default identity: fixed base,
            and the trivial root theta_a is excluded).
        psi: bending-plane angle (radians).
        grid_step: bracketing grid step (radians); roots closer together than this may merge.

    Returns:
        ``(N, R)`` roots in ``[-theta_max, theta_max]``, ascending per row, padded with NaN
        (``R >= 1``; a row of NaN where a correspondence has no admissible root, e.g. NaN input).
    """
    f_a, f_b = checked_bearings(f_a, f_b)
    view = SegmentTwoView.build(theta_a, segment, tip_T_cam, baseA_T_baseB, psi)
    return solve_roots(constraint_coefficients(f_a, f_b, view), view, grid_step)
