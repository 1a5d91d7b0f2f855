"""How the fixed-lag smoother runs: frozen, validated options records, one per concern.

:class:`SmootherOptions` is the record of four records, each validated on its own:

- :class:`WindowOptions`: the window and gtsam's iSAM2 that holds it (the lag, the marginal
  sigmas, re-linearisation, the factorization);
- :class:`TrackOptions`: the live tracks (when a piece joins the graph, its triangulation,
  when ended pieces are committed and when long tracks are cut);
- :class:`LandmarkOptions`: the tracks that outlive the window and become landmarks;
- :class:`FaultOptions`: the checks against faults of the data and the model (still frames,
  the model-free outlier gate, the residual test).

The options of :class:`~apcc_graph.estimation.smoother.FixedLagSmoother` are
``SmootherOptions(window=WindowOptions(lag=0.5), landmarks=LandmarkOptions(enabled=False))``;
a record not given has its defaults. How the factor graph itself is built is
:class:`~apcc_graph.estimation.options.GraphOptions`, shared with the batch.

The smoother takes the record whole (``settings=``; a misspelled field is refused by name) and,
for the window's length alone, ``lag`` (``FixedLagSmoother(robot, lag=0.5)``), which overrides
``window.lag``. The flat names of earlier releases (``SmootherOptions(lag=0.5)``) are refused
with the record each field went to; :meth:`SmootherOptions.of` still converts them, for one
release (:data:`FLAT_FIELDS`).
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Mapping
from dataclasses import dataclass, field, replace

from apcc_graph.estimation.keyframes import KeyframeRule


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
class WindowOptions:
    """The smoother's window and gtsam's iSAM2 that holds it.

    Attributes:
        lag: window length (seconds); frames older than this are marginalised.
        uncertainty: compute marginal standard deviations of each new and each final frame
            (a little slower); otherwise they are NaN.
        relinearize: keep committed pieces as Python factors that iSAM2 re-linearises when
            their frames move more than ``relinearize_threshold`` (default). ``False``
            linearises each piece once, when it is committed: faster, but the newest frames'
            estimates are still off by about a degree then, and the error grows far beyond the
            Cramer-Rao bound.
        relinearize_threshold: iSAM2 re-linearises the factors of a variable that moved more
            than this since their last linearisation (radians).
        factorization: how iSAM2 factors the window's linear system: ``"CHOLESKY"`` (of the
            normal equations) or ``"QR"`` (of the whitened Jacobians, which does not square
            their condition number; docs/estimation.md, "The fixed-lag smoother").
        reproducible: hold the window in
            :class:`~apcc_graph.estimation.smoother.fixed_lag.FixedLagISAM2`, which gives the
            same bytes on every run and marginalises in blocks; ``False``: gtsam's
            ``IncrementalFixedLagSmoother``, whose runs differ by about 1e-8 rad once landmarks
            are in the window (docs/estimation.md, "The fixed-lag smoother").
        loose_sigma: the weak prior (radians) at each frame's initial guess that keeps it
            determined when nothing else constrains it and the motion prior is disabled
            (``GraphOptions.motion_sigma`` ``None``).
    """

    lag: float = 1.0
    uncertainty: bool = True
    relinearize: bool = True
    relinearize_threshold: float = 3e-4
    factorization: str = "CHOLESKY"
    reproducible: bool = True
    loose_sigma: float = math.radians(30.0)

    def __post_init__(self) -> None:
        _coerce(self, {"lag": float, "uncertainty": bool, "relinearize": bool,
                       "relinearize_threshold": float, "reproducible": bool,
                       "loose_sigma": float})
        _positive(self, "lag", self.lag, "seconds")
        _threshold(self, "relinearize_threshold", self.relinearize_threshold, "radians")
        if self.factorization not in FACTORIZATIONS:
            raise ValueError(f"{type(self).__name__}.factorization = {self.factorization!r}: "
                             f"expected one of {', '.join(FACTORIZATIONS)}")
        _positive(self, "loose_sigma", self.loose_sigma, "radians")


@dataclass(frozen=True)
class TrackOptions:
    """How the smoother's live tracks enter the window.

    Attributes:
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
        stagger_cuts: a track that outlives the window and is not a landmark is cut (the rest
            a new piece with its own point) up to half a window before its first frame would
            leave, at a share fixed per piece, so that tracks born together (all of them, when
            a camera starts or sees a new scene) are not all cut together, every lag, leaving a
            frame with no known point; ``False`` cuts each when its first frame leaves.
    """

    min_live_rows: int = 4
    front_end_rows: int = 20
    point_iterations: int = 1
    commit_every: int = 1
    stagger_cuts: bool = True

    def __post_init__(self) -> None:
        _coerce(self, {"min_live_rows": int, "front_end_rows": int, "point_iterations": int,
                       "commit_every": int, "stagger_cuts": bool})
        _at_least(self, "min_live_rows", self.min_live_rows, 2, "observations")
        _at_least(self, "front_end_rows", self.front_end_rows, 0, "observations")
        _at_least(self, "point_iterations", self.point_iterations, 1, "steps")
        _at_least(self, "commit_every", self.commit_every, 1, "frames")


@dataclass(frozen=True)
class LandmarkOptions:
    """The tracks that outlive the smoother's window and become landmarks.

    Attributes:
        enabled: a track that outlives the window becomes a landmark, its point a variable
            (:mod:`apcc_graph.factors.landmark`), instead of being cut into pieces with points of
            their own (which loses what the old observations said about the point).
        prior_sigma: a landmark's weak prior at its first triangulation (metres), so that
            one seen without parallax stays determined.
        pose_sigma: stiffness of the tie between a frame's angles and its camera-pose
            variables, which the landmarks' observations attach to (radians and metres).
        max_per_camera: most landmarks per camera at a time (each update re-eliminates every
            landmark seen in the new frame); the other tracks that outlive the window are cut.
    """

    enabled: bool = True
    prior_sigma: float = 10.0
    pose_sigma: float = 1e-4
    max_per_camera: int = 10

    def __post_init__(self) -> None:
        _coerce(self, {"enabled": bool, "prior_sigma": float, "pose_sigma": float,
                       "max_per_camera": int})
        _positive(self, "prior_sigma", self.prior_sigma, "metres")
        _positive(self, "pose_sigma", self.pose_sigma, "radians and metres")
        _at_least(self, "max_per_camera", self.max_per_camera, 0, "landmarks per camera")


@dataclass(frozen=True)
class FaultOptions:
    """The smoother's checks against faults of the data and of the model.

    Attributes:
        still_frames: after this many frames in which no camera saw motion, the frames that
            follow are held out of the graph until the robot moves again
            (:mod:`apcc_graph.estimation.stillness`); ``None`` never holds a frame.
        still_chi2: a camera sees no motion while the chi-square of its tracks' coherent
            displacement stays below this (noise alone exceeds the default with probability
            1e-4).
        rotation_gate: the model-free outlier gate's threshold (radians of bearing): an
            observation that a neighbouring frame of its camera could judge and that agrees
            with neither neighbour's rotation is an outlier, whatever its residual
            (:mod:`~apcc_graph.estimation.rotation_gate`); ``None`` leaves every decision to
            the residuals at the current estimates.
        misfit_seconds: the residual test of the final frames, in blocks of this many seconds
            (:mod:`~apcc_graph.estimation.fit_monitor`; a failing block warns); ``None`` skips
            it (``apcc_graph.estimate`` tests the whole recording instead).
    """

    still_frames: int | None = 10
    still_chi2: float = 18.4
    rotation_gate: float | None = None
    misfit_seconds: float | None = 2.0

    def __post_init__(self) -> None:
        _coerce(self, {"still_chi2": float})
        if self.still_frames is not None:
            _coerce(self, {"still_frames": int})
            _at_least(self, "still_frames", self.still_frames, 0, "frames")
        _positive(self, "still_chi2", self.still_chi2, "(a chi-square with 2 degrees of freedom)")
        if self.rotation_gate is not None:
            _coerce(self, {"rotation_gate": float})
            _positive(self, "rotation_gate", self.rotation_gate, "radians of bearing")
        if self.misfit_seconds is not None:
            _coerce(self, {"misfit_seconds": float})
            _positive(self, "misfit_seconds", self.misfit_seconds, "seconds")


RECORDS: dict[str, type] = {"window": WindowOptions, "tracks": TrackOptions,
                            "landmarks": LandmarkOptions, "faults": FaultOptions}
"""The fields of :class:`SmootherOptions` and the record each holds."""

FLAT_FIELDS: dict[str, tuple[str, str]] = {
    "lag": ("window", "lag"), "uncertainty": ("window", "uncertainty"),
    "relinearize": ("window", "relinearize"),
    "relinearize_threshold": ("window", "relinearize_threshold"),
    "factorization": ("window", "factorization"), "reproducible": ("window", "reproducible"),
    "loose_sigma": ("window", "loose_sigma"),
    "min_live_rows": ("tracks", "min_live_rows"), "front_end_rows": ("tracks", "front_end_rows"),
    "point_iterations": ("tracks", "point_iterations"),
    "commit_every": ("tracks", "commit_every"), "stagger_cuts": ("tracks", "stagger_cuts"),
    "landmarks": ("landmarks", "enabled"), "landmark_sigma": ("landmarks", "prior_sigma"),
    "pose_sigma": ("landmarks", "pose_sigma"), "max_landmarks": ("landmarks", "max_per_camera"),
    "still_frames": ("faults", "still_frames"), "still_chi2": ("faults", "still_chi2"),
    "rotation_gate": ("faults", "rotation_gate"), "misfit_seconds": ("faults", "misfit_seconds"),
}
"""The flat fields of earlier releases' ``SmootherOptions`` -> where each went:
``(field of SmootherOptions, field of its record)``."""


def _nested(flat: Mapping[str, object]) -> str:
    """The nested form of flat options, e.g. ``window=WindowOptions(lag=0.5)``."""
    groups: dict[str, list[str]] = {}
    for name, value in flat.items():
        record, inner = FLAT_FIELDS[name]
        groups.setdefault(record, []).append(f"{inner}={value!r}")
    return ", ".join(f"{record}={RECORDS[record].__name__}({', '.join(args)})"
                     for record, args in groups.items())


def _unknown(names: list[str]) -> TypeError:
    return TypeError(f"SmootherOptions has no field {', '.join(map(repr, names))}; its fields "
                     f"are {', '.join(RECORDS)}")


@dataclass(frozen=True, init=False)
class SmootherOptions:
    """The fixed-lag smoother's options
    (:class:`~apcc_graph.estimation.smoother.FixedLagSmoother`): one record per concern.

    Attributes:
        window: the window and iSAM2 (:class:`WindowOptions`: the lag, ...).
        tracks: the live tracks (:class:`TrackOptions`).
        landmarks: the tracks that outlive the window (:class:`LandmarkOptions`).
        faults: still frames, the outlier gate, the residual test (:class:`FaultOptions`).
        keyframes: when a frame enters the window
            (:class:`~apcc_graph.estimation.keyframes.KeyframeRule`); ``None``: every frame
            does (:mod:`~apcc_graph.estimation.smoother.keyframing`).

    A record not given (or ``None``) has its defaults. The flat names of earlier releases
    (``SmootherOptions(lag=0.5)``) are refused: the ``TypeError`` names the record each went
    to (:data:`FLAT_FIELDS`); :meth:`of` converts them, for one release.

    Raises:
        TypeError: a field that is not its record (named, with the record expected); a flat
            or unknown keyword (named).
    """

    window: WindowOptions = field(default_factory=WindowOptions)
    tracks: TrackOptions = field(default_factory=TrackOptions)
    landmarks: LandmarkOptions = field(default_factory=LandmarkOptions)
    faults: FaultOptions = field(default_factory=FaultOptions)
    keyframes: KeyframeRule | None = None

    def __init__(self, window: WindowOptions | None = None, tracks: TrackOptions | None = None,
                 landmarks: LandmarkOptions | None = None, faults: FaultOptions | None = None,
                 keyframes: KeyframeRule | None = None, **flat: object) -> None:
        unknown = [name for name in flat if name not in FLAT_FIELDS]
        if unknown:
            raise _unknown(unknown)
        if isinstance(landmarks, bool):  # the flat switch of earlier releases
            flat = {**flat, "landmarks": landmarks}
        if flat:
            raise TypeError(f"SmootherOptions({', '.join(f'{k}=...' for k in flat)}): the "
                            f"options are grouped by concern: SmootherOptions({_nested(flat)}) "
                            "(SmootherOptions.of(...) still converts the flat names, for one "
                            "release)")
        given = {"window": window, "tracks": tracks, "landmarks": landmarks, "faults": faults}
        for name, value in given.items():
            kind = RECORDS[name]
            if value is None:
                value = kind()
            elif not isinstance(value, kind):
                raise TypeError(f"SmootherOptions.{name}: expected {kind.__name__}, got "
                                f"{type(value).__name__}")
            object.__setattr__(self, name, value)
        if keyframes is not None and not isinstance(keyframes, KeyframeRule):
            raise TypeError(f"SmootherOptions.keyframes: expected KeyframeRule or None, got "
                            f"{type(keyframes).__name__}")
        object.__setattr__(self, "keyframes", keyframes)

    @classmethod
    def of(cls, **flat: object) -> SmootherOptions:
        """The record from the flat field names of earlier releases
        (``SmootherOptions.of(lag=0.5, landmarks=False)``), each put in its record
        (:data:`FLAT_FIELDS`); the other fields keep their defaults. For one release: it warns
        with the nested form to write instead.

        Raises:
            TypeError: a name that was never a field (named).
            ValueError: a value out of range (named by its record and field).

        Warns:
            DeprecationWarning: always, with the nested form of the options given.
        """
        unknown = [name for name in flat if name not in FLAT_FIELDS]
        if unknown:
            raise _unknown(unknown)
        warnings.warn(f"SmootherOptions.of(...) goes in the next release: write "
                      f"SmootherOptions({_nested(flat)})", DeprecationWarning, stacklevel=2)
        groups: dict[str, dict[str, object]] = {name: {} for name in RECORDS}
        for name, value in flat.items():
            record, inner = FLAT_FIELDS[name]
            groups[record][inner] = value
        return cls(**{name: RECORDS[name](**values) for name, values in groups.items()})


def smoother_settings(settings: SmootherOptions | None, lag: float | None,
                      owner: str) -> SmootherOptions:
    """The options record of a smoother: ``settings`` (default ``SmootherOptions()``) with
    ``lag`` overriding its ``window.lag``.

    Raises:
        TypeError: ``settings`` of another type.
        ValueError: a field out of range (from the record's validation).
    """
    if settings is not None and not isinstance(settings, SmootherOptions):
        raise TypeError(f"{owner}.settings: expected SmootherOptions, got "
                        f"{type(settings).__name__}")
    settings = SmootherOptions() if settings is None else settings
    return settings if lag is None else replace(settings, window=replace(settings.window,
                                                                          lag=lag))
