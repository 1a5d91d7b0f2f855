"""The result of an estimator: angles per frame and segment, their uncertainty, tip poses."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from apcc_graph.model.arrays import FloatArray, rms
from apcc_graph.model.robot import Robot


@dataclass(frozen=True)
class StartReport:
    """Where an estimator found the robot to start, when it was not told.

    Attributes:
        theta0: ``(S,)`` the configuration at frame 0 (radians).
        sigma0: ``(S,)`` its marginal standard deviations from the window searched (radians).
        seconds: the length of that window (seconds).
        n_frames: its frames.
        hypotheses: starting hypotheses refined.
    """

    theta0: FloatArray
    sigma0: FloatArray
    seconds: float
    n_frames: int
    hypotheses: int


@dataclass(frozen=True)
class Estimate:
    """Estimated bending angles of a sequence.

    Attributes:
        method: the estimator (``"chain"``, ``"batch"``, ``"smoother"``).
        robot: the robot model used.
        timestamps: ``(F,)`` seconds.
        thetas: ``(F, S)`` estimated angles (radians).
        sigmas: ``(F, S)`` marginal standard deviations (radians); NaN where the method gives none.
        status: ``(F, S)`` what happened per frame and segment (e.g. ``"ok"``, ``"no-motion"``,
            ``"no-consensus"``, ``"no-camera"``, ``"initial"``).
        inliers: ``(F, S)`` inlier correspondences used (0 where none).
        world_T_base: ``(F, 4, 4)`` base poses if the sequence had them.
        calibration_sigmas: with self-calibration, ``(S, 2)`` marginal standard deviations
            of each segment's k and delta_max (radians); ``robot`` then holds the calibrated
            segments. ``None`` otherwise.
        start: when no starting configuration was given, where the estimator found the
            robot to start (:class:`StartReport`); ``None`` otherwise.
    """

    method: str
    robot: Robot
    timestamps: FloatArray
    thetas: FloatArray
    sigmas: FloatArray
    status: NDArray[np.str_]
    inliers: NDArray[np.int64]
    world_T_base: FloatArray | None = field(default=None, repr=False)
    calibration_sigmas: FloatArray | None = field(default=None, repr=False)
    start: StartReport | None = field(default=None, repr=False)

    @property
    def n_frames(self) -> int:
        """Number of frames."""
        return len(self.timestamps)

    def world_T_tip(self) -> FloatArray:
        """``(F, S, 4, 4)`` tip poses of every segment from the estimated angles."""
        return self.robot.forward(self.thetas, world_T_base=self.world_T_base)

    def errors(self, truth: FloatArray) -> FloatArray:
        """``(F, S)`` estimate minus truth (radians)."""
        return self.thetas - np.asarray(truth, dtype=float)

    def rms(self, truth: FloatArray) -> FloatArray:
        """``(S,)`` RMS error per segment against ground truth (radians)."""
        return rms(self.errors(truth))
