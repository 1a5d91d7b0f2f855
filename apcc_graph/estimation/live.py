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
*arrives* at the wall time its timestamp says, counted from the first. Every frame is tracked
(a few milliseconds per camera), so the tracks stay as continuous as offline, unless it has
waited more than :data:`MAX_BEHIND` while newer frames arrived (then the trackers step over
it). A tracked frame after which a newer one has already arrived is not smoothed, unless the
last smoothed frame is :data:`MAX_GAP` old: it is dropped from the estimate (counted), and the
smoother takes a newer one. The lag stays bounded (never a growing queue), and the smoother
sees a lower frame rate with the same tracks. (Dropping frames before tracking, as a first
version did, broke the tracks: with KLT steps three frames long the estimate ran 60 to 120
degrees off on ``apcc-graph bench live``.) A camera device delivers its newest image when
asked (OpenCV's buffer of one), so it drops by itself.
"""

from __future__ import annotations

import time
import warnings
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from apcc_graph.estimation.smoother import FixedLagSmoother
from apcc_graph.estimation.smoother_options import SmootherOptions
from apcc_graph.estimation.window import SmootherFrame
from apcc_graph.frontend.recordings import CameraStream, match_frames
from apcc_graph.frontend.tracking import KLTTracker
from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.robot import Robot
from apcc_graph.model.sequence import FrameObservations

MAX_GAP = 0.2
"""Seconds of the source: under overload a frame is smoothed anyway when the last smoothed
frame is this old (the smoother then sees at least five frames a second; with gaps of half a
second it took each for a pause, re-acquired, and ran 100 degrees off)."""
MAX_BEHIND = 0.1
"""Seconds: a frame that has waited this long while newer ones arrived is not even tracked
(the trackers then step over it), so the lag stays bounded when tracking alone is slower
than the frames."""

Frame = tuple[int, float, dict[int, NDArray]]
"""``(index in the source, timestamp in seconds, camera -> image)``."""


class LiveWarning(UserWarning):
    """The live loop drops more frames than it smooths."""


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
        self._smoothed, self._warned = 0, False
        self._pool = ThreadPoolExecutor(max_workers=max(len(self.trackers), 1))

    def run(self, frames: Iterator[Frame]) -> Iterator[LiveEstimate]:
        """An estimate per smoothed frame of ``frames`` (:func:`recording_frames`,
        :func:`device_frames`), until the source ends or the iterator is closed."""
        source = iter(frames)
        pending = next(source, None)
        start: tuple[float, float] | None = None  # wall time and source time of the first
        smoothed = -np.inf  # source time of the last smoothed frame
        while pending is not None:
            index, t, images = pending
            start = start or (self.clock(), t)
            arrival = start[0] + (t - start[1])
            pending = next(source, None)
            if self.realtime:
                if arrival > self.clock():
                    self.sleep(arrival - self.clock())
                elif self._waiting(pending, start) and self.clock() - arrival > MAX_BEHIND:
                    self.dropped += 1  # too far behind even to track it
                    continue
            tracks = self._track(images)
            if self.realtime and self._waiting(pending, start) and t - smoothed < MAX_GAP:
                self.dropped += 1  # tracked, not smoothed: a newer frame is waiting
                continue
            smoothed = t
            yield self._process(index, t, tracks, arrival)

    def _waiting(self, pending: Frame | None, start: tuple[float, float]) -> bool:
        """Whether the next frame has already arrived."""
        return pending is not None and start[0] + (pending[1] - start[1]) <= self.clock()

    def _track(self, images: dict[int, NDArray]) -> dict[int, tuple[NDArray, NDArray]]:
        """Each camera's tracks in its new image, the cameras in parallel threads (OpenCV's
        optical flow and corner detection release the interpreter)."""
        cams = sorted(images)
        found = self._pool.map(lambda cam: self.trackers[cam].update(images[cam]), cams)
        return dict(zip(cams, found, strict=True))

    def _process(self, index: int, t: float, tracks: dict[int, tuple[NDArray, NDArray]],
                 arrival: float) -> LiveEstimate:
        """One tracked frame smoothed (and, once, a warning when most frames are dropped)."""
        self._smoothed += 1
        if not self._warned and self._smoothed >= 30 and self.dropped > self._smoothed:
            self._warned = True
            warnings.warn(f"live: by frame {index} {self.dropped} frames were dropped and "
                          f"{self._smoothed} smoothed: this machine does not keep up with the "
                          "recording, and frames dropped before tracking break the tracks (the "
                          "estimate can run far off); --no-realtime estimates every frame",
                          LiveWarning, stacklevel=2)
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
        self._pool.shutdown(wait=False)
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
