"""How the fixed-lag smoother runs: one frozen, validated options record.

:class:`SmootherOptions` holds the window, gtsam's iSAM2, the live tracks, the landmarks and the
still frames of :class:`~apcc_graph.estimation.smoother.FixedLagSmoother`. How the factor graph
itself is built is :class:`~apcc_graph.estimation.options.GraphOptions`, shared with the batch.

The smoother takes the record whole (``settings=``; a misspelled field is refused by name) and,
for the window's length alone, ``lag`` (``FixedLagSmoother(robot, lag=0.5)``), which overrides
the record's.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, replace


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


FACTORIZATIONS = ("CHOLESKY", "QR")
"""iSAM2's factorizations of the window's linear system."""


@dataclass(frozen=True)
class SmootherOptions:
    """The fixed-lag smoother's options
    (:class:`~apcc_graph.estimation.smoother.FixedLagSmoother`).

    Attributes:
        lag: window length (seconds); frames older than this are marginalised.
        uncertainty: compute marginal standard deviations of each new and each final frame
            (a little slower); otherwise they are NaN.
        relinearize_threshold: iSAM2 re-linearises the factors of a variable that moved more
            than this since their last linearisation (radians).
        loose_sigma: the weak prior (radians) at each frame's initial guess that keeps it
            determined when nothing else constrains it and the motion prior is disabled
            (``GraphOptions.motion_sigma`` ``None``).
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
            bend started by the two-frame front end from the previous frame
            (:func:`~apcc_graph.estimation.front_end.front_end_guess`).
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
        factorization: how iSAM2 factors the window's linear system: ``"CHOLESKY"`` (of the
            normal equations) or ``"QR"`` (of the whitened Jacobians, which does not square
            their condition number; docs/estimation.md, "The fixed-lag smoother").
        stagger_cuts: a track that outlives the window and is not a landmark is cut (the rest
            a new piece with its own point) up to half a window before its first frame would
            leave, at a share fixed per piece, so that tracks born together (all of them, when
            a camera starts or sees a new scene) are not all cut together, every lag, leaving a
            frame with no known point; ``False`` cuts each when its first frame leaves.
        rotation_gate: the model-free outlier gate's threshold (radians of bearing): an
            observation that a neighbouring frame of its camera could judge and that agrees
            with neither neighbour's rotation is an outlier, whatever its residual
            (:mod:`~apcc_graph.estimation.rotation_gate`); ``None`` leaves every decision to
            the residuals at the current estimates.
        reproducible: hold the window in
            :class:`~apcc_graph.estimation.smoother.fixed_lag.FixedLagISAM2`, which gives the
            same bytes on every run and marginalises in blocks; ``False``: gtsam's
            ``IncrementalFixedLagSmoother``, whose runs differ by about 1e-8 rad once landmarks
            are in the window (docs/estimation.md, "The fixed-lag smoother").
        misfit_seconds: the residual test of the final frames, in blocks of this many seconds
            (:mod:`~apcc_graph.estimation.fit_monitor`; a failing block warns); ``None`` skips
            it (``apcc_graph.estimate`` tests the whole recording instead).
    """

    lag: float = 1.0
    uncertainty: bool = True
    relinearize_threshold: float = 3e-4
    loose_sigma: float = math.radians(30.0)
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
    factorization: str = "CHOLESKY"
    misfit_seconds: float | None = 2.0
    stagger_cuts: bool = True
    rotation_gate: float | None = None
    reproducible: bool = True

    def __post_init__(self) -> None:
        _coerce(self, {"lag": float, "uncertainty": bool, "relinearize_threshold": float,
                       "loose_sigma": float, "relinearize": bool, "min_live_rows": int,
                       "front_end_rows": int,
                       "point_iterations": int, "commit_every": int, "landmarks": bool,
                       "landmark_sigma": float, "pose_sigma": float, "max_landmarks": int,
                       "stagger_cuts": bool, "reproducible": bool,
                       "still_chi2": float})
        if not (math.isfinite(self.lag) and self.lag > 0.0):
            raise ValueError(f"{type(self).__name__}.lag = {self.lag!r}: expected a positive "
                             "number of seconds")
        _threshold(self, "relinearize_threshold", self.relinearize_threshold, "radians")
        _positive(self, "loose_sigma", self.loose_sigma, "radians")
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
        if self.rotation_gate is not None:
            _coerce(self, {"rotation_gate": float})
            _positive(self, "rotation_gate", self.rotation_gate, "radians of bearing")
        if self.misfit_seconds is not None:
            _coerce(self, {"misfit_seconds": float})
            _positive(self, "misfit_seconds", self.misfit_seconds, "seconds")
        if self.factorization not in FACTORIZATIONS:
            raise ValueError(f"{type(self).__name__}.factorization = {self.factorization!r}: "
                             f"expected one of {', '.join(FACTORIZATIONS)}")


def smoother_settings(settings: SmootherOptions | None, lag: float | None,
                      owner: str) -> SmootherOptions:
    """The options record of a smoother: ``settings`` (default ``SmootherOptions()``) with
    ``lag`` overriding its own.

    Raises:
        TypeError: ``settings`` of another type.
        ValueError: a field out of range (from the record's validation).
    """
    if settings is not None and not isinstance(settings, SmootherOptions):
        raise TypeError(f"{owner}.settings: expected SmootherOptions, got "
                        f"{type(settings).__name__}")
    settings = SmootherOptions() if settings is None else settings
    return settings if lag is None else replace(settings, lag=lag)
