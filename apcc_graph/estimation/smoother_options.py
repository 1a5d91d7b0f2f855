"""How a fixed-lag smoother runs: frozen, validated options records for both smoothers.

:class:`SmootherOptions` holds what both smoothers share (the window and iSAM2);
:class:`EpipolarSmootherOptions` adds the epipolar smoother's front end, linearisation and
self-calibration (:class:`~apcc_graph.estimation.smoother.FixedLagSmoother`);
:class:`ProjectionSmootherOptions` the projection smoother's live tracks and landmarks
(:class:`~apcc_graph.estimation.projection_smoother.ProjectionFixedLagSmoother`). How the factor
graph itself is built is :class:`~apcc_graph.estimation.options.GraphOptions`, shared with the
batch.

Both smoothers take these fields as keyword arguments (``FixedLagSmoother(robot, lag=0.5)``)
and build the record with :func:`smoother_settings`; a record can be passed whole instead
(``settings=``), and keywords then override its fields.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, fields, replace
from typing import Any, TypeVar

BACKENDS = ("incremental", "batch")
"""gtsam smoothers: ``IncrementalFixedLagSmoother`` (iSAM2) or ``BatchFixedLagSmoother``."""
LINEARIZATIONS = ("first-estimate", "relinearize")
"""How the epipolar smoother's factors are linearised (see
:attr:`EpipolarSmootherOptions.linearization`)."""


def _positive(owner: object, name: str, value: float, unit: str) -> None:
    if not (math.isfinite(value) and value > 0.0):
        raise ValueError(f"{type(owner).__name__}.{name} = {value!r}: expected a finite value "
                         f"> 0 ({unit})")


def _threshold(owner: object, name: str, value: float, unit: str) -> None:
    if not value >= 0.0:  # NaN fails too; inf is a threshold never crossed
        raise ValueError(f"{type(owner).__name__}.{name} = {value!r}: expected a value >= 0 "
                         f"({unit})")


def _at_least(owner: object, name: str, value: int, least: int, unit: str) -> None:
    if value < least:
        raise ValueError(f"{type(owner).__name__}.{name} = {value!r}: expected at least "
                         f"{least} ({unit})")


def _coerce(record: object, kinds: Mapping[str, type]) -> None:
    """Store the named fields as plain ``int``, ``float`` or ``bool`` (numpy scalars in)."""
    for name, kind in kinds.items():
        object.__setattr__(record, name, kind(getattr(record, name)))


@dataclass(frozen=True)
class SmootherOptions:
    """What both fixed-lag smoothers share: the window and gtsam's iSAM2.

    Attributes:
        lag: window length (seconds); frames older than this are marginalised.
        uncertainty: compute marginal standard deviations of each new and each final frame
            (a little slower); otherwise they are NaN.
        relinearize_threshold: iSAM2 re-linearises the factors of a variable that moved more
            than this since their last linearisation (radians).
        loose_sigma: the weak prior (radians) that keeps a frame determined when nothing else
            constrains it and the motion prior is disabled (``GraphOptions.motion_sigma``
            ``None``).
    """

    lag: float = 1.0
    uncertainty: bool = True
    relinearize_threshold: float = 1e-3
    loose_sigma: float = math.radians(30.0)

    def __post_init__(self) -> None:
        _coerce(self, {"lag": float, "uncertainty": bool, "relinearize_threshold": float,
                       "loose_sigma": float})
        if not (math.isfinite(self.lag) and self.lag > 0.0):
            raise ValueError(f"{type(self).__name__}.lag = {self.lag!r}: expected a positive "
                             "number of seconds")
        _threshold(self, "relinearize_threshold", self.relinearize_threshold, "radians")
        _positive(self, "loose_sigma", self.loose_sigma, "radians")


@dataclass(frozen=True)
class EpipolarSmootherOptions(SmootherOptions):
    """The epipolar smoother's options (:class:`~apcc_graph.estimation.smoother.FixedLagSmoother`),
    beside :class:`SmootherOptions`' ``lag``, ``uncertainty``, ``relinearize_threshold`` and
    ``loose_sigma``.

    Attributes:
        backend: ``"incremental"`` (iSAM2, default) or ``"batch"`` (Levenberg-Marquardt over
            the whole window at every frame); see :data:`BACKENDS`.
        calibrate: add each segment's k and delta_max as variables with priors, never
            marginalised (online self-calibration). Experimental: k is only weakly observable
            from the epipolar geometry and delta_max trades off against the weakly observed
            absolute angles, so on a model that is off it can make the angles worse
            (``docs/estimation.md``).
        calibration_sigmas: prior standard deviations of k (dimensionless) and delta_max
            (radians) around the robot's values.
        relinearize_skip: iSAM2 checks for re-linearisation every this many updates.
        marginalise_every: frames leave the window in blocks of this many (gtsam
            re-eliminates the window whenever it marginalises; blocks pay that once per block).
            The window holds between ``lag`` and ``lag`` plus one block of frames.
        limit_margin: soft joint limits are added to frames whose initial angle is within this
            of the limit (radians); elsewhere they are inactive anyway.
        linearization: ``"first-estimate"`` (default): each epipolar factor is linearised once,
            when its frame arrives, and enters gtsam as a C++ ``LinearContainerFactor`` (no
            Python runs inside gtsam). ``"relinearize"``: the Python factor itself, which iSAM2
            re-linearises when its variables move more than ``relinearize_threshold``.
        rebuild_threshold: first-estimate factors whose variables have since moved more than
            this (radians) are rebuilt at the current estimate (re-gated, re-linearised) and
            swapped in, at most ``rebuilds_per_frame`` per update, largest move first (iSAM2).
        rebuilds_per_frame: see ``rebuild_threshold``; 0 (default) disables rebuilding.
        iterations: a new frame's first-estimate factors are linearised at the prediction;
            while the update then moves that frame's angles by more than ``iterate_threshold``
            they are re-gated, re-linearised at the new estimate and swapped in, up to this
            many linearisations in all (an iterated update; iSAM2). 1 disables it.
        iterate_threshold: see ``iterations`` (radians).
        keyframe_every: every this many frames one becomes a keyframe.
        keyframes: the last this many keyframes stay in the window beyond ``lag`` (their
            timestamps are renewed) and new frames are paired with them too: long baselines
            observe the absolute configuration, at the cost of more pairs and a window gtsam
            re-eliminates whole. 0 (default) disables keyframes.
        agreement: fraction of the correspondences with the latest frame that must fall inside
            the gate for the prediction to stand (otherwise the 1-point RANSAC re-initialises
            the angle); in ``[0, 1]``.
        seed: random seed of the front end's RANSAC.
    """

    backend: str = "incremental"
    calibrate: bool = False
    calibration_sigmas: tuple[float, float] = (0.05, math.radians(5.0))
    relinearize_skip: int = 1
    marginalise_every: int = 10
    limit_margin: float = math.radians(10.0)
    linearization: str = "first-estimate"
    rebuild_threshold: float = math.radians(0.1)
    rebuilds_per_frame: int = 0
    iterations: int = 3
    iterate_threshold: float = math.radians(0.1)
    keyframe_every: int = 10
    keyframes: int = 0
    agreement: float = 0.5
    seed: int = 0

    def __post_init__(self) -> None:
        super().__post_init__()
        name = type(self).__name__
        if self.backend not in BACKENDS:
            raise ValueError(f"{name}.backend = {self.backend!r}: expected one of {BACKENDS}")
        if self.linearization not in LINEARIZATIONS:
            raise ValueError(f"{name}.linearization = {self.linearization!r}: expected one of "
                             f"{LINEARIZATIONS}")
        _coerce(self, {"calibrate": bool, "relinearize_skip": int, "marginalise_every": int,
                       "limit_margin": float, "rebuild_threshold": float,
                       "rebuilds_per_frame": int, "iterations": int, "iterate_threshold": float,
                       "keyframe_every": int, "keyframes": int, "agreement": float,
                       "seed": int})
        sigmas = tuple(float(s) for s in self.calibration_sigmas)
        if len(sigmas) != 2 or not all(math.isfinite(s) and s > 0.0 for s in sigmas):
            raise ValueError(f"{name}.calibration_sigmas = {self.calibration_sigmas!r}: expected "
                             "two finite values > 0 (k, delta_max in radians)")
        object.__setattr__(self, "calibration_sigmas", sigmas)
        _at_least(self, "relinearize_skip", self.relinearize_skip, 1, "updates")
        _at_least(self, "marginalise_every", self.marginalise_every, 1, "frames")
        _threshold(self, "limit_margin", self.limit_margin, "radians")
        _threshold(self, "rebuild_threshold", self.rebuild_threshold, "radians")
        _at_least(self, "rebuilds_per_frame", self.rebuilds_per_frame, 0, "factors")
        _at_least(self, "iterations", self.iterations, 1, "linearisations")
        _threshold(self, "iterate_threshold", self.iterate_threshold, "radians")
        _at_least(self, "keyframe_every", self.keyframe_every, 1, "frames")
        _at_least(self, "keyframes", self.keyframes, 0, "keyframes")
        if not 0.0 <= self.agreement <= 1.0:
            raise ValueError(f"{name}.agreement = {self.agreement!r}: expected a fraction in "
                             "[0, 1]")


@dataclass(frozen=True)
class ProjectionSmootherOptions(SmootherOptions):
    """The projection smoother's options
    (:class:`~apcc_graph.estimation.projection_smoother.ProjectionFixedLagSmoother`), beside
    :class:`SmootherOptions`' ``lag``, ``uncertainty``, ``relinearize_threshold`` (here 3e-4
    radians by default) and ``loose_sigma`` (each frame's weak prior at its initial guess
    when the motion prior is disabled).

    Attributes:
        relinearize: keep committed pieces as Python factors that iSAM2 re-linearises when
            their frames move more than ``relinearize_threshold`` (default). ``False``
            linearises each piece once, when it is committed: faster, but the newest frames'
            estimates are still off by about a degree then, and the error grows far beyond the
            Cramer-Rao bound.
        min_live_rows: a live piece joins the live factor (and its point the initial guesses)
            once it has this many observations (at least 2): with two or three a wrong
            association cannot be told from the rest, unless the front end accepted each of
            its pairs (those join the live factor from two; see
            :meth:`~apcc_graph.estimation.live_tracks.LiveTracks.vouch`). Committed pieces
            keep all their observations.
        front_end_rows: a camera whose new observations include fewer than this many of
            tracks with known points (the first frames, after a blackout) has its segment's
            angle started by the 1-point front end from the previous frame
            (:func:`~apcc_graph.estimation.initial_guess.one_point_guess`).
        point_iterations: triangulation steps per linearisation of a projection factor, from
            its points of the previous one
            (:func:`apcc_graph.factors.reduced_system.reduced_system`).
        commit_every: pieces whose tracks ended are committed together every this many frames
            (they stay in the live factor until then): fewer committed Python factors.
        landmarks: a track that outlives the window becomes a landmark, its point a variable
            (:mod:`apcc_graph.factors.landmark`), instead of being cut into pieces with points of
            their own (which loses what the old observations said about the point).
        landmark_sigma: a landmark's weak prior at its first triangulation (metres), so that
            one seen without parallax stays determined.
        pose_sigma: stiffness of the tie between a frame's angles and its camera-pose
            variables, which the landmarks' observations attach to (radians and metres).
        max_landmarks: most landmarks per camera at a time (each update re-eliminates every
            landmark seen in the new frame); the other tracks that outlive the window are cut.
        still_frames: after this many frames in which no camera saw motion, the frames that
            follow are held out of the graph until the robot moves again
            (:mod:`apcc_graph.estimation.stillness`); ``None`` never holds a frame.
        still_chi2: a camera sees no motion while the chi-square of its tracks' coherent
            displacement stays below this (noise alone exceeds the default with probability
            1e-4).
    """

    relinearize_threshold: float = 3e-4
    relinearize: bool = True
    min_live_rows: int = 4
    front_end_rows: int = 20
    point_iterations: int = 1
    commit_every: int = 1
    landmarks: bool = True
    landmark_sigma: float = 10.0
    pose_sigma: float = 1e-4
    max_landmarks: int = 10
    still_frames: int | None = 10
    still_chi2: float = 18.4

    def __post_init__(self) -> None:
        super().__post_init__()
        _coerce(self, {"relinearize": bool, "min_live_rows": int, "front_end_rows": int,
                       "point_iterations": int, "commit_every": int, "landmarks": bool,
                       "landmark_sigma": float, "pose_sigma": float, "max_landmarks": int,
                       "still_chi2": float})
        if self.still_frames is not None:
            _coerce(self, {"still_frames": int})
            _at_least(self, "still_frames", self.still_frames, 0, "frames")
        _positive(self, "still_chi2", self.still_chi2, "(a chi-square with 2 degrees of freedom)")
        _at_least(self, "min_live_rows", self.min_live_rows, 2, "observations")
        _at_least(self, "front_end_rows", self.front_end_rows, 0, "observations")
        _at_least(self, "point_iterations", self.point_iterations, 1, "steps")
        _at_least(self, "commit_every", self.commit_every, 1, "frames")
        _positive(self, "landmark_sigma", self.landmark_sigma, "metres")
        _positive(self, "pose_sigma", self.pose_sigma, "radians and metres")
        _at_least(self, "max_landmarks", self.max_landmarks, 0, "landmarks per camera")


Settings = TypeVar("Settings", bound=SmootherOptions)


def smoother_settings(kind: type[Settings], settings: Settings | None, lag: float | None,
                      keywords: Mapping[str, Any], owner: str) -> Settings:
    """The options record of a smoother built from keyword arguments: ``settings`` (default
    ``kind()``) with ``lag`` and ``keywords`` overriding its fields.

    Raises:
        TypeError: a keyword that is no field of ``kind``, or ``settings`` of another type.
        ValueError: a field out of range (from ``kind``'s validation).
    """
    names = {f.name for f in fields(kind)}
    unknown = sorted(set(keywords) - names)
    if unknown:
        raise TypeError(f"{owner}: unknown argument(s) {', '.join(unknown)}; expected "
                        f"{', '.join(sorted(names))}")
    if settings is not None and not isinstance(settings, kind):
        raise TypeError(f"{owner}.settings: expected {kind.__name__}, got "
                        f"{type(settings).__name__}")
    changes = dict(keywords)
    if lag is not None:
        changes["lag"] = lag
    if settings is None:
        return kind(**changes)
    return replace(settings, **changes) if changes else settings
