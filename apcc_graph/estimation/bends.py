"""The estimators' parameterisation of a robot, and the way back to ``(theta, psi)``.

Every estimator solves for one vector per frame in a
:class:`~apcc_graph.model.parameterisation.Bending`: the angles in fixed bending planes (a
planar robot, :func:`parameterisation` with ``spatial=False``) or every segment's bending vector
``(u, v) = theta (cos psi, sin psi)`` (a robot that bends in 3-D, ``spatial=True``; docs/
estimation.md, "Robots that bend in 3-D"). This module builds it for a robot, checks the start
a user gives (:func:`start_vector`), and turns frame vectors with their marginal covariance
blocks into an :class:`~apcc_graph.estimation.result.Estimate` (:func:`bending_estimate`): a
planar robot's signed angles, or a spatial robot's magnitudes ``theta >= 0`` with the planes
``psi`` and first-order standard deviations of both.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from apcc_graph.estimation.result import Estimate
from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.parameterisation import Bending
from apcc_graph.model.robot import Robot
from apcc_graph.model.sequence import Sequence


def parameterisation(robot: Robot, spatial: bool) -> Bending:
    """The estimators' parameterisation of ``robot``: free bending planes with ``spatial``,
    otherwise the planar robot's fixed planes (every ``psi = 0``)."""
    return Bending.free(robot.segments) if spatial else Bending.fixed(robot.segments)


def start_vector(robot: Robot, bending: Bending, theta0: ArrayLike | None,
                 psi0: ArrayLike | None = None) -> FloatArray:
    """The start's frame vector ``(dim,)`` from ``theta0`` (checked as
    :meth:`~apcc_graph.model.robot.Robot.configuration`; ``None`` is straight) and, for free
    planes, ``psi0`` (``(S,)`` finite radians; ``None`` is 0).

    Raises:
        ValueError: ``theta0`` as :meth:`~apcc_graph.model.robot.Robot.configuration`;
            ``psi0`` not ``(S,)`` finite angles, or given for fixed planes.
    """
    thetas = robot.configuration(theta0)
    if psi0 is None:
        return bending.vector(thetas)
    if not bending.is_free:
        raise ValueError("psi0 is given but the bending planes are fixed (a planar robot): "
                         "bending planes are estimated only for a spatial robot "
                         "(spatial=True)")
    try:
        psis = np.asarray(psi0, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"psi0 = {psi0!r}: expected {robot.n_segments} bending-plane "
                         "angles in radians") from None
    if psis.shape != (robot.n_segments,):
        raise ValueError(f"psi0 has shape {psis.shape}: expected ({robot.n_segments},), "
                         "one bending-plane angle per segment in radians")
    bad = np.flatnonzero(~np.isfinite(psis))
    if len(bad):
        raise ValueError(f"psi0[{bad[0]}] = {float(psis[bad[0]])!r}: expected a finite angle "
                         "(radians)")
    return bending.vector(thetas, psis)


def bending_estimate(method: str, sequence: Sequence, bending: Bending, x: FloatArray,
                     blocks: FloatArray | None, status: NDArray[np.str_],
                     inliers: NDArray[np.int64], **extra: Any) -> Estimate:
    """The :class:`~apcc_graph.estimation.result.Estimate` of frame vectors ``x`` ``(F, dim)``
    with per-segment marginal covariance blocks ``(F, S, w, w)`` (``None``: no uncertainty,
    NaN sigmas); ``extra`` goes to the Estimate (e.g. ``robot``, ``calibration_sigmas``)."""
    thetas, psis = bending.polar(x)
    if blocks is None:
        sigmas = np.full(thetas.shape, np.nan)
        psi_sigmas = None if psis is None else sigmas.copy()
    else:
        sigmas, psi_sigmas = bending.deviations(x, blocks)
    extra.setdefault("robot", sequence.robot)
    return Estimate(method=method, timestamps=sequence.timestamps.copy(), thetas=thetas,
                    sigmas=sigmas, status=status, inliers=inliers,
                    world_T_base=sequence.world_T_base, psis=psis, psi_sigmas=psi_sigmas,
                    **extra)
