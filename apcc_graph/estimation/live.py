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
waited more than :data:`MAX_BEHIND` beyond the last smoothing while newer frames arrived (then
the trackers step over it). A tracked frame after which a newer one has already arrived is not
smoothed, unless the last smoothed frame is :data:`MAX_GAP` old: it is dropped from the
estimate (counted), and the smoother takes a newer one: the lag stays bounded, and the
smoother sees a lower frame rate with the same tracks (dropping frames before tracking broke
the tracks: 60 to 120 degrees off on ``apcc-graph bench live``). A camera device delivers its
newest image when asked (OpenCV's buffer of one), so it drops by itself. When fewer frames are
smoothed than arrive by a margin over the first second already, a :class:`LiveWarning` says
both rates (:class:`~apcc_graph.estimation.live_guards.RateMonitor`).

**Unknown start.** Without ``theta0`` the first second of tracked frames is kept, the start is
searched in it as ``estimate`` searches it (:func:`~apcc_graph.estimation.start_search.
find_start`; 2 s, then 4 s when the robot barely moved), and the smoother then starts there,
held with the search's sigma, and takes the kept frames first (in real time one per
:data:`MAX_GAP`). Every frame is tracked while they are kept, and a recording's replay resumes
after the search where it paused (its frames are not dropped for the search's time). If 4 s do
not tell the start, a :class:`LiveWarning` says so and the best guess is held loosely.

**Joint limits.** An angle beyond its segment's ``theta_max`` is clamped and flagged, with a
:class:`LiveWarning` (:class:`~apcc_graph.estimation.live_guards.LimitGuard`).

**Stopping.** ``run(frames, stop=event)`` ends at the next frame boundary once ``event`` is
set (:func:`~apcc_graph.estimation.live_guards.deferred_interrupts` sets it on Ctrl-C), so an
interrupt never lands inside a gtsam update; :meth:`LiveEstimator.finish` then smooths the
window. Stopped while the start is still searched, ``run`` first searches it in the frames kept
so far (a :class:`LiveWarning` when they do not tell it) and smooths them. If an exception left
the smoother mid-update, ``finish`` gives nothing rather than touch the inconsistent solver.
"""

from __future__ import annotations

import math
import threading
import time
import warnings
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from apcc_graph.estimation.blackout import stacked_tracks
from apcc_graph.estimation.live_guards import LimitGuard, LiveWarning, RateMonitor
from apcc_graph.estimation.options import GraphOptions
from apcc_graph.estimation.smoother import FixedLagSmoother
from apcc_graph.estimation.smoother.keyframing import PENDING
from apcc_graph.estimation.smoother_options import SmootherOptions
from apcc_graph.estimation.window import SmootherFrame
from apcc_graph.frontend.recordings import CameraStream, match_frames
from apcc_graph.frontend.tracking import KLTTracker
from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.robot import Robot
from apcc_graph.model.sequence import FrameObservations
from apcc_graph.model.sequence import Sequence as Recording

MAX_GAP = 0.2
"""Seconds of the source: under overload a frame is smoothed anyway when the last smoothed
frame is this old (the smoother then sees at least five frames a second; with gaps of half a
second it took each for a pause, re-acquired, and ran 100 degrees off)."""
MAX_BEHIND = 0.1
"""Seconds: a frame that has waited this long beyond the last smoothing's duration while
newer ones arrived is not even tracked (the trackers then step over it), so the lag stays
bounded when tracking alone is slower than the frames. The frames that arrived during one
smoothing are all tracked: skipping them made KLT steps of several frames under overload, and
broken tracks sent the estimate tens of degrees off."""

START_WINDOWS = (1.0, 2.0, 4.0)
"""Seconds of the first frames the unknown start is searched in, in turn, until one tells it."""

Frame = tuple[int, float, dict[int, NDArray]]
"""``(index in the source, timestamp in seconds, camera -> image)``."""

__all__ = ["LiveEstimate", "LiveEstimator", "LiveFrame", "LiveWarning", "device_frames",
           "live_estimates", "recording_frames"]


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
        theta0: the starting configuration (radians), or ``None``: searched in the first
            frames (module docstring).
        settings: the smoother's settings.
        graph: the measurement model (with ``model_sigma``, model error as noise); its
            ``theta0_sigma`` is replaced by the start search's when it runs.
        realtime: play the source at its own pace, dropping frames under overload; ``False``
            processes every frame as fast as it can (nothing dropped).
        clock, sleep: wall time (seconds) and waiting, replaceable in tests.
    """

    def __init__(self, robot: Robot, theta0: ArrayLike | None = None,
                 settings: SmootherOptions | None = None, realtime: bool = True,
                 clock: Callable[[], float] = time.monotonic,
                 sleep: Callable[[float], None] = time.sleep,
                 graph: GraphOptions | None = None) -> None:
        self.robot, self.settings = robot, settings
        self.graph = GraphOptions() if graph is None else graph
        self.smoother = None if theta0 is None else self._smoother(theta0, self.graph)
        self.start_search: str | None = None  # what the start search found, when it ran
        self.trackers = {cam: KLTTracker((c.width, c.height))
                         for cam, c in enumerate(robot.cameras) if c is not None}
        self.realtime, self.clock, self.sleep = realtime, clock, sleep
        self.dropped = 0
        self.interrupted = False  # ``run`` stopped on its ``stop`` event
        self.limits = LimitGuard(np.array([seg.theta_max for seg in robot.segments]))
        self.rate = RateMonitor()
        self._done: deque[float] = deque()
        self._index: dict[int, int] = {}  # the smoother's frame -> the source's index
        self._kept: list[tuple[int, float, dict[int, tuple[NDArray, NDArray]], float]] = []
        self._broken = False  # an exception left the smoother mid-update
        self._window = 0  # the start search's next window (START_WINDOWS)
        self._smoothing = 0.0  # seconds the last smoothed frame took
        self._pool = ThreadPoolExecutor(max_workers=max(len(self.trackers), 1))

    def run(self, frames: Iterator[Frame], stop: threading.Event | None = None
            ) -> Iterator[LiveEstimate]:
        """An estimate per smoothed frame of ``frames`` (:func:`recording_frames`,
        :func:`device_frames`), until the source ends, ``stop`` is set (checked between
        frames: :attr:`interrupted` then says so) or the iterator is closed."""
        source = iter(frames)
        pending = next(source, None)
        start: tuple[float, float] | None = None  # wall time and source time of the first
        smoothed = -np.inf  # source time of the last smoothed frame
        while pending is not None:
            if stop is not None and stop.is_set():
                self.interrupted = True
                break  # frames kept for the start search are still searched and smoothed
            index, t, images = pending
            start = start or (self.clock(), t)
            arrival = start[0] + (t - start[1])
            pending = next(source, None)
            if self.realtime and self.smoother is not None:  # not while the start is searched
                self.rate.arrived(t, index)
            if self.realtime:
                if arrival > self.clock():
                    self.sleep(arrival - self.clock())
                elif (self.smoother is not None and self._waiting(pending, start)
                      and self.clock() - arrival > MAX_BEHIND + self._smoothing):
                    self.dropped += 1  # too far behind even to track it
                    continue
            tracks = self._track(images)
            if self.smoother is None:  # the start is still being searched for
                self._kept.append((index, t, tracks, arrival))
                if self._search_start(ended=pending is None):
                    yield from self._kept_frames()
                    smoothed = t
                    start = (self.clock(), t)  # a recording's replay resumes after the search
                continue
            if self.realtime and self._waiting(pending, start) and t - smoothed < MAX_GAP:
                self.dropped += 1  # tracked, not smoothed: a newer frame is waiting
                continue
            smoothed = t
            began = self.clock()
            estimate = self._process(index, t, tracks, arrival)
            self._smoothing = self.clock() - began
            yield estimate
        if self.smoother is None and self._kept:  # a source shorter than the search, or stopped
            self._search_start(ended=True)
            yield from self._kept_frames()

    def _kept_frames(self) -> Iterator[LiveEstimate]:
        """The frames kept for the start search, smoothed (in real time one per
        :data:`MAX_GAP` of the source and the last: the others count as dropped)."""
        kept, self._kept = self._kept, []
        last = -np.inf
        for k, (index, t, tracks, arrival) in enumerate(kept):
            if self.realtime and t - last < MAX_GAP and k < len(kept) - 1:
                self.dropped += 1
                continue
            last = t
            yield self._process(index, t, tracks, arrival, count=False)
        self.rate.restart()  # the search's own pause is not an overload

    def _search_start(self, ended: bool) -> bool:
        """The start searched in the kept frames once they span the next of
        :data:`START_WINDOWS` (or the source ended); whether the smoother now exists."""
        from apcc_graph.estimation.start_search import FIRM_SIGMA, PRIOR_SIGMA, find_start

        span = self._kept[-1][1] - self._kept[0][1]
        if not ended and span + 1e-9 < START_WINDOWS[self._window]:
            return False
        recording = self._recording()
        found = None
        if recording.n_frames >= 2:
            found = find_start(recording, span + 1.0, max_sigma=FIRM_SIGMA)
            if not found.determined and not ended and self._window + 1 < len(START_WINDOWS):
                self._window += 1  # wait for a longer window
                return False
        if found is None or not found.determined:
            why = "a single frame" if found is None else found.reason
            theta0 = np.zeros(self.robot.n_segments) if found is None else found.theta0
            sigma = PRIOR_SIGMA
            warnings.warn(f"live: the start is not determined ({why}); starting from "
                          f"{', '.join(f'{math.degrees(v):.1f}' for v in theta0)} deg held "
                          f"with {math.degrees(sigma):.0f} deg; --theta0-deg gives it",
                          LiveWarning, stacklevel=3)
        else:
            theta0, sigma = found.theta0, float(np.nanmax(found.sigma0))
        theta0 = np.clip(theta0, -self.limits.theta_max, self.limits.theta_max)
        self.start_search = (f"start searched in the first {span:.2f} s: "
                             f"{', '.join(f'{math.degrees(v):.2f}' for v in theta0)} deg "
                             f"(sigma {math.degrees(sigma):.2f} deg)")
        self.smoother = self._smoother(theta0, replace(self.graph, theta0_sigma=sigma))
        return True

    def _smoother(self, theta0: ArrayLike, graph: GraphOptions) -> FixedLagSmoother:
        return FixedLagSmoother(self.robot, theta0=theta0, settings=self.settings, options=graph)

    def _recording(self) -> Recording:
        """The kept frames as a recording (frame k: the k-th kept)."""
        return Recording(self.robot, [kept[1] for kept in self._kept],
                         stacked_tracks(self.robot.camera_segments,
                                        [kept[2] for kept in self._kept]))

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
                 arrival: float, count: bool = True) -> LiveEstimate:
        """One tracked frame smoothed (and, once, a warning when the smoothed rate falls
        behind the recording's; not for the frames kept during the start search)."""
        assert self.smoother is not None
        if count and self.realtime:
            self.rate.smoothed(t)
        try:
            estimate = self.smoother.update(FrameObservations(t, tracks))
        except BaseException:
            self._broken = True  # gtsam may be mid-update: never touched again
            raise
        self._index[estimate.frame] = index
        final = self._numbered(self.smoother.pop_final())
        now = self.clock()
        self._done.append(now)
        while self._done[0] < now - 1.0:
            self._done.popleft()
        thetas, clamped = self.limits.clamp(index, estimate.thetas, final=False)
        return LiveEstimate(index, t, thetas, estimate.sigmas, final,
                            max(now - arrival, 0.0) if self.realtime else 0.0,
                            float(len(self._done)), self.dropped, clamped,
                            bool(np.any(estimate.status == PENDING)))

    def finish(self) -> list[LiveFrame]:
        """The final estimates of the frames still in the window (the others came with the
        estimates, in ``final``); nothing if an exception left the smoother mid-update."""
        self._pool.shutdown(wait=False)
        if self.smoother is None or self._broken:
            return []
        return self._numbered(self.smoother.finish())

    def _numbered(self, frames: list[SmootherFrame]) -> list[LiveFrame]:
        """Final estimates numbered by the source's frame index, clamped to the limits."""
        out = []
        for fr in frames:
            index = self._index.pop(fr.frame, fr.frame)
            thetas, clamped = self.limits.clamp(index, fr.thetas, final=True)
            out.append(LiveFrame(index, fr.timestamp, thetas, fr.sigmas, clamped))
        return out


def live_estimates(frames: Iterator[Frame], robot: Robot, theta0: ArrayLike | None = None,
                   settings: SmootherOptions | None = None, realtime: bool = True,
                   stop: threading.Event | None = None,
                   graph: GraphOptions | None = None) -> Iterator[LiveEstimate]:
    """:meth:`LiveEstimator.run` of a new :class:`LiveEstimator` (without its
    :meth:`~LiveEstimator.finish`: the last lag's frames then have only their filtered
    estimates)."""
    return LiveEstimator(robot, theta0, settings, realtime, graph=graph).run(frames, stop)
