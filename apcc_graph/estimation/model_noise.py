"""Which model noise an estimator uses: the robot file's by default
(``docs/estimation.md``, "Model error from the calibration").

``GraphOptions.model_sigma`` names it:

- ``"robot"`` (:data:`ROBOT`, the default): each segment's measured departure from its model,
  as the calibration wrote it into ``robot.toml``
  (:attr:`~apcc_graph.model.segment.Segment.model_error`); the exact model when no segment has
  one or every one is zero (a model-exact robot, or a file without them);
- ``None``: the exact model, whatever the robot file says;
- ``(position m, rotation rad)``: the same noise for every segment;
- one such pair per segment.

:func:`segment_sigmas` turns it into what the two measurement models' choosers need
(:func:`~apcc_graph.estimation.terms.measurement_model`,
:func:`~apcc_graph.estimation.smoother.measurement.window_model`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from apcc_graph.model.model_error import NEGLIGIBLE
from apcc_graph.model.robot import Robot

ROBOT = "robot"
"""``GraphOptions.model_sigma``: the robot file's model errors."""
FLOOR = (1e-4, math.radians(0.05))
"""The least model noise (position m, rotation rad) of a segment whose measured error is zero
or missing while another segment's is not: a tie with no noise would be a hard constraint,
which the model-noise graph does not linearise well."""

Pair = tuple[float, float]
ModelSigma = str | Pair | tuple[Pair, ...] | None
"""What ``GraphOptions.model_sigma`` holds (module docstring)."""


def normalised(value: object) -> ModelSigma:
    """``value`` checked and made plain floats; ValueError naming ``GraphOptions.model_sigma``
    and what is expected otherwise."""
    if value is None:
        return None
    expected = (f"GraphOptions.model_sigma = {value!r}: expected {ROBOT!r} (the robot file's "
                "model errors), None (the exact model), (position m, rotation rad) or one such "
                "pair per segment, every value finite and > 0")
    if isinstance(value, str):
        if value == ROBOT:
            return ROBOT
        raise ValueError(expected)
    if hasattr(value, "tolist"):  # a numpy array
        value = value.tolist()
    if not isinstance(value, Sequence):
        raise ValueError(expected)

    def pair(item: object) -> Pair:
        if isinstance(item, str) or not isinstance(item, Sequence) or len(item) != 2:
            raise ValueError(expected)
        try:
            out = (float(item[0]), float(item[1]))
        except (TypeError, ValueError):
            raise ValueError(expected) from None
        if not all(math.isfinite(v) and v > 0.0 for v in out):
            raise ValueError(expected)
        return out

    if len(value) == 2 and not any(isinstance(v, Sequence) for v in value):
        return pair(value)
    if len(value) == 0:
        raise ValueError(expected)
    return tuple(pair(item) for item in value)


def segment_sigmas(model_sigma: ModelSigma, robot: Robot) -> tuple[Pair, ...] | None:
    """Per segment, ``(position m, rotation rad)`` of the model noise, or ``None``: the exact
    model (module docstring).

    Raises:
        ValueError: one pair per segment for a robot of another number of segments.
    """
    if model_sigma is None:
        return None
    if model_sigma == ROBOT:
        errors = [seg.model_error for seg in robot.segments]
        if all(e is None or e.is_zero for e in errors):
            return None
        return tuple((FLOOR if e is None else (max(e.position, FLOOR[0]),
                                                max(e.rotation, FLOOR[1])))
                     for e in errors)
    assert not isinstance(model_sigma, str)
    if isinstance(model_sigma[0], float):
        return (model_sigma,) * robot.n_segments  # type: ignore[return-value]
    if len(model_sigma) != robot.n_segments:
        raise ValueError(f"GraphOptions.model_sigma gives {len(model_sigma)} segments' model "
                         f"noise for a robot of {robot.n_segments} segments")
    return tuple(model_sigma)  # type: ignore[arg-type]


def approximate(sigmas: tuple[Pair, ...] | None) -> bool:
    """Whether a model noise says the model is materially off: some segment's at least the
    negligible size (:data:`~apcc_graph.model.model_error.NEGLIGIBLE`) in position or rotation.
    The batch then starts from the cameras' rotations rather than from the exact chain
    (``BatchOptions.init = "auto"``): on 30 frames of a model-exact replay, a model noise of
    0.01 mm / 0.001 deg ended 0.44 / 0.99 mm off from the chain and 1.8 / 5.9 mm from the
    rotations, whose parallax the graph did not undo; on the real impulse recording the
    rotations won on every stretch."""
    return sigmas is not None and any(p >= NEGLIGIBLE[0] or r >= NEGLIGIBLE[1]
                                      for p, r in sigmas)


def correlation_normalised(value: object) -> str | float:
    """``GraphOptions.model_correlation`` checked: :data:`ROBOT` or radians (finite, >= 0);
    ValueError naming the field and what is expected otherwise."""
    if value == ROBOT:
        return ROBOT
    try:
        tau = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        tau = math.nan
    if isinstance(value, str | bool) or not (math.isfinite(tau) and tau >= 0.0):
        raise ValueError(f"GraphOptions.model_correlation = {value!r}: expected {ROBOT!r} (the "
                         "robot file's correlation lengths) or radians of bend >= 0 (0: an "
                         "independent model error per frame)")
    return tau


def segment_correlations(model_correlation: str | float, robot: Robot) -> tuple[float, ...]:
    """Per segment, how far the bends move before its model error changes (radians of the
    frame vector; 0: independent per frame, the plain ties): ``model_correlation`` for every
    segment, or with :data:`ROBOT` the robot file's measured correlation length (0 where the
    file has none) (:mod:`apcc_graph.factors.drifting_tie`)."""
    if model_correlation != ROBOT:
        return (float(model_correlation),) * robot.n_segments
    return tuple(0.0 if seg.model_error is None or seg.model_error.correlation_bend is None
                 else seg.model_error.correlation_bend for seg in robot.segments)


def tie_sigmas(sigmas: tuple[Pair, ...], segment: int) -> list[float]:
    """The kinematic tie's six sigmas of ``segment`` (rotation, then translation)."""
    position, rotation = sigmas[segment]
    return [rotation] * 3 + [position] * 3


def describe(sigmas: tuple[Pair, ...] | None, correlations: Sequence[float] = ()) -> str:
    """``"the exact model"`` or ``"model error as noise: 1.81 mm / 0.93 deg, ..."``, followed
    by ``", drifting over 12 deg, 15 deg of bend"`` where some segment's ``correlations``
    (radians) is not 0."""
    if sigmas is None:
        return "the exact model"
    text = "model error as noise: " + ", ".join(
        f"{p * 1e3:.2f} mm / {math.degrees(r):.2f} deg" for p, r in sigmas)
    if any(correlations):
        text += (", drifting over " + ", ".join(f"{math.degrees(c):.2g} deg" for c in correlations)
                 + " of bend")
    return text
