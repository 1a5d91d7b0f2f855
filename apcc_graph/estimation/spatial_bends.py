"""Spatial estimates in bending vectors: conversions to and from ``(theta, psi)``.

A spatial robot's estimators solve for every segment's bending vector ``b = (u, v) = theta (cos
psi, sin psi)`` (:mod:`apcc_graph.model.bending`; docs/estimation.md, "Robots that bend in 3-D"),
smooth through straight, and report ``theta = |b| >= 0`` and ``psi = atan2(v, u)``. Frame
vectors are laid out ``(u_0, v_0, u_1, v_1, ...)``: ``(F, 2 S)`` for F frames, S segments.

Uncertainty, to first order: with the bending vector's ``2 x 2`` marginal covariance ``C``,
``sigma_theta^2 = r^T C r`` along ``r = b / |b|`` and ``sigma_psi^2 = t^T C t / |b|^2`` across,
``t = (-v, u) / |b|``. ``sigma_psi`` grows like ``1 / |b|`` toward straight, where psi is
undefined; at exactly ``b = 0`` it is ``inf`` and ``sigma_theta`` is the larger axis of ``C``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.bending import bending_vector, polar
from apcc_graph.model.robot import Robot


def bends_from(thetas: ArrayLike, psis: ArrayLike) -> FloatArray:
    """``(..., 2 S)`` bending vectors of angles and bending planes ``(..., S)`` (radians;
    ``theta`` may be negative)."""
    u, v = bending_vector(thetas, psis)
    return np.stack([u, v], axis=-1).reshape(*u.shape[:-1], 2 * u.shape[-1])


def polar_from(bends: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """``(thetas, psis)``, each ``(..., S)``, of bending vectors ``(..., 2 S)``: ``theta >= 0``,
    ``psi`` in ``(-pi, pi]`` (0 where straight)."""
    b = np.asarray(bends, dtype=float)
    b = b.reshape(*b.shape[:-1], b.shape[-1] // 2, 2)
    return polar(b[..., 0], b[..., 1])


def polar_sigmas(bends: ArrayLike, covariances: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """First-order standard deviations ``(sigma_theta, sigma_psi)``, each ``(..., S)``, of
    bending vectors ``(..., 2 S)`` with marginal covariances ``(..., S, 2, 2)`` (module
    docstring); NaN where a covariance is NaN."""
    b = np.asarray(bends, dtype=float)
    b = b.reshape(*b.shape[:-1], b.shape[-1] // 2, 2)
    C = np.asarray(covariances, dtype=float)
    norm = np.hypot(b[..., 0], b[..., 1])
    straight = norm == 0.0
    safe = np.where(straight, 1.0, norm)
    r = np.where(straight[..., None], np.array([1.0, 0.0]), b / safe[..., None])
    t = np.stack([-r[..., 1], r[..., 0]], axis=-1)
    along = np.einsum("...i,...ij,...j->...", r, C, r)
    across = np.einsum("...i,...ij,...j->...", t, C, t)
    with np.errstate(invalid="ignore"):
        largest = np.linalg.eigvalsh(np.nan_to_num(C))[..., -1]
    largest = np.where(np.isnan(C).any(axis=(-2, -1)), np.nan, largest)
    sigma_theta = np.sqrt(np.maximum(np.where(straight, largest, along), 0.0))
    with np.errstate(divide="ignore"):
        sigma_psi = np.where(straight, np.inf, np.sqrt(np.maximum(across, 0.0)) / safe)
    sigma_psi = np.where(np.isnan(across), np.nan, sigma_psi)
    return sigma_theta, sigma_psi


def start_bends(robot: Robot, theta0: ArrayLike | None, psi0: ArrayLike | None) -> FloatArray:
    """``(2 S,)`` the starting bending vectors of a spatial robot from ``theta0`` (checked as
    :meth:`~apcc_graph.model.robot.Robot.configuration`; ``None`` is straight) and ``psi0``
    (``(S,)`` finite radians; ``None`` is 0).

    Raises:
        ValueError: ``theta0`` as :meth:`~apcc_graph.model.robot.Robot.configuration`;
            ``psi0`` not ``(S,)`` finite angles.
    """
    thetas = robot.configuration(theta0)
    if psi0 is None:
        psis = np.zeros(robot.n_segments)
    else:
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
    return bends_from(thetas, psis)
