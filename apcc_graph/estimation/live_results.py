"""What the live loop (:mod:`~apcc_graph.estimation.live`) gives: each processed frame's
estimate at once (:class:`LiveEstimate`) and the final estimates of the frames that left the
smoother's window (:class:`LiveFrame`)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from apcc_graph.model.arrays import FloatArray

__all__ = ["LiveEstimate", "LiveFrame"]


@dataclass(frozen=True)
class LiveFrame:
    """A frame's final estimate (it left the smoother's window).

    Attributes:
        frame: the frame's index in the source.
        timestamp: seconds (the source's clock).
        thetas: ``(S,)`` radians, clamped to each segment's ``[-theta_max, theta_max]``.
        sigmas: ``(S,)`` marginal standard deviations (radians).
        clamped: ``(S,)`` which angles were beyond their limit (and clamped to it).
    """

    frame: int
    timestamp: float
    thetas: FloatArray
    sigmas: FloatArray
    clamped: NDArray[np.bool_]


@dataclass(frozen=True)
class LiveEstimate:
    """One processed frame of :func:`live_estimates`.

    Attributes:
        index: the frame's index in the source (frames dropped before it are skipped).
        timestamp: the frame's time (seconds, the source's clock).
        thetas: ``(S,)`` its filtered estimate (radians: only frames up to it were seen),
            clamped to the joint limits.
        sigmas: ``(S,)`` their marginal standard deviations (radians).
        final: the frames that left the smoother's window with this update, their final
            estimates (``frame``: the index in the source).
        clamped: ``(S,)`` which of ``thetas`` were beyond their limit.
        latency: seconds from the frame's arrival to this estimate.
        fps: frames processed per second over the last second of wall time.
        dropped: frames dropped so far (arrived while the estimator was busy).
        pending: the estimate is the frame's fit to the window's points, before the smoother
            solved with it (keyframes: smoothed at the next one); else the filtered estimate.
    """

    index: int
    timestamp: float
    thetas: FloatArray
    sigmas: FloatArray
    final: list[LiveFrame] = field(default_factory=list)
    latency: float = 0.0
    fps: float = 0.0
    dropped: int = 0
    clamped: NDArray[np.bool_] | None = None
    pending: bool = False
