"""Solving the backbone calibration by variable projection.

The unknowns split into a few shared ones ``z`` (k, rate, marker offsets) and two per pose and
segment (the bending vector), and a pose's residuals depend on its own bends only. So for a given
``z`` every pose's bends are found on their own (:func:`best_bends`: a damped Gauss-Newton step
per pose, all poses at once in numpy), and scipy's least squares works on ``z`` alone with the
projected residual ``r(z) = r(z, b*(z))``. Its Jacobian is the Schur complement form of Golub and
Pereyra: with ``J_z`` and ``J_b`` the partial Jacobians at ``b*``,

    dr/dz = (I - J_b (J_b^T J_b)^-1 J_b^T) J_z        (one 2x2 block per pose and segment)

computed from finite differences of the pose residuals with the bends held (one evaluation per
shared unknown, two for all bends at once). The same matrix gives the covariance of ``z``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import scipy.optimize

from apcc_graph.calibration.backbone_model import Layout, pose_rows
from apcc_graph.model.arrays import FloatArray

STEP = 1e-7
"""Finite-difference step of the Jacobians (radians, metres, or unitless for k and the rate)."""
BEND_TOLERANCE = 1e-11
"""The per-pose solve stops when no bend moves more than this (radians)."""
OFFSET_REACH = 5.0
"""Offsets are bounded to this many prior sigmas."""


def _pose_jacobian(rows_of: Callable[[FloatArray], FloatArray], bends: FloatArray,
                   base: FloatArray) -> FloatArray:
    """``(..., rows, p)`` derivative of each block's rows by its own ``p`` unknowns (the rows of
    a pose and segment depend on that bending vector only, so one step moves all at once)."""
    cols = []
    for c in range(bends.shape[-1]):
        step = np.zeros_like(bends)
        step[..., c] = STEP
        cols.append((rows_of(bends + step) - base) / STEP)
    return np.stack(cols, axis=-1)


def best_bends(rows_of: Callable[[FloatArray], FloatArray], start: FloatArray,
               max_iterations: int = 60) -> FloatArray:
    """Each block's unknowns that minimise its own rows (damped Gauss-Newton, per block): a
    pose's bending vector here, a frame's bends in :mod:`apcc_graph.evaluation.tip_floor`.

    Args:
        rows_of: unknowns ``(..., p)`` -> rows ``(..., r)``; a block's rows depend on its own
            unknowns only.
        start: ``(..., p)`` first guess.
        max_iterations: at most this many steps.
    """
    bends = start.copy()
    rows = rows_of(bends)
    cost = np.sum(rows**2, axis=-1)
    damping = np.full(cost.shape, 1e-6)
    for _ in range(max_iterations):
        jac = _pose_jacobian(rows_of, bends, rows)
        normal = np.einsum("...ri,...rj->...ij", jac, jac)
        scale = 1.0 + np.trace(normal, axis1=-2, axis2=-1)
        normal += (damping * scale)[..., None, None] * np.eye(bends.shape[-1])
        step = -np.linalg.solve(normal, np.einsum("...ri,...r->...i", jac, rows)[..., None])[..., 0]
        trial = bends + step
        trial_rows = rows_of(trial)
        trial_cost = np.sum(trial_rows**2, axis=-1)
        better = trial_cost <= cost
        bends[better], rows[better], cost[better] = trial[better], trial_rows[better], \
            trial_cost[better]
        damping = np.where(better, damping * 0.1, damping * 10.0).clip(1e-12, 1e6)
        if np.max(np.abs(step)) < BEND_TOLERANCE:
            break
    return bends


@dataclass
class ProjectedProblem:
    """The calibration's least squares in ``z`` with the bends eliminated (module docstring).

    Attributes:
        layout: where each shared unknown sits.
        measured: ``(N, S, 4, 4)`` measured ``base-marker_T_end-marker``.
        sigmas: position (metres) and angle (radians) noise of the pose rows.
        prior: zero-mean prior sigmas of the offsets, rotation (radians) and translation
            (metres).
        bends: the bends of the last ``z`` evaluated (the next solve starts there).
    """

    layout: Layout
    measured: FloatArray
    sigmas: tuple[float, float]
    prior: tuple[float, float]
    bends: FloatArray

    def __post_init__(self) -> None:
        self._cache: tuple[bytes, FloatArray] | None = None

    def rows_of(self, z: FloatArray) -> Callable[[FloatArray], FloatArray]:
        """bends -> ``(N, S, 6)`` pose rows at this ``z``."""
        return lambda bends: pose_rows(self.layout, z, bends, self.measured, self.sigmas)

    def solve_bends(self, z: FloatArray) -> FloatArray:
        """``b*(z)``, cached for the Jacobian at the same ``z``."""
        key = np.asarray(z, dtype=float).tobytes()
        if self._cache is None or self._cache[0] != key:
            self.bends = best_bends(self.rows_of(z), self.bends)
            self._cache = (key, self.bends.copy())
        return self._cache[1]

    def prior_rows(self, z: FloatArray) -> FloatArray:
        """The offsets' prior, whitened."""
        return z[self.layout.n_globals:] / self.layout.offset_scales(self.prior)

    def residuals(self, z: FloatArray) -> FloatArray:
        """Projected residuals: the pose rows at ``b*(z)``, raveled, then the prior rows."""
        rows = self.rows_of(z)(self.solve_bends(z))
        return np.concatenate([rows.ravel(), self.prior_rows(z)])

    def jacobian(self, z: FloatArray) -> FloatArray:
        """``d residuals / dz`` by the projection formula (module docstring)."""
        bends = self.solve_bends(z)
        rows = self.rows_of(z)(bends)
        jb = _pose_jacobian(self.rows_of(z), bends, rows)  # (N, S, 6, 2)
        jz = np.empty((*rows.shape, self.layout.size))
        for j in range(self.layout.size):
            step = np.zeros(self.layout.size)
            step[j] = STEP
            jz[..., j] = (self.rows_of(z + step)(bends) - rows) / STEP
        normal = np.einsum("...ri,...rj->...ij", jb, jb)
        coupling = np.einsum("...ri,...rj->...ij", jb, jz)
        projected = jz - np.einsum("...ri,...ij->...rj", jb,
                                   np.linalg.solve(normal + 1e-12 * np.eye(2), coupling))
        prior = np.zeros((self.layout.n_offsets, self.layout.size))
        prior[:, self.layout.n_globals:] = np.diag(1.0 / self.layout.offset_scales(self.prior))
        return np.vstack([projected.reshape(-1, self.layout.size), prior])

    def solve(self, z0: FloatArray) -> scipy.optimize.OptimizeResult:
        """scipy's trust-region least squares on ``z`` within :meth:`Layout.bounds`."""
        lower, upper = self.layout.bounds(self.prior, OFFSET_REACH)
        return scipy.optimize.least_squares(
            self.residuals, np.clip(z0, lower, upper), jac=self.jacobian, bounds=(lower, upper),
            method="trf", x_scale="jac", xtol=1e-9, ftol=1e-10, gtol=1e-10, max_nfev=100)
