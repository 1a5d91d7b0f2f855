"""The batch's measurement models behind one interface (:class:`MeasurementModel`): the exact
model (:mod:`.exact`) and model error as noise (:mod:`.noisy`); :func:`measurement_model` is the
one place that chooses between them. The batch (:mod:`apcc_graph.estimation.batch_solve`) runs
the same robust Levenberg-Marquardt loop over either. May import: the layers below
:mod:`apcc_graph.estimation`, and from it the graph building, the options, the outlier decisions
and the model calibration; never the batch or the smoother.
"""

from __future__ import annotations

from typing import Protocol

import gtsam
import numpy as np
from numpy.typing import NDArray

from apcc_graph.estimation.model_calibration import ModelCalibration
from apcc_graph.estimation.model_noise import ROBOT, segment_sigmas
from apcc_graph.estimation.options import GraphOptions, Robustness
from apcc_graph.estimation.terms.exact import ExactTerms
from apcc_graph.estimation.terms.noisy import NoisyTerms
from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.parameterisation import Bending
from apcc_graph.model.robot import Robot
from apcc_graph.model.sequence import Sequence


class MeasurementModel(Protocol):
    """What a batch's graph adds for the observations of one sequence, and how it decides
    outliers: ``start`` binds the sequence and decides first; each stage solves the priors on
    the frame vectors plus ``factors()`` from ``values(x)``, then ``measure``s the residuals at
    the solution, from which the next stage's ``set_weights`` decide."""

    calibration: ModelCalibration | None  # the self-calibration at the last solution
    stage_iterations: int | None  # most Levenberg-Marquardt iterations a stage (None: the caller's)
    diagonal_damping: bool  # Levenberg-Marquardt damps by the information's diagonal

    def start(self, sequence: Sequence, x: FloatArray, robustness: Robustness) -> list[float]:
        """First decisions at ``x``; returns the stages (``mu``) before the residual rounds."""

    def factors(self) -> list[gtsam.NonlinearFactor]:
        """The factors of the observations and the model's own variables."""

    def values(self, x: FloatArray) -> tuple[gtsam.Values, gtsam.Ordering | None]:
        """The frame vectors ``x`` and the model's own variables at their last values, and
        their elimination order (``None``: gtsam's)."""

    def measure(self, values: gtsam.Values) -> None:
        """Take the model's own variables from the solution ``values``; residuals there."""

    def set_weights(self, threshold: float, mu: float) -> int:
        """Decisions from the last residuals; returns how many changed side."""

    def decisions(self) -> tuple[NDArray[np.int64], int, int]:
        """``(F, S)`` inliers per frame and camera; outliers; all observations."""


def measurement_model(robot: Robot, options: GraphOptions, bending: Bending,
                      calibration_sigmas: tuple[float, float] | None = None,
                      mount_sigmas: tuple[float, float] | None = None) -> MeasurementModel:
    """The exact model when ``options.model_sigma`` names none
    (:func:`~apcc_graph.estimation.model_noise.segment_sigmas`), else model error as noise.
    Self-calibration (``calibration_sigmas``, ``mount_sigmas``: :class:`ExactTerms`) fits the
    model itself, so it runs the exact model whatever the robot file says; with an explicit
    noise it is a ValueError."""
    self_calibrating = calibration_sigmas is not None or mount_sigmas is not None
    if self_calibrating and options.model_sigma == ROBOT:
        return ExactTerms(robot, options, bending, calibration_sigmas, mount_sigmas)
    sigmas = segment_sigmas(options.model_sigma, robot)
    if sigmas is None:
        return ExactTerms(robot, options, bending, calibration_sigmas, mount_sigmas)
    if self_calibrating:
        raise ValueError("self-calibration (calibrate) needs the exact model: "
                         "GraphOptions.model_sigma = None")
    return NoisyTerms(robot, options, bending, sigmas)
