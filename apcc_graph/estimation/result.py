"""The result of an estimator: angles per frame and segment, their uncertainty, tip poses."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from apcc_graph.model.arrays import FloatArray, rms
from apcc_graph.model.robot import Robot

if TYPE_CHECKING:
    from apcc_graph.estimation.model_fit import ModelFit


@dataclass(frozen=True)
class StartReport:
    """Where an estimator found the robot to start, when it was not told.

    Attributes:
        theta0: ``(S,)`` the configuration at frame 0 (radians).
        sigma0: ``(S,)`` its marginal standard deviations from the window searched (radians).
        seconds: the length of that window (seconds).
        n_frames: its frames.
        hypotheses: starting hypotheses refined.
        psi0: for a robot estimated as spatial, ``(S,)`` the bending planes at frame 0
            (radians; ``theta0`` are then the bends' magnitudes, and ``sigma0`` the sigma of
            each bending vector along its worst-determined direction); ``None`` otherwise.
    """

    theta0: FloatArray
    sigma0: FloatArray
    seconds: float
    n_frames: int
    hypotheses: int
    psi0: FloatArray | None = None


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
        mount_sigmas: with mount calibration, ``(S, 6)`` marginal standard deviations of each
            segment's camera mounting (rotations about the camera's x, y, z in radians, then
            translations along them in metres; NaN where a segment's mount was not
            estimated); ``robot`` then holds the calibrated mounts. ``None`` otherwise.
        start: when no starting configuration was given, where the estimator found the
            robot to start (:class:`StartReport`); ``None`` otherwise.
        psis: for a robot estimated as spatial, ``(F, S)`` bending-plane angles in
            ``(-pi, pi]`` (radians); ``thetas`` are then the bends' magnitudes ``>= 0``
            (:mod:`~apcc_graph.model.bending`). ``None`` for a planar estimate.
        psi_sigmas: ``(F, S)`` standard deviations of ``psis`` to first order (radians; they
            grow like ``1 / theta`` toward straight, where the bending plane is undefined, and
            are ``inf`` at exactly straight; NaN where the method gives none), or ``None``.
        model_fit: the residual test of the estimate (:mod:`~apcc_graph.estimation.
            model_fit`: does the kinematic model explain the images?), for the batch and the
            smoother through :func:`apcc_graph.estimate`; ``None`` when it was not run.
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
    mount_sigmas: FloatArray | None = field(default=None, repr=False)
    start: StartReport | None = field(default=None, repr=False)
    psis: FloatArray | None = field(default=None, repr=False)
    psi_sigmas: FloatArray | None = field(default=None, repr=False)
    model_fit: ModelFit | None = field(default=None, repr=False)

    @property
    def n_frames(self) -> int:
        """Number of frames."""
        return len(self.timestamps)

    @property
    def spatial(self) -> bool:
        """Whether the estimate has bending planes (a robot estimated as spatial)."""
        return self.psis is not None

    def world_T_tip(self) -> FloatArray:
        """``(F, S, 4, 4)`` tip poses of every segment from the estimated angles (and bending
        planes)."""
        return self.robot.forward(self.thetas, self.psis, world_T_base=self.world_T_base)

    def errors(self, truth: FloatArray, truth_psis: FloatArray | None = None) -> FloatArray:
        """``(F, S)`` estimate minus truth (radians). For a spatial estimate, the length of
        the bending-vector error ``|b - b_true|`` (``truth_psis`` required; ``None`` counts
        as planar truth, ``psi = 0``)."""
        truth = np.asarray(truth, dtype=float)
        if self.psis is None:
            return self.thetas - truth
        true_psis = np.zeros_like(truth) if truth_psis is None else np.asarray(truth_psis)
        du = self.thetas * np.cos(self.psis) - truth * np.cos(true_psis)
        dv = self.thetas * np.sin(self.psis) - truth * np.sin(true_psis)
        return np.hypot(du, dv)

    def rms(self, truth: FloatArray, truth_psis: FloatArray | None = None) -> FloatArray:
        """``(S,)`` RMS error per segment against ground truth (radians); of the bending
        vector for a spatial estimate (:meth:`errors`)."""
        return rms(self.errors(truth, truth_psis))

    def bend_sigmas(self) -> FloatArray:
        """``(F, S)`` standard deviation of each bend (radians): ``sigmas`` for a planar
        estimate; for a spatial one, of the bending vector, ``sqrt(sigma_theta^2 + theta^2
        sigma_psi^2)`` (the trace of its covariance, to first order)."""
        if self.psis is None or self.psi_sigmas is None:
            return self.sigmas
        finite = np.isfinite(self.psi_sigmas)
        across = self.thetas * np.where(finite, self.psi_sigmas, 0.0)
        # Exactly straight: sigmas holds the larger axis; the other is at most as large.
        return np.where(finite, np.hypot(self.sigmas, across), np.sqrt(2.0) * self.sigmas)
