"""What a user sets for an estimator: one frozen, validated record per concern.

- :class:`GraphOptions`, the measurement model: the pixel noise, the priors (start, motion,
  joint limits) and how tracks enter the graph; shared by every estimator;
- :class:`Robustness`: how outliers are decided (the inlier threshold, the batch's graduated
  non-convexity) and when the residual test says the model does not explain the images;
- one record per method: :class:`ChainOptions`, :class:`BatchOptions` and
  :class:`~apcc_graph.estimation.smoother_options.SmootherOptions`.

:func:`apcc_graph.estimate` takes them by name; a misspelled field is refused by the record.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

from apcc_graph.estimation.image_motion import STILL_TICK
from apcc_graph.estimation.model_calibration import MOUNT_SIGMAS
from apcc_graph.estimation.model_noise import ROBOT, ModelSigma, correlation_normalised, normalised


@dataclass(frozen=True)
class GraphOptions:
    """The measurement model: how the factor graph is built (every estimator).

    Attributes:
        threshold_px: the pixel noise, standard deviation per coordinate (pixels).
        theta0_sigma: prior standard deviation of the starting configuration (radians).
        motion_sigma: random-walk prior between consecutive frames (rad/sqrt(s)); ``None``
            leaves it out. Weak by default (5 deg between frames at 30 fps): it only carries
            frames the cameras do not constrain.
        limit_sigma: softness of the joint limits (radians).
        frames_per_chunk: tracks starting within this many frames of each other share one
            gtsam factor (one Python callback per chunk and linearisation).
        min_track_rows: tracks seen in fewer frames are left out (one observation of an
            unknown point carries no information; two carry one number).
        max_track_frames: longer tracks are cut into pieces of this many frames, each with a
            point of its own, so that no factor spans more frames than this (its dense block
            grows with the square of its span); ``None`` keeps whole tracks.
        still_tick: what a frame in which no camera's images moved counts towards
            ``max_track_frames`` (a moving frame counts 1): a piece born while the robot
            stands still lasts until it has moved, so that its point has parallax
            (:func:`apcc_graph.estimation.image_motion.motion_clock`); ``None`` counts every
            frame as 1.
        model_sigma: how far a real segment's tip may depart from its kinematic model, the
            standard deviation of each component of the tip pose's departure in the tip's
            frame (docs/estimation.md, "Model error as noise"). ``"robot"`` (default): each
            segment's model error as the calibration wrote it into the robot file, and the
            exact model where the file has none (or zero); ``None``: the exact model, every
            observation projected through the model's camera poses, whatever the file says;
            ``(position in metres, rotation in radians)``: that noise for every segment; or
            one such pair per segment (:mod:`apcc_graph.estimation.model_noise`). The batch
            and the smoother; the chain has the exact model (it refuses an explicit noise).
        model_correlation: how far the bends move before a segment's model error changes,
            radians of the frame vector (docs/estimation.md, "A model error that drifts"):
            ``"robot"`` (default): the correlation length the calibration wrote into the robot
            file, per segment (an independent error per frame where it has none); ``0``: an
            independent model error per frame; a number: that for every segment. Only with
            model error as noise. The default measured better on the real robot's recordings.
    """

    threshold_px: float = 1.0
    theta0_sigma: float = math.radians(0.1)
    motion_sigma: float | None = 0.5
    limit_sigma: float = math.radians(1.0)
    frames_per_chunk: int = 15
    min_track_rows: int = 2
    max_track_frames: int | None = 150
    still_tick: float | None = STILL_TICK
    model_sigma: ModelSigma = ROBOT
    model_correlation: str | float = ROBOT

    def __post_init__(self) -> None:
        object.__setattr__(self, "model_sigma", normalised(self.model_sigma))
        object.__setattr__(self, "model_correlation",
                           correlation_normalised(self.model_correlation))
        for name in ("threshold_px", "theta0_sigma", "limit_sigma"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"GraphOptions.{name} = {value!r}: expected a finite value > 0")
        if self.motion_sigma is not None and not (math.isfinite(self.motion_sigma)
                                                  and self.motion_sigma > 0.0):
            raise ValueError(f"GraphOptions.motion_sigma = {self.motion_sigma!r}: expected a "
                             "finite value > 0 (rad/sqrt(s)) or None")
        if self.still_tick is not None and not 0.0 < self.still_tick <= 1.0:
            raise ValueError(f"GraphOptions.still_tick = {self.still_tick!r}: expected None or "
                             "a value in (0, 1]")
        if self.frames_per_chunk < 1 or self.min_track_rows < 2:
            raise ValueError("GraphOptions: frames_per_chunk >= 1 and min_track_rows >= 2 "
                             f"expected, got {self.frames_per_chunk}, {self.min_track_rows}")


@dataclass(frozen=True)
class Robustness:
    """How outliers are decided (docs/estimation.md, "Outliers").

    Attributes:
        inlier_sigmas: an observation whose whitened reprojection error (pixel-noise units,
            2 degrees of freedom) at its track's point exceeds this is an outlier (truncated
            least squares); 3.5 keeps 99.8% of true observations.
        schedule: the batch's graduated non-convexity: the values of ``mu`` of its stages,
            ending with ``inf`` (the truncated quadratic itself); ``None`` fits one to the
            residuals at the batch's start.
        misfit_alarm: the residual test of the batch's and the smoother's estimates
            (:mod:`~apcc_graph.estimation.model_fit`): a camera whose model rejects more than
            this share of the observations the images alone accept gets a
            ``ModelFitWarning`` (the model does not explain its images); ``None`` skips the
            test.
    """

    inlier_sigmas: float = 3.5
    schedule: tuple[float, ...] | None = None
    misfit_alarm: float | None = 0.05

    def __post_init__(self) -> None:
        if not (math.isfinite(self.inlier_sigmas) and self.inlier_sigmas > 0.0):
            raise ValueError(f"Robustness.inlier_sigmas = {self.inlier_sigmas!r}: expected a "
                             "finite value > 0 (pixel-noise units)")
        if self.schedule is not None:
            schedule = tuple(float(mu) for mu in self.schedule)
            if not schedule or not math.isinf(schedule[-1]) or any(
                    not mu > 0.0 for mu in schedule):
                raise ValueError(f"Robustness.schedule = {self.schedule!r}: expected positive "
                                 "values of mu ending with inf")
            object.__setattr__(self, "schedule", schedule)
        if self.misfit_alarm is not None and not 0.0 < self.misfit_alarm < 1.0:
            raise ValueError(f"Robustness.misfit_alarm = {self.misfit_alarm!r}: expected a "
                             "share in (0, 1), or None to skip the residual test")


@dataclass(frozen=True)
class ChainOptions:
    """The paper's chained estimator (``method="chain"``).

    Attributes:
        confidence: RANSAC confidence.
        seed: random seed of the RANSAC sampling.
    """

    confidence: float = 0.999
    seed: int = 0

    def __post_init__(self) -> None:
        if not 0.0 < self.confidence < 1.0:
            raise ValueError(f"ChainOptions.confidence = {self.confidence!r}: expected a "
                             "probability strictly between 0 and 1")


INITS = ("auto", "chain", "smoother", "rotations")
"""Where the batch's initial values come from."""


@dataclass(frozen=True)
class BatchOptions:
    """The batch optimiser (``method="batch"``).

    Attributes:
        init: where the initial values come from: ``"auto"`` (the default: ``"rotations"``
            with a model noise of at least 0.25 mm or 0.15 deg on some segment, else
            ``"chain"``), ``"chain"`` (the
            paper's chained estimate,
            fast; it drifts, and the graduated non-convexity of the outlier decisions brings
            the batch back from there), ``"smoother"`` (the fixed-lag smoother: closer,
            slower) or ``"rotations"`` (the vectors whose tip rotations fit the cameras'
            own, chained from frame to frame without the model:
            :mod:`~apcc_graph.estimation.rotation_start`; the basin the images point to where
            the robot departs from its model).
        max_iterations: Levenberg-Marquardt iterations per stage (with model error as noise
            at most 3: :attr:`~apcc_graph.estimation.terms.noisy.NoisyTerms.stage_iterations`).
        marginals: compute marginal standard deviations (otherwise NaN).
        calibrate: self-calibration: estimate each segment's k and delta_max jointly with the
            bends, with priors of ``calibration_sigmas`` around the robot's values.
        calibration_sigmas: those priors' standard deviations (k, delta_max in radians);
            ``None`` holds the segment models (with ``mount_sigmas``: the mounts alone).
        mount_sigmas: with ``calibrate``, each observed camera's mounting ``tip_T_cam`` is
            estimated too, with a prior of these standard deviations (rotation in radians,
            translation in metres, on each of the camera's axes) around the robot's;
            ``None`` holds the mounts.
    """

    init: str = "auto"
    max_iterations: int = 30
    marginals: bool = True
    calibrate: bool = False
    calibration_sigmas: Sequence[float] | None = field(default=(0.05, math.radians(5.0)))
    mount_sigmas: Sequence[float] | None = field(default=MOUNT_SIGMAS)

    def __post_init__(self) -> None:
        if self.init not in INITS:
            raise ValueError(f"BatchOptions.init = {self.init!r}: expected one of {INITS}")
        if self.max_iterations < 1:
            raise ValueError(f"BatchOptions.max_iterations = {self.max_iterations!r}: expected "
                             "at least 1")
        for name, units in (("calibration_sigmas", "k, delta_max in radians"),
                            ("mount_sigmas", "rotation in radians, translation in metres")):
            value = getattr(self, name)
            if value is None:
                continue
            sigmas = tuple(float(v) for v in value)
            if len(sigmas) != 2 or not all(math.isfinite(v) and v > 0.0 for v in sigmas):
                raise ValueError(f"BatchOptions.{name} = {value!r}: expected two finite "
                                 f"values > 0 ({units}) or None")
            object.__setattr__(self, name, sigmas)
        if self.calibrate and self.calibration_sigmas is None and self.mount_sigmas is None:
            raise ValueError("BatchOptions.calibrate with calibration_sigmas = None and "
                             "mount_sigmas = None calibrates nothing: give either")
