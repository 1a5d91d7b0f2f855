"""Live estimation: each frame tracked and smoothed as it arrives (``apcc-graph live``).

:func:`live_estimates` is the loop, an iterator over :class:`LiveEstimate`:

1. a source gives frames in time order, each with one image per camera
   (:func:`recording_frames` for a bag or video files, their cameras matched by time as
   ``apcc-graph track`` matches them; :func:`device_frames` for cameras plugged in);
2. each camera's :class:`~apcc_graph.frontend.tracking.KLTTracker` follows its tracks into the
   new image, and the :class:`~apcc_graph.estimation.smoother.FixedLagSmoother` takes the frame;
3. the frame's filtered estimate is yielded, with the frames that left the window since
   (their final estimates), the rate and the latency.

**Real time and overload.** A recording is played at its own pace (``realtime``): a frame
*arrives* at the wall time its timestamp says, counted from the first. When the estimator is
busy while frames arrive, only the newest arrived frame is taken next and the ones before it
are dropped (and counted): the estimate lags by at most one frame's processing, never by a
growing queue. The trackers then follow their tracks over the longer step. A camera device
delivers its newest image when asked (OpenCV's buffer of one), so it drops by itself.
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field, replace

from numpy.typing import ArrayLike, NDArray

from apcc_graph.estimation.smoother import FixedLagSmoother
from apcc_graph.estimation.smoother_options import SmootherOptions
from apcc_graph.estimation.window import SmootherFrame
from apcc_graph.frontend.recordings import CameraStream, match_frames
from apcc_graph.frontend.tracking import KLTTracker
from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.robot import Robot
from apcc_graph.model.sequence import FrameObservations

Frame = tuple[int, float, dict[int, NDArray]]
"""``(index in the source, timestamp in seconds, camera -> image)``."""


@dataclass(frozen=True)
class LiveEstimate:
    """One processed frame of :func:`live_estimates`.

    Attributes:
        index: the frame's index in the source (frames dropped before it are skipped).
        timestamp: the frame's time (seconds, the source's clock).
        thetas: ``(S,)`` its filtered estimate (radians: only frames up to it were seen).
        sigmas: ``(S,)`` their marginal standard deviations (radians).
        final: the frames that left the smoother's window with this update, their final
            estimates (``frame``: the index in the source).
        latency: seconds from the frame's arrival to this estimate.
        fps: frames processed per second over the last second of wall time.
        dropped: frames dropped so far (arrived while the estimator was busy).
    """

    index: int
    timestamp: float
    thetas: FloatArray
    sigmas: FloatArray
    final: list[SmootherFrame] = field(default_factory=list)
    latency: float = 0.0
    fps: float = 0.0
    dropped: int = 0


def recording_frames(streams: Sequence[CameraStream], cameras: Sequence[int],
                     tolerance: float | None = None) -> Iterator[Frame]:
    """The frames of a recording's streams (one per camera, in the order of ``cameras``),
    matched by time (:func:`~apcc_graph.frontend.recordings.match_frames`), read in order."""
    matched = match_frames([s.timestamps for s in streams], tolerance)
    readers = [s.images() for s in streams]
    for f, t in enumerate(matched.timestamps.tolist()):
        images = {}
        for cam, reader, wanted in zip(cameras, readers, matched.indices[:, f], strict=True):
            for index, image in reader:
                if index == wanted:
                    images[cam] = image
                    break
        if len(images) < len(cameras):
            return  # a stream ended early
        yield f, t, images


def device_frames(devices: Sequence[int], cameras: Sequence[int],
                  clock: Callable[[], float] = time.monotonic) -> Iterator[Frame]:
    """Frames of cameras plugged in (OpenCV device indices, one per camera in the order of
    ``cameras``): each camera's newest image, grabbed together, timed by ``clock``.

    Raises:
        ValueError: a device OpenCV cannot open.
    """
    import cv2

    captures = []
    for device in devices:
        capture = cv2.VideoCapture(int(device))
        if not capture.isOpened():
            raise ValueError(f"camera device {device}: OpenCV cannot open it")
        capture.set(cv2.CAP_PROP_BUFFERSIZE, 1)
        captures.append(capture)
    try:
        index = 0
        while True:
            if not all(c.grab() for c in captures):
                return
            t = clock()
            images = {}
            for cam, capture in zip(cameras, captures, strict=True):
                ok, image = capture.retrieve()
                if not ok:
                    return
                images[cam] = image
            yield index, t, images
            index += 1
    finally:
        for capture in captures:
            capture.release()


class LiveEstimator:
    """Tracks and smooths frames as they arrive (module docstring): :meth:`run` is the loop,
    an iterator over :class:`LiveEstimate`; :meth:`finish` then gives the final estimates of
    the frames still in the window.

    Args:
        robot: the robot (its cameras' sizes check the images).
        theta0: the starting configuration (radians), or ``None`` (straight).
        settings: the smoother's settings.
        realtime: play the source at its own pace, dropping frames under overload; ``False``
            processes every frame as fast as it can (nothing dropped).
        clock, sleep: wall time (seconds) and waiting, replaceable in tests.
    """

    def __init__(self, robot: Robot, theta0: ArrayLike | None = None,
                 settings: SmootherOptions | None = None, realtime: bool = True,
                 clock: Callable[[], float] = time.monotonic,
                 sleep: Callable[[float], None] = time.sleep) -> None:
        self.smoother = FixedLagSmoother(robot, theta0=theta0, settings=settings)
        self.trackers = {cam: KLTTracker((c.width, c.height))
                         for cam, c in enumerate(robot.cameras) if c is not None}
        self.realtime, self.clock, self.sleep = realtime, clock, sleep
        self.dropped = 0
        self._done: deque[float] = deque()
        self._index: dict[int, int] = {}  # the smoother's frame -> the source's index

    def run(self, frames: Iterator[Frame]) -> Iterator[LiveEstimate]:
        """An estimate per processed frame of ``frames`` (:func:`recording_frames`,
        :func:`device_frames`), until the source ends or the iterator is closed."""
        source = iter(frames)
        pending = next(source, None)
        start: tuple[float, float] | None = None  # wall time and source time of the first
        while pending is not None:
            index, t, images = pending
            start = start or (self.clock(), t)
            pending = next(source, None)
            if self.realtime:
                wait = start[0] + (t - start[1]) - self.clock()
                if wait > 0:
                    self.sleep(wait)
                while pending is not None and start[0] + (pending[1] - start[1]) <= self.clock():
                    self.dropped += 1  # a newer frame has arrived: this one is dropped
                    index, t, images = pending
                    pending = next(source, None)
            arrival = start[0] + (t - start[1])
            yield self._process(index, t, images, arrival)

    def _process(self, index: int, t: float, images: dict[int, NDArray], arrival: float
                 ) -> LiveEstimate:
        """One frame tracked and smoothed."""
        tracks = {cam: self.trackers[cam].update(image) for cam, image in images.items()}
        estimate = self.smoother.update(FrameObservations(t, tracks))
        self._index[estimate.frame] = index
        final = self._numbered(self.smoother.pop_final())
        now = self.clock()
        self._done.append(now)
        while self._done[0] < now - 1.0:
            self._done.popleft()
        return LiveEstimate(index, t, estimate.thetas, estimate.sigmas, final,
                            max(now - arrival, 0.0) if self.realtime else 0.0,
                            float(len(self._done)), self.dropped)

    def finish(self) -> list[SmootherFrame]:
        """The final estimates of the frames still in the window (the others came with the
        estimates, in ``final``)."""
        return self._numbered(self.smoother.finish())

    def _numbered(self, frames: list[SmootherFrame]) -> list[SmootherFrame]:
        """Final estimates numbered by the source's frame index."""
        return [replace(fr, frame=self._index.pop(fr.frame, fr.frame)) for fr in frames]


def live_estimates(frames: Iterator[Frame], robot: Robot, theta0: ArrayLike | None = None,
                   settings: SmootherOptions | None = None, realtime: bool = True
                   ) -> Iterator[LiveEstimate]:
    """:meth:`LiveEstimator.run` of a new :class:`LiveEstimator` (without its
    :meth:`~LiveEstimator.finish`: the last lag's frames then have only their filtered
    estimates)."""
    return LiveEstimator(robot, theta0, settings, realtime).run(frames)
