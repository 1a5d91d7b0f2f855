"""Live estimation: each frame tracked and smoothed as it arrives (``apcc-graph live``).

:meth:`LiveEstimator.run` is the loop, an iterator over :class:`LiveEstimate`, in two stages
that overlap:

1. **tracking** (:class:`~apcc_graph.estimation.live_feed.TrackedFeed`, a thread of its own):
   a source gives frames in time order, each with one image per camera
   (:func:`~apcc_graph.estimation.live_sources.recording_frames` for a bag or video files;
   :func:`~apcc_graph.estimation.live_sources.device_frames` for cameras plugged in); each
   camera's :class:`~apcc_graph.frontend.tracking.KLTTracker` follows its tracks into the new
   image (the cameras in parallel threads: OpenCV releases the interpreter), and the tracked
   frame joins a bounded queue;
2. **smoothing**: the :class:`~apcc_graph.estimation.smoother.FixedLagSmoother` takes the
   queue's frames in order; each frame's estimate is yielded at once, with the frames that
   left the window since (their final estimates), the rate and the latency. With keyframes a
   frame between keyframes comes out with its fit to the window's points (``pending``), and
   the keyframe's solve smooths it later; its final estimate follows in ``final``.

**Real time and overload.** A recording is played at its own pace (``realtime``): a frame
*arrives* at the wall time its timestamp says, counted from the first. Under overload the
loop gives up, in this order:

1. *keyframe candidates* (with keyframes): while tracked frames wait, a keyframe the rule asks
   for waits too (the smoother is told it is busy), up to the rule's ``max_deferral`` since the
   last; the frames still get their estimates at once;
2. *frames from smoothing*: a tracked frame after which :data:`DROP_BACKLOG` frames (one
   without keyframes) already wait is not smoothed, unless the last smoothed frame is
   :data:`MAX_GAP` old; it is dropped from the estimate (counted), and the tracks stay as
   continuous as offline (dropping frames before tracking broke them: 60 to 120 degrees off on
   ``apcc-graph bench live``); a full queue drops its oldest frame the same way;
3. *frames from tracking*, last: a frame the tracking stage reaches more than
   :data:`~apcc_graph.estimation.live_feed.MAX_BEHIND` after it arrived, while a newer one is
   there, is not tracked (the trackers step over it).

A camera device delivers its newest image when asked (OpenCV's buffer of one), so it drops by
itself. When fewer frames are smoothed than arrive by a margin over the first second already,
a :class:`LiveWarning` says both rates
(:class:`~apcc_graph.estimation.live_guards.RateMonitor`).

**Where tracking runs** (``tracking``): ``"process"`` (the default) reads a source described by a
:class:`~apcc_graph.estimation.live_process.SourceSpec` and tracks it in a process of its own
(:mod:`~apcc_graph.estimation.live_process`: in this one, gtsam's updates hold the interpreter
and starve a tracking thread), and sends the images of a source given as an iterator to a
:class:`~apcc_graph.frontend.tracking_process.TrackingProcess`; ``"thread"`` tracks in a thread
of this process, the cameras in threads; ``"inline"`` in the loop's own thread (no overlap;
the same policy, deterministic under a controlled clock).

**Unknown start.** Without ``theta0`` the first second of tracked frames is kept, the start is
searched in it as ``estimate`` searches it (:func:`~apcc_graph.estimation.start_search.
find_start`; 2 s, then 4 s when the robot barely moved), and the smoother then starts there,
held with the search's sigma, and takes the kept frames first (in real time one per
:data:`MAX_GAP`). Every frame is tracked while they are kept; the source is paused during the
search, and a recording's replay resumes where it paused (its frames are not dropped for the
search's time). If 4 s do not tell the start, a :class:`LiveWarning` says so and the best guess
is held loosely.

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
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from apcc_graph.estimation.blackout import stacked_tracks
from apcc_graph.estimation.live_feed import MAX_BEHIND, QUEUE_FRAMES, TrackedFeed, TrackedFrame
from apcc_graph.estimation.live_guards import LimitGuard, LiveWarning, RateMonitor
from apcc_graph.estimation.live_process import ProcessSource, SourceSpec
from apcc_graph.estimation.live_results import LiveEstimate, LiveFrame
from apcc_graph.estimation.live_sources import Frame, device_frames, recording_frames
from apcc_graph.estimation.options import GraphOptions
from apcc_graph.estimation.smoother import FixedLagSmoother
from apcc_graph.estimation.smoother.keyframing import PENDING
from apcc_graph.estimation.smoother_options import SmootherOptions
from apcc_graph.estimation.window import SmootherFrame
from apcc_graph.frontend.tracking import KLTTracker
from apcc_graph.frontend.tracking_process import TrackingProcess
from apcc_graph.model.robot import Robot
from apcc_graph.model.sequence import FrameObservations
from apcc_graph.model.sequence import Sequence as Recording

MAX_GAP = 0.2
"""Seconds of the source: under overload a frame is smoothed anyway when the last smoothed
frame is this old (the smoother then sees at least five frames a second; with gaps of half a
second it took each for a pause, re-acquired, and ran 100 degrees off)."""
TRACKING = ("process", "thread", "inline")
"""Where the live loop tracks the cameras (module docstring)."""

DROP_BACKLOG = 2
"""With keyframes, a frame is dropped from smoothing only when this many tracked frames wait
behind it (a frame between keyframes costs a fraction of a solve, so the smoother catches up by
deferring keyframes first); without, one waiting frame drops it."""

START_WINDOWS = (1.0, 2.0, 4.0)
"""Seconds of the first frames the unknown start is searched in, in turn, until one tells it."""

__all__ = ["MAX_BEHIND", "LiveEstimate", "LiveEstimator", "LiveFrame", "LiveWarning",
           "device_frames", "live_estimates", "recording_frames"]


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
        tracking: where the cameras are tracked, one of :data:`TRACKING` (module docstring).
        queue: tracked frames waiting for the smoother, at most.

    Attributes:
        feed: the last run's tracking stage (its counts: ``tracked``, ``untracked``,
            ``overflow``, ``deepest``), ``None`` before a run.
    """

    def __init__(self, robot: Robot, theta0: ArrayLike | None = None,
                 settings: SmootherOptions | None = None, realtime: bool = True,
                 clock: Callable[[], float] = time.monotonic,
                 sleep: Callable[[float], None] = time.sleep,
                 graph: GraphOptions | None = None, tracking: str = "process",
                 queue: int = QUEUE_FRAMES) -> None:
        if tracking not in TRACKING:
            raise ValueError(f"LiveEstimator tracking = {tracking!r}: expected one of "
                             f"{', '.join(TRACKING)}")
        self.robot, self.settings = robot, settings
        self.graph = GraphOptions() if graph is None else graph
        self.smoother = None if theta0 is None else self._smoother(theta0, self.graph)
        self.start_search: str | None = None  # what the start search found, when it ran
        self.trackers = {cam: KLTTracker((c.width, c.height))
                         for cam, c in enumerate(robot.cameras) if c is not None}
        self.realtime, self.clock, self.sleep = realtime, clock, sleep
        self.interrupted = False  # ``run`` stopped on its ``stop`` event
        self.limits = LimitGuard(np.array([seg.theta_max for seg in robot.segments]))
        self.rate = RateMonitor()
        self._done: deque[float] = deque()
        self._index: dict[int, int] = {}  # the smoother's frame -> the source's index
        self._kept: list[TrackedFrame] = []
        self._broken = False  # an exception left the smoother mid-update
        self._window = 0  # the start search's next window (START_WINDOWS)
        self.tracking, self.queue = tracking, queue
        self.feed: TrackedFeed | None = None
        self._tracking: TrackingProcess | None = None
        self._remote: ProcessSource | None = None
        self._dropped_here = 0  # dropped by the smoothing stage's policy
        self._pool = ThreadPoolExecutor(max_workers=max(len(self.trackers), 1))

    @property
    def dropped(self) -> int:
        """Frames of the source not smoothed so far: not tracked, pushed out of the full queue,
        or tracked and passed over by the smoothing stage (module docstring)."""
        feed = self.feed
        extra = 0 if feed is None else feed.untracked + feed.overflow
        return self._dropped_here + extra

    def run(self, frames: Iterator[Frame] | SourceSpec, stop: threading.Event | None = None
            ) -> Iterator[LiveEstimate]:
        """An estimate per smoothed frame of ``frames``
        (:func:`~apcc_graph.estimation.live_sources.recording_frames`,
        :func:`~apcc_graph.estimation.live_sources.device_frames`, or a
        :class:`~apcc_graph.estimation.live_process.SourceSpec`: read and tracked in a process
        of its own, module docstring), until the source ends,
        ``stop`` is set (checked between frames: :attr:`interrupted` then says so) or the
        iterator is closed."""
        self.feed = feed = self._feed(frames)
        smoothed = -np.inf  # source time of the last smoothed frame
        try:
            while True:
                if stop is not None and stop.is_set():
                    self.interrupted = True
                    break  # frames kept for the start search are still searched and smoothed
                frame = feed.get()
                self._count_arrivals(feed)
                if frame is None:
                    break
                if self.smoother is None:  # the start is still being searched for
                    self._kept.append(frame)
                    ended = feed.backlog == 0 and feed.exhausted
                    if self._search_due(ended):
                        feed.pause()
                        if self._search_start(ended):
                            yield from self._kept_frames()
                            smoothed = frame.timestamp
                        feed.resume()  # a recording's replay resumes after the search
                    continue
                backlog = feed.backlog
                limit = 1 if self._keys_off() else DROP_BACKLOG
                if self.realtime and backlog >= limit and frame.timestamp - smoothed < MAX_GAP:
                    self._dropped_here += 1  # tracked, not smoothed: newer frames wait
                    continue
                smoothed = frame.timestamp
                began = self.clock()
                yield self._process(frame, busy=self.realtime and backlog > 0)
                if self.tracking == "inline":  # tracking waited for this smoothing
                    feed.allowance = self.clock() - began
        finally:  # the processes first: the feed's thread may wait on one
            for stage in (self._tracking, self._remote):
                if stage is not None:
                    stage.close()
            self._tracking = self._remote = None
            feed.close()
        if self.smoother is None and self._kept:  # a source shorter than the search, or stopped
            self._search_start(ended=True)
            yield from self._kept_frames()

    def _feed(self, frames: Iterator[Frame] | SourceSpec) -> TrackedFeed:
        """The tracking stage of a run (module docstring; a source read in a process only on
        the wall clock: a controlled clock is this process's)."""
        sizes = {cam: (c.width, c.height) for cam, c in enumerate(self.robot.cameras)
                 if c is not None}
        if isinstance(frames, SourceSpec):
            if self.tracking == "process" and self.clock is time.monotonic:
                self._remote = ProcessSource(frames, sizes, self.realtime, self.queue)
                return TrackedFeed(iter(self._remote), None, self.realtime, self.clock,
                                   self.sleep, self.queue)
            frames = frames.frames()
        if self.tracking == "process":
            self._tracking = TrackingProcess(sizes)
        return TrackedFeed(frames, self._track, self.realtime, self.clock, self.sleep,
                           self.queue, threaded=self.tracking != "inline")

    def _keys_off(self) -> bool:
        """Whether the smoother solves at every frame (no keyframes to defer)."""
        return self.settings is None or self.settings.keyframes is None

    def _count_arrivals(self, feed: TrackedFeed) -> None:
        """The frames that arrived since, to the rate monitor (real time, once smoothing)."""
        for t, index in feed.arrivals():
            if self.realtime and self.smoother is not None:
                self.rate.arrived(t, index)

    def _kept_frames(self) -> Iterator[LiveEstimate]:
        """The frames kept for the start search, smoothed (in real time one per
        :data:`MAX_GAP` of the source and the last: the others count as dropped)."""
        kept, self._kept = self._kept, []
        last = -np.inf
        for k, frame in enumerate(kept):
            if self.realtime and frame.timestamp - last < MAX_GAP and k < len(kept) - 1:
                self._dropped_here += 1
                continue
            last = frame.timestamp
            yield self._process(frame, count=False)
        self.rate.restart()  # the search's own pause is not an overload

    def _search_due(self, ended: bool) -> bool:
        """Whether the kept frames span the next of :data:`START_WINDOWS` (or the source
        ended)."""
        span = self._kept[-1].timestamp - self._kept[0].timestamp
        return ended or span + 1e-9 >= START_WINDOWS[self._window]

    def _search_start(self, ended: bool) -> bool:
        """The start searched in the kept frames once they span the next of
        :data:`START_WINDOWS` (or the source ended); whether the smoother now exists."""
        from apcc_graph.estimation.start_search import FIRM_SIGMA, PRIOR_SIGMA, find_start

        if not self._search_due(ended):
            return False
        span = self._kept[-1].timestamp - self._kept[0].timestamp
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
        return Recording(self.robot, [kept.timestamp for kept in self._kept],
                         stacked_tracks(self.robot.camera_segments,
                                        [kept.tracks for kept in self._kept]))

    def _track(self, images: dict[int, NDArray]) -> dict[int, tuple[NDArray, NDArray]]:
        """Each camera's tracks in its new image: in the tracking process if there is one, else
        the cameras in parallel threads (OpenCV's optical flow and corner detection release
        the interpreter)."""
        if self._tracking is not None:
            return self._tracking.track(images)
        cams = sorted(images)
        found = self._pool.map(lambda cam: self.trackers[cam].update(images[cam]), cams)
        return dict(zip(cams, found, strict=True))

    def _process(self, frame: TrackedFrame, count: bool = True, busy: bool = False
                 ) -> LiveEstimate:
        """One tracked frame smoothed (and, once, a warning when the smoothed rate falls
        behind the recording's; not for the frames kept during the start search); ``busy``:
        newer frames wait (a keyframe may wait too)."""
        assert self.smoother is not None
        index, t, arrival = frame.index, frame.timestamp, frame.arrival
        if count and self.realtime:
            self.rate.smoothed(t)
        try:
            estimate = self.smoother.update(FrameObservations(t, frame.tracks), busy=busy)
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
