"""How far a real segment departs from its APCC model, as its calibration measured it
(``docs/estimation.md``, "Model error from the calibration").

A real segment is only approximately APCC: at the bend that best fits it, its end is still a
few millimetres and a degree or two from where the model puts it. :class:`ModelError` is the
size of that departure, per axis of the segment end's pose in its own frame (the convention of
the kinematic tie, :func:`~apcc_graph.factors.kinematic.segment_tie_factor`: rotation, then
translation). The backbone calibration measures it (:mod:`apcc_graph.calibration.model_error`)
and ``robot.toml`` carries it (``[segments.model_error]``, docs/formats.md); the batch and the
smoother then use it as the model's noise by default (:mod:`apcc_graph.estimation.model_noise`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

NEGLIGIBLE = (2.5e-4, math.radians(0.15))
"""A departure below both (position m, rotation rad per component) is zero: about a pixel of a
tip camera (f = 500 px: 0.115 deg a pixel), and above what re-fitting a model-exact motion
measures (0.1 mm, 0.1 deg)."""

@dataclass(frozen=True)
class ModelError:
    """One segment's measured departure from its model (metres, radians, seconds).

    Attributes:
        position: standard deviation of each component of the segment end's position departure
            (metres), the part that persists from sample to sample: the model's error, not the
            measurement's noise.
        rotation: the same for each component of its rotation departure (radians).
        correlation_time: how long the departure takes to change: the lag at which its
            autocorrelation falls below ``1/e`` (seconds); ``None`` when not measured.
        measured: how it was measured (the method, the source, the number of samples).
        correlation_bend: how far the robot's bends move before the departure changes: the
            distance between two samples' frame vectors (radians; every segment's bend)
            at which the departures' correlation falls below ``1/e``; ``None`` when not
            measured. A segment's departure from its model is a function of the robot's
            shape, so this, not time, is what the estimator's drifting tie uses.
    """

    position: float
    rotation: float
    correlation_time: float | None = None
    measured: str = ""
    correlation_bend: float | None = None

    def __post_init__(self) -> None:
        for name in ("position", "rotation"):
            value = float(getattr(self, name))
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"ModelError.{name} = {getattr(self, name)!r}: expected a "
                                 "finite value >= 0")
            object.__setattr__(self, name, value)
        if self.correlation_time is not None:
            tau = float(self.correlation_time)
            if not (math.isfinite(tau) and tau > 0.0):
                raise ValueError(f"ModelError.correlation_time = {self.correlation_time!r}: "
                                 "expected a finite value > 0 (seconds) or None")
            object.__setattr__(self, "correlation_time", tau)
        if self.correlation_bend is not None:
            length = float(self.correlation_bend)
            if not (math.isfinite(length) and length > 0.0):
                raise ValueError(f"ModelError.correlation_bend = {self.correlation_bend!r}: "
                                 "expected a finite value > 0 (radians) or None")
            object.__setattr__(self, "correlation_bend", length)

    @property
    def is_zero(self) -> bool:
        """Whether the calibration found no departure beyond its measurement noise."""
        return self.position == 0.0 and self.rotation == 0.0

    def describe(self) -> str:
        """``"1.81 mm, 0.93 deg, changing over 2.1 s and 8.3 deg of bend"`` (what a report
        prints)."""
        text = f"{self.position * 1e3:.2f} mm, {math.degrees(self.rotation):.2f} deg"
        over = []
        if self.correlation_time is not None:
            over.append(f"{self.correlation_time:.2g} s")
        if self.correlation_bend is not None:
            over.append(f"{math.degrees(self.correlation_bend):.2g} deg of bend")
        if over:
            text += ", changing over " + " and ".join(over)
        return text
