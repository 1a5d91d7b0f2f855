"""The Cramer-Rao bound of the segment ends' positions: the angles' bound through the kinematics.

An estimator reports angles; a user of a continuum robot cares where its segment ends are. For
any unbiased estimator of a frame's vector ``x_f`` (the robot's parameterisation: angles, or
bending vectors ``(u, v)`` per segment) with covariance at least ``C_f``, the position
``p_j(x_f)`` of segment j's end has a covariance at least ``J C_f J^T`` (``J = dp_j / dx_f``
at the truth; the bound of a function of the parameters), so its error norm has an RMS of at
least ``sqrt(trace(J C_f J^T))``. ``C_f`` is the ``f`` block of the inverse Fisher information
(:func:`~apcc_graph.evaluation.sequence_bound.fisher_information`):

- of the whole recording: the bound of a batch (every frame seen);
- of the observations up to ``f + lag_frames``: the bound of a fixed-lag smoother's final
  estimate of ``f`` (:func:`~apcc_graph.evaluation.sequence_bound.lag_bound`).

Units: metres; ``J`` by central differences of :meth:`apcc_graph.model.robot.Robot.forward`
(step :data:`STEP` radians) with the base fixed (as the simulations here have it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.linalg
from numpy.typing import NDArray

from apcc_graph.evaluation.sequence_bound import fisher_information, true_parameters
from apcc_graph.model.arrays import FloatArray, rms
from apcc_graph.model.parameterisation import Bending
from apcc_graph.model.robot import Robot
from apcc_graph.simulation.simulator import Simulation

STEP = 1e-6
"""Radians: the central-difference step of the ends' Jacobian."""


@dataclass(frozen=True)
class TipBound:
    """The bound of each segment end's position error at sampled frames.

    Attributes:
        frames: ``(K,)`` the sampled frames.
        sigmas: ``(K, S)`` the smallest RMS position error (metres) of segment j's end an
            unbiased estimator can have at that frame.
        lag_frames: the lag in frames (``None``: the whole recording's bound).
    """

    frames: NDArray[np.int64]
    sigmas: FloatArray
    lag_frames: int | None

    def rms(self) -> FloatArray:
        """``(S,)`` RMS over the sampled frames (metres): the figure beside an estimator's RMS
        tip error."""
        return rms(self.sigmas)


def end_jacobians(robot: Robot, bending: Bending, x: FloatArray) -> FloatArray:
    """``(S, 3, dim)``: the derivatives of every segment end's position at frame vector ``x``
    ``(dim,)`` of ``bending`` in ``x`` (central differences, the base fixed)."""
    x = np.asarray(x, dtype=float)
    steps = np.eye(len(x)) * STEP
    ahead, behind = _ends(robot, bending, x + steps), _ends(robot, bending, x - steps)
    return np.transpose((ahead - behind) / (2.0 * STEP), (1, 2, 0))  # from (dim, S, 3)


def _ends(robot: Robot, bending: Bending, xs: FloatArray) -> FloatArray:
    """``(N, S, 3)`` the segment ends' positions of frame vectors ``(N, dim)``."""
    thetas, psis = bending.polar(xs)
    if psis is None and bending.planes is not None:
        psis = np.broadcast_to(bending.planes, thetas.shape)
    return robot.forward(thetas, psis)[..., :3, 3]


def tip_bound(simulation: Simulation, noise_px: float, theta0_sigma: float | None,
              lag_frames: int | None = None, step: int = 10, spatial: bool = False
              ) -> TipBound:
    """The bound of every segment end's position at frames ``0, step, 2 step, ...``.

    Args:
        simulation: the simulated recording and its truth.
        noise_px: the pixel noise (pixels).
        theta0_sigma: the start prior (radians, on each component of frame 0's vector), or
            ``None``.
        lag_frames: a fixed-lag smoother's lag in frames; ``None``: the whole recording (a
            batch).
        step: sample every ``step``-th frame.
        spatial: the robot's bending planes are unknowns (bending vectors).

    Raises:
        ValueError: ``step < 1`` or ``lag_frames < 0``.
    """
    if step < 1 or (lag_frames is not None and lag_frames < 0):
        raise ValueError(f"step = {step!r}, lag_frames = {lag_frames!r}: expected step >= 1 "
                         "and lag_frames >= 0")
    seq = simulation.sequence
    segments = seq.robot.segments
    bending = Bending.free(segments) if spatial else Bending.fixed(segments)
    P, n_frames = bending.dim, seq.n_frames
    truth = true_parameters(simulation, spatial).reshape(n_frames, P)
    frames = np.arange(0, n_frames, step, dtype=np.int64)
    whole = None
    sigmas = np.full((len(frames), len(segments)), math.inf)
    if lag_frames is None:
        try:
            whole = scipy.linalg.cholesky(fisher_information(
                simulation, noise_px, theta0_sigma, spatial=spatial), lower=False,
                check_finite=False)
        except np.linalg.LinAlgError:
            return TipBound(frames, sigmas, None)  # some frame is undetermined: inf
    for i, f in enumerate(frames.tolist()):
        if whole is not None:
            U = whole
        else:
            last = min(f + lag_frames, n_frames - 1)  # type: ignore[operator]
            info = fisher_information(simulation, noise_px, theta0_sigma, spatial=spatial,
                                      last_frame=last)[:(last + 1) * P, :(last + 1) * P]
            try:
                U = scipy.linalg.cholesky(info, lower=False, check_finite=False)
            except np.linalg.LinAlgError:
                continue  # some frame up to f is undetermined: inf
        unit = np.zeros((len(U), P))
        unit[f * P + np.arange(P), np.arange(P)] = 1.0
        z = scipy.linalg.solve_triangular(U, unit, trans="T", check_finite=False)
        C = z.T @ z  # the f block of info^-1
        J = end_jacobians(seq.robot, bending, truth[f])
        sigmas[i] = np.sqrt(np.maximum(np.einsum("sik,kl,sil->s", J, C, J), 0.0))
    return TipBound(frames, sigmas, lag_frames)
