"""Online self-calibration of the epipolar smoother: each segment's k and delta_max as variables.

With ``calibrate=True`` (:class:`~apcc_graph.estimation.smoother_options.EpipolarSmootherOptions`)
the smoother adds, at its first frame (and again after a restart), one ``Vector1`` variable per
segment for k and one for delta_max (radians), each with a prior around the robot's value. They
are never marginalised: every update renews their timestamps. The epipolar factors then take
them as extra keys (:class:`apcc_graph.factors.epipolar.EpipolarFrameFactor`,
``calibration_keys``), and the front end works with the segments at the current calibration.

Angle keys are ``frame * S + segment`` (:func:`~apcc_graph.estimation.epipolar_graph.angle_key`),
far below any gtsam ``Symbol`` key, which the calibration keys are.
"""

from __future__ import annotations

from collections.abc import Mapping

import gtsam
import numpy as np

from apcc_graph.estimation.window import Window
from apcc_graph.factors.epipolar import calibrated_segments
from apcc_graph.factors.priors import angle_prior
from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.robot import Robot
from apcc_graph.model.segment import Segment

SYMBOL_KEYS = gtsam.symbol("a", 0)
"""Keys from here up are gtsam Symbols (calibration); below, angle keys."""


def calibration_keys(segment: int) -> tuple[int, int]:
    """The keys of segment ``segment``'s k and delta_max."""
    return gtsam.symbol("k", segment), gtsam.symbol("d", segment)


class OnlineCalibration:
    """The calibration variables of the epipolar smoother, or their absence.

    Args:
        robot: the robot (the priors' means, and the values before the first update).
        sigmas: prior standard deviations of k and delta_max (radians).
        enabled: whether the smoother self-calibrates; otherwise every method answers with the
            robot's segments, ``None`` or nothing.
        window: the smoother's window (its gtsam smoother holds the variables).
    """

    def __init__(self, robot: Robot, sigmas: tuple[float, float], enabled: bool,
                 window: Window) -> None:
        self.robot = robot
        self.sigmas = sigmas
        self.enabled = enabled
        self.window = window

    def factor_keys(self, camera: int) -> list[tuple[int, int]] | None:
        """The calibration keys of segments ``0..camera`` for an epipolar factor, or ``None``."""
        if not self.enabled:
            return None
        return [calibration_keys(j) for j in range(camera + 1)]

    def add(self, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values,
            start: FloatArray | None = None) -> None:
        """k and delta_max variables with priors around the robot's values, starting at
        ``start`` (``(S, 2)``, after a restart) or at the robot's values."""
        sk, sd = self.sigmas
        for i, seg in enumerate(self.robot.segments):
            k_key, d_key = calibration_keys(i)
            k0, d0 = (seg.k, seg.delta_max) if start is None else start[i]
            values.insert(k_key, np.array([k0]))
            values.insert(d_key, np.array([d0]))
            graph.add(angle_prior(k_key, seg.k, sk))
            graph.add(angle_prior(d_key, seg.delta_max, sd))

    def stamps(self, stamp: float) -> list[tuple[int, float]]:
        """``(key, stamp)`` for every calibration variable (renewed: never marginalised)."""
        if not self.enabled:
            return []
        return [(key, stamp) for i in range(self.robot.n_segments)
                for key in calibration_keys(i)]

    def current(self) -> FloatArray | None:
        """``(S, 2)`` current k and delta_max, or ``None`` without self-calibration."""
        if not self.enabled:
            return None
        est = self.window.smoother.calculateEstimate()
        return np.array([[est.atVector(key)[0] for key in calibration_keys(i)]
                         for i in range(self.robot.n_segments)])

    def as_mapping(self) -> Mapping[int, tuple[float, float]] | None:
        """``{segment: (k, delta_max)}``, or ``None`` without self-calibration."""
        now = self.current()
        if now is None:
            return None
        return {i: (float(k), float(d)) for i, (k, d) in enumerate(now)}

    def segments(self) -> tuple[Segment, ...]:
        """The segments with the current calibration (the robot's before the first update)."""
        if not self.enabled or self.window.count == 0:
            return self.robot.segments
        keys = [calibration_keys(i) for i in range(self.robot.n_segments)]
        return tuple(calibrated_segments(self.robot.segments,
                                         self.window.smoother.calculateEstimate(), keys))

    def value(self, key: int) -> float:
        """The current value of one calibration variable (the robot's before the first
        update)."""
        if self.window.count == 0:
            symbol = gtsam.Symbol(key)
            seg = self.robot.segments[symbol.index()]
            return seg.k if chr(symbol.chr()) == "k" else seg.delta_max
        return float(self.window.smoother.calculateEstimateVector(key)[0])
