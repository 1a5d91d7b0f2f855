"""``apcc_graph.estimate``: one entry point for every estimator."""

from __future__ import annotations

import warnings
from os import PathLike
from typing import Any

from numpy.typing import ArrayLike

from apcc_graph.estimation.result import Estimate
from apcc_graph.model.sequence import Sequence

METHODS = ("chain", "batch", "smoother")
"""Estimators available."""


class ObservationWarning(UserWarning):
    """A camera of the robot observed nothing in the whole sequence: its segment's angle rests
    on the cameras further out and on the motion prior."""


def check_observations(sequence: Sequence) -> None:
    """Warn for each camera without a single observation; refuse a sequence without any.

    Raises:
        ValueError: no camera observed anything (e.g. ``tracks/`` empty or missing).
    """
    counts = {cam: 0 if sequence.tracks.get(cam) is None else len(sequence.tracks[cam])
              for cam in sequence.robot.camera_segments}
    if not any(counts.values()):
        raise ValueError("the sequence has no observations: no camera has a track (tracks/ "
                         "empty or missing? a folder of images needs `apcc-graph track` first)")
    for cam, count in counts.items():
        if count == 0:
            warnings.warn(f"camera cam_{cam + 1} (segment {cam + 1}) observed nothing in the "
                          f"whole sequence: segment {cam + 1}'s angle rests on the cameras "
                          "further out and on the motion prior", ObservationWarning,
                          stacklevel=3)


def estimate(sequence: Sequence, method: str = "batch", theta0: ArrayLike | None = None,
             theta0_sigma: float | None = None, vision: str | None = None,
             threshold_px: float | None = None, **options: Any) -> Estimate:
    """Estimate every frame's segment angles.

    Args:
        sequence: the sequence; ground-truth columns are never read.
        method: ``"chain"`` (the paper's front end), ``"batch"`` (factor graph, whole
            sequence) or ``"smoother"`` (fixed-lag smoother, frame by frame).
        theta0: ``(S,)`` starting configuration in radians (default straight).
        theta0_sigma: standard deviation of the prior on ``theta0`` (radians; default
            :class:`~apcc_graph.estimation.options.GraphOptions`' 0.1 deg); batch and
            smoother only (the chain starts exactly at ``theta0``).
        vision: ``"projection"`` (default: every observation once, each track's point
            eliminated) or ``"epipolar"`` (frame pairs, for comparison); batch and smoother
            only.
        threshold_px: the tracks' pixel noise (pixels, default 1); batch and smoother only.
        **options: passed to the estimator (:func:`~apcc_graph.estimation.chain.chain_estimate`,
            :func:`~apcc_graph.estimation.batch.batch_estimate` or
            :func:`~apcc_graph.estimation.smoother.smoother_estimate`); e.g.
            ``calibrate=True``, self-calibration of each segment's k and delta_max (batch, or
            smoother with ``vision="epipolar"``).

    Raises:
        TypeError: ``sequence`` is not a :class:`~apcc_graph.model.sequence.Sequence` (a path
            must be loaded first, with ``apcc_graph.load_sequence``).
        ValueError: an unknown method; ``theta0`` not one finite angle per segment within its
            ``theta_max`` (radians); a sequence without a single observation.

    Warns:
        ObservationWarning: a camera observed nothing in the whole sequence (named).
    """
    if not isinstance(sequence, Sequence):
        hint = (" (a path: load it first, apcc_graph.load_sequence(path))"
                if isinstance(sequence, str | PathLike) else "")
        raise TypeError(f"sequence: expected a Sequence, got {type(sequence).__name__}{hint}")
    if method not in METHODS:
        raise ValueError(f"method = {method!r}: expected one of {', '.join(METHODS)}")
    sequence.robot.configuration(theta0)
    check_observations(sequence)
    if method in ("batch", "smoother") and (theta0_sigma is not None or vision is not None
                                            or threshold_px is not None):
        from dataclasses import replace

        from apcc_graph.estimation.options import GraphOptions

        changes: dict[str, Any] = {}
        if theta0_sigma is not None:
            changes["theta0_sigma"] = float(theta0_sigma)
        if threshold_px is not None:
            changes["threshold_px"] = float(threshold_px)
        if vision is not None and method == "batch":
            changes["vision"] = vision
        if vision is not None and method == "smoother":
            options["vision"] = vision
        options["options"] = replace(options.get("options") or GraphOptions(), **changes)
    elif method == "chain" and vision not in (None, "epipolar"):
        raise ValueError(f"vision = {vision!r}: the chain is the epipolar 1-point front end")
    if method == "chain":
        from apcc_graph.estimation.chain import chain_estimate

        return chain_estimate(sequence, theta0=theta0, **options)
    if method == "batch":
        from apcc_graph.estimation.batch import batch_estimate

        return batch_estimate(sequence, theta0=theta0, **options)
    if method == "smoother":
        from apcc_graph.estimation.smoother_runs import smoother_estimate

        return smoother_estimate(sequence, theta0=theta0, **options)
    raise ValueError(f"method = {method!r}: expected one of {', '.join(METHODS)}")
