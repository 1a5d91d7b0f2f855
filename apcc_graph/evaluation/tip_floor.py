"""Tip errors on real motion, and the floor beside them (docs/estimation.md, "Replaying a real
robot's motion").

A real robot is not its model, so on real motion no estimator reaches zero tip error. The floor is
what the model itself can do: for each frame, the bending vectors that place the model's segment
ends closest to the measured ones (least squares over the positions of all segment ends, the chain
composed from the base as the estimators compose it). The RMS tip error of those model tips is the
best any estimator with that model can do on tip position; estimated tips are compared with the
measured tips beside it. On model-exact data the floor is zero. The rotation floor
(:func:`rotation_floor`) fits the tips' orientations instead: what tip cameras measure well.

Tip errors: the position error (metres) of each segment end, and its tangent error, the angle
between the estimated and measured backbone tangents (the z axes; radians).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial.transform import Rotation

from apcc_graph.calibration.backbone_model import initial_bends, rigid_inverse, tangent_angles
from apcc_graph.calibration.backbone_solve import best_bends
from apcc_graph.model.arrays import FloatArray, rms
from apcc_graph.model.robot import Robot

FLOOR_SIGMA = 1e-3
"""Scale of the floor's position rows (metres); it does not change the least-squares answer."""


@dataclass(frozen=True)
class TipErrors:
    """Per frame and segment end: position error (metres) and tangent error (radians)."""

    position: FloatArray
    tangent: FloatArray

    @property
    def rms_position(self) -> FloatArray:
        """``(S,)`` RMS position error per segment end (metres)."""
        return rms(self.position, axis=0)

    @property
    def rms_tangent(self) -> FloatArray:
        """``(S,)`` RMS tangent error per segment end (radians)."""
        return rms(self.tangent, axis=0)


def tip_errors(estimated: ArrayLike, measured: ArrayLike) -> TipErrors:
    """Errors of ``(F, S, 4, 4)`` estimated tips against the measured ones.

    Raises:
        ValueError: the shapes differ.
    """
    est, ref = np.asarray(estimated, dtype=float), np.asarray(measured, dtype=float)
    if est.shape != ref.shape or est.shape[-2:] != (4, 4):
        raise ValueError(f"estimated tips {est.shape} and measured tips {ref.shape}: expected "
                         "the same (F, S, 4, 4)")
    return TipErrors(np.linalg.norm(est[..., :3, 3] - ref[..., :3, 3], axis=-1),
                     tangent_angles(est, ref))


@dataclass(frozen=True)
class TipFloor:
    """The model's best fit to measured tips, frame by frame.

    Attributes:
        bends: ``(F, S, 2)`` bending vectors ``theta (cos psi, sin psi)`` (radians).
        tips: ``(F, S, 4, 4)`` the model's segment ends at those bends.
        errors: their errors against the measured tips (the floor).
    """

    bends: FloatArray
    tips: FloatArray
    errors: TipErrors

    @property
    def thetas(self) -> FloatArray:
        """``(F, S)`` bending angles (radians, >= 0)."""
        return np.linalg.norm(self.bends, axis=-1)

    @property
    def psis(self) -> FloatArray:
        """``(F, S)`` bending-plane angles (radians)."""
        return np.arctan2(self.bends[..., 1], self.bends[..., 0])


def _forward(robot: Robot, bends: FloatArray, world_T_base: FloatArray | None) -> FloatArray:
    theta, psi = np.linalg.norm(bends, axis=-1), np.arctan2(bends[..., 1], bends[..., 0])
    return robot.forward(theta, psi, world_T_base)


def _fit(robot: Robot, measured: ArrayLike, world_T_base: ArrayLike | None,
         rows: Callable[[FloatArray, FloatArray], FloatArray]) -> TipFloor:
    """Per frame, the bends minimising ``rows(model tips, measured tips)`` (``(F, k)``)."""
    tips = np.asarray(measured, dtype=float)
    n_frames, n_seg = tips.shape[:2]
    base = None if world_T_base is None else np.asarray(world_T_base, dtype=float)
    chain = np.concatenate([np.broadcast_to(np.eye(4) if base is None else base[:, None],
                                            (n_frames, 1, 4, 4)), tips[:, :-1]], axis=1)
    start = initial_bends(rigid_inverse(chain) @ tips).reshape(n_frames, 1, 2 * n_seg)

    def rows_of(flat: FloatArray) -> FloatArray:
        model = _forward(robot, flat.reshape(n_frames, n_seg, 2), base)
        return rows(model, tips).reshape(n_frames, 1, -1)

    bends = best_bends(rows_of, start).reshape(n_frames, n_seg, 2)
    model = _forward(robot, bends, base)
    return TipFloor(bends, model, tip_errors(model, tips))


def tip_floor(robot: Robot, measured: ArrayLike, world_T_base: ArrayLike | None = None
              ) -> TipFloor:
    """The floor of ``robot`` on ``(F, S, 4, 4)`` measured tips (module docstring).

    Args:
        robot: the model (its calibrated segments).
        measured: measured ``world_T_tip`` of every segment end.
        world_T_base: ``(F, 4, 4)`` base poses, or ``None`` for the fixed base at the origin.
    """
    return _fit(robot, measured, world_T_base,
                lambda model, tips: (model[..., :3, 3] - tips[..., :3, 3]) / FLOOR_SIGMA)


def rotation_floor(robot: Robot, measured: ArrayLike, world_T_base: ArrayLike | None = None
                   ) -> TipFloor:
    """The model's best fit to the measured tips' *orientations*, frame by frame.

    A tip camera measures its own rotation far better than its position (over a short baseline a
    narrow camera's translation trades off against its rotation), so an estimator that trusts
    the images places each segment where the model's tip rotations match the measured ones.
    Where the model misses the measured ends, those bends place the tips further from the
    measured positions than the (position) floor of :func:`tip_floor`: the RMS tip error at
    them is what a camera-based estimator with this model can be expected to reach. Arguments
    as :func:`tip_floor`; the rows are the rotation vectors of ``model_R^T measured_R``.
    """
    def rows(model: FloatArray, tips: FloatArray) -> FloatArray:
        rel = np.swapaxes(model[..., :3, :3], -1, -2) @ tips[..., :3, :3]
        return Rotation.from_matrix(rel.reshape(-1, 3, 3)).as_rotvec().reshape(
            rel.shape[:-2] + (3,))

    return _fit(robot, measured, world_T_base, rows)
