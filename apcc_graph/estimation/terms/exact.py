"""The exact model: every observation projected through the model's camera pose, each track's
point eliminated inside the projection factors (:class:`~apcc_graph.estimation.graph.CameraTerms`),
graduated non-convexity of the outlier decisions; optionally self-calibrating the segment models
and camera mounts (``docs/estimation.md``).
"""

from __future__ import annotations

import gtsam
import numpy as np
from numpy.typing import NDArray

from apcc_graph.estimation.graph import (
    CameraTerms,
    calibration_factors,
    camera_chain,
    mount_factors,
    observed_cameras,
    thetas_from,
    values_from,
)
from apcc_graph.estimation.model_calibration import ModelCalibration
from apcc_graph.estimation.options import GraphOptions, Robustness
from apcc_graph.estimation.robust import gnc_start
from apcc_graph.factors.keys import frame_key
from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.parameterisation import Bending
from apcc_graph.model.robot import Robot
from apcc_graph.model.sequence import Sequence

__all__ = ["ExactTerms", "build_terms"]


def build_terms(sequence: Sequence, options: GraphOptions, bending: Bending | None = None,
                calibrate: bool = False, mounts: bool = False) -> list[CameraTerms]:
    """The projection terms of every camera of the sequence that has tracks, over frame
    vectors of ``bending`` (default: the planar robot's fixed planes); with ``calibrate`` and
    ``mounts`` they also depend on the segment models and each camera's mounting. The
    sequence's ``psis`` are ground truth, which no estimator reads."""
    bending = Bending.fixed(sequence.robot.segments) if bending is None else bending
    return [CameraTerms(obs, camera_chain(sequence.robot, obs.camera, bending,
                                          sequence.world_T_base),
                        bending.dim, options.frames_per_chunk, calibrate, mounts)
            for obs in observed_cameras(sequence, options)]


class ExactTerms:
    """The batch's terms of the exact model (module docstring); ``calibration_sigmas`` (k,
    radians) and ``mount_sigmas`` (radians, metres), when given, self-calibrate with priors of
    these standard deviations (:func:`~apcc_graph.estimation.graph.calibration_factors`)."""

    stage_iterations = None
    diagonal_damping = False

    def __init__(self, robot: Robot, options: GraphOptions, bending: Bending,
                 calibration_sigmas: tuple[float, float] | None = None,
                 mount_sigmas: tuple[float, float] | None = None) -> None:
        self.robot, self.options, self.bending = robot, options, bending
        self.sigmas = calibration_sigmas, mount_sigmas
        self.terms: list[CameraTerms] = []
        self.calibration: ModelCalibration | None = None
        self._factors: list[gtsam.NonlinearFactor] = []
        self.n_frames = 0

    def start(self, sequence: Sequence, x: FloatArray, robustness: Robustness) -> list[float]:
        """Build the terms of ``sequence``, triangulate every track robustly at ``x`` and set
        the first stage's weights; returns the GNC stages before the truncated quadratic
        (``robustness.schedule``, else :func:`~apcc_graph.estimation.robust.gnc_start` fitted
        to the residuals at ``x``)."""
        (segments, mounts), self.n_frames = self.sigmas, sequence.n_frames
        self.terms = build_terms(sequence, self.options, self.bending, segments is not None,
                                 mounts is not None)
        cameras = [t.camera for t in self.terms] if mounts is not None else []
        cal = ModelCalibration.of(self.robot, segments is not None, cameras)
        self.calibration = None if cal.empty else cal
        self._factors = ([] if segments is None else calibration_factors(self.robot, segments))
        self._factors += [] if mounts is None else mount_factors(self.robot, cameras, mounts)
        self._factors += [factor for t in self.terms for factor in t.factors()]
        for t in self.terms:
            t.measure(np.asarray(x, dtype=float), robust=True)
        schedule = (list(robustness.schedule) if robustness.schedule is not None else
                    gnc_start(np.concatenate([n for t in self.terms for n in t.norms] or [[]]),
                              robustness.inlier_sigmas))
        self.set_weights(robustness.inlier_sigmas, schedule[0])
        return schedule[:-1]

    def factors(self) -> list[gtsam.NonlinearFactor]:
        """The calibration and mount priors, then every camera's projection factors."""
        return self._factors

    def values(self, x: FloatArray) -> tuple[gtsam.Values, gtsam.Ordering]:
        """The frame vectors ``x`` and the calibrated parameters; frames in time order (the
        graph is banded), then the calibration, which every camera's factors share."""
        values = values_from(x, range(self.n_frames))
        cal = [] if self.calibration is None else self.calibration.keys()
        if self.calibration is not None:
            self.calibration.insert(values)
        return values, gtsam.Ordering([frame_key(f) for f in range(self.n_frames)] + cal)

    def measure(self, values: gtsam.Values) -> None:
        """Take the calibration of the solution ``values``; every residual there."""
        if self.calibration is not None:
            self.calibration = self.calibration.read(values)
        cal, x = self.calibration, thetas_from(values, range(self.n_frames))
        segments = None if cal is None else cal.segment_models(self.robot)
        for t in self.terms:
            t.measure(x, segments=segments, tip_T_cam=None if cal is None else cal.mount(t.camera))

    def set_weights(self, threshold: float, mu: float) -> int:
        """GNC weights of the last residuals; returns how many rows changed side."""
        return sum(t.set_weights(threshold, mu) for t in self.terms)

    def decisions(self) -> tuple[NDArray[np.int64], int, int]:
        """``(F, S)`` inliers per frame and camera, outliers (weight <= 1/2), observations."""
        inliers = np.zeros((self.n_frames, self.robot.n_segments), dtype=np.int64)
        for t in self.terms:
            inliers[:, t.camera] = t.inliers_per_frame(self.n_frames)
        return (inliers, sum(t.outlier_rows() for t in self.terms),
                sum(len(c.obs) for t in self.terms for c in t.chunks))
