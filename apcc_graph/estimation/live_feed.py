"""The tracking stage of the live loop: :class:`TrackedFeed` reads a frame source at its pace,
tracks each frame's images and queues the tracked frames for the smoother, in a thread of its
own, so tracking the next frame overlaps smoothing this one.

**Pace.** A source played in real time (``realtime``): a frame *arrives* at the wall time its
timestamp says, counted from the first (:meth:`TrackedFeed.resume` counts again from the next
frame, after a pause the loop chose). The feed waits for a frame that has not arrived yet, and
does not even track one that arrived more than :data:`MAX_BEHIND` ago when a newer one has
arrived too (tracking alone is then slower than the frames: the trackers step over it, counted
in :attr:`TrackedFeed.untracked`).

**Bounded queue.** At most ``capacity`` tracked frames wait for the smoother. In real time a
frame tracked while the queue is full pushes out the oldest waiting one (counted in
:attr:`TrackedFeed.overflow`): tracking never waits for the smoother, and what the smoother
takes next is never more than ``capacity`` frames old. Otherwise the feed waits for room, so
every frame is smoothed.

**Inline.** With ``threaded=False`` nothing runs in the background: :meth:`TrackedFeed.get`
tracks the next frame when the queue is empty, and then (real time) every further frame that
has already arrived by the clock (at most ``capacity``). The smoother's policy then sees the
same backlog as with the thread, deterministically under a controlled clock (the tests use
it), but tracking no longer overlaps smoothing.
"""

from __future__ import annotations

import threading
from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass

from numpy.typing import NDArray

MAX_BEHIND = 0.1
"""Seconds: a frame that arrived this long ago before its turn to be tracked is not tracked
(the trackers step over it), so tracking stays bounded when it alone is slower than the
frames."""

QUEUE_FRAMES = 4
"""Tracked frames waiting for the smoother, at most (the default ``capacity``)."""

Frame = tuple[int, float, dict[int, NDArray]]
"""``(index in the source, timestamp in seconds, camera -> image)``."""

Tracks = dict[int, tuple[NDArray, NDArray]]
"""Camera -> its track ids and pixels in the frame."""

Relayed = tuple["TrackedFrame", list[tuple[float, int]], int, int]
"""A frame tracked in another process (:mod:`~apcc_graph.estimation.live_process`), the
``(timestamp, index)`` of the frames that arrived there since the last, and its counts of
frames not tracked and pushed out of its queue so far."""


@dataclass(frozen=True)
class TrackedFrame:
    """A frame tracked and waiting for the smoother.

    Attributes:
        index: the frame's index in the source.
        timestamp: seconds (the source's clock).
        tracks: each camera's track ids and pixels.
        arrival: the wall time it arrived (the clock's seconds).
    """

    index: int
    timestamp: float
    tracks: Tracks
    arrival: float


class TrackedFeed:
    """Frames of ``source`` tracked by ``track`` (module docstring); :meth:`get` takes them in
    order, :meth:`close` stops the feed.

    Args:
        source: the frames, in time order.
        track: a frame's images -> its tracks (the live loop's trackers); ``None``: the source
            gives :data:`Relayed` frames, paced and tracked in another process (they join the
            queue as they come).
        realtime: play the source at its own pace (module docstring).
        clock, sleep: wall time (seconds) and waiting.
        capacity: tracked frames waiting, at most.
        threaded: track in a background thread (``False``: inline, module docstring).

    Attributes:
        tracked: frames tracked so far.
        untracked: frames not tracked (real time: they arrived more than :data:`MAX_BEHIND`
            before their turn).
        overflow: tracked frames pushed out of the full queue (real time).
        deepest: the most tracked frames that waited at once.
        allowance: seconds added to :data:`MAX_BEHIND` (inline, the loop sets it to its last
            smoothing's: the frames that arrived meanwhile are all tracked).
    """

    def __init__(self, source: Iterator[Frame] | Iterator[Relayed],
                 track: Callable[[dict[int, NDArray]], Tracks] | None,
                 realtime: bool, clock: Callable[[], float], sleep: Callable[[float], None],
                 capacity: int = QUEUE_FRAMES, threaded: bool = True) -> None:
        if capacity < 1:
            raise ValueError(f"TrackedFeed capacity = {capacity}: expected at least 1 frame")
        self._source, self._track = iter(source), track
        self._relay = track is None  # the source gives frames paced and tracked elsewhere
        self.realtime, self.clock, self.sleep = realtime, clock, sleep
        self.capacity, self.threaded = capacity, threaded
        self.tracked = self.untracked = self.deepest = 0
        self._overflow_here = self._overflow_there = 0
        self.allowance = 0.0
        self._queue: deque[TrackedFrame] = deque()
        self._arrivals: deque[tuple[float, int]] = deque()  # not yet taken by ``arrivals``
        self._lock = threading.Condition()
        self._next: Frame | None = (  # read ahead: has it arrived?
            None if self._relay else next(self._source, None))  # type: ignore[arg-type]
        self._start: tuple[float, float] | None = None  # wall time and source time of a frame
        self._ended = self._closed = self._paused = False
        self._error: BaseException | None = None
        self._thread: threading.Thread | None = None
        if threaded:
            self._thread = threading.Thread(target=self._run, name="apcc-graph tracking",
                                            daemon=True)
            self._thread.start()

    # ------------------------------------------------------------------ the consumer's side
    def get(self) -> TrackedFrame | None:
        """The oldest tracked frame waiting (waits for one); ``None`` once the source ended.

        Raises:
            Exception: what tracking raised (a wrong image), once the frames before it are
                taken.
        """
        if not self.threaded:
            while not self._queue and self._step(wait=True):
                pass
            while (self.realtime and self._queue and len(self._queue) < self.capacity
                   and self._arrived()):
                self._step(wait=False)
        with self._lock:
            while not self._queue and not self._ended:
                self._lock.wait()
            if self._queue:
                frame = self._queue.popleft()
                self._lock.notify_all()
                return frame
            if self._error is not None:
                raise self._error
            return None

    def arrivals(self) -> list[tuple[float, int]]:
        """The ``(timestamp, index)`` of the frames that arrived since the last call, tracked
        or not, in order (for the loop's rate monitor)."""
        with self._lock:
            out = list(self._arrivals)
            self._arrivals.clear()
        return out

    @property
    def backlog(self) -> int:
        """Tracked frames waiting now (newer than the last one :meth:`get` gave)."""
        with self._lock:
            return len(self._queue)

    @property
    def overflow(self) -> int:
        """Tracked frames pushed out of a full queue (real time), here and where they were
        tracked."""
        return self._overflow_here + self._overflow_there

    @property
    def exhausted(self) -> bool:
        """Whether the source has no frame left to track (the queue may still hold some)."""
        with self._lock:
            return self._ended or (self._next is None and not self._relay)

    def pause(self) -> None:
        """Stop reading the source until :meth:`resume` (the loop's own pause, e.g. the start
        search): a frame being tracked still joins the queue."""
        with self._lock:
            self._paused = True

    def resume(self) -> None:
        """Read on; in real time the next frame arrives now and the others at their pace
        from it (a recording's replay resumes where it paused)."""
        with self._lock:
            self._paused = False
            self._start = None
            self._lock.notify_all()

    def close(self) -> None:
        """Stop tracking (the frame being tracked is finished and dropped) and wait for the
        thread."""
        with self._lock:
            self._closed = True
            self._lock.notify_all()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join()

    # ------------------------------------------------------------------ the tracking side
    def _run(self) -> None:
        try:
            while self._step(wait=True):
                pass
        except BaseException as error:  # given to the consumer by ``get``
            with self._lock:
                self._error = error
        finally:
            with self._lock:
                self._ended = True
                self._lock.notify_all()

    def _arrived(self) -> bool:
        """Whether the next frame of the source has arrived (real time; always otherwise)."""
        if self._next is None:
            return False
        if not self.realtime or self._start is None:
            return True
        return self._start[0] + (self._next[1] - self._start[1]) <= self.clock()

    def _step(self, wait: bool) -> bool:
        """Read, pace and track the source's next frame into the queue; ``False`` once the
        source ended or the feed closed."""
        with self._lock:
            while self._paused and not self._closed:
                self._lock.wait()
        if self._relay and not self._closed:
            return self._relayed()
        if self._closed or self._next is None:
            with self._lock:
                self._ended = True
                self._lock.notify_all()
            return False
        index, t, images = self._next
        if self._start is None:
            self._start = (self.clock(), t)
        arrival = self._start[0] + (t - self._start[1])
        if self.realtime and wait and arrival > self.clock():
            self.sleep(arrival - self.clock())
        with self._lock:
            self._arrivals.append((t, index))
        self._next = next(self._source, None)
        if (self.realtime and self.clock() - arrival > MAX_BEHIND + self.allowance
                and self._arrived()):
            self.untracked += 1  # tracking is too far behind and a newer frame is there
            return True
        frame = TrackedFrame(index, t, self._track(images), arrival)
        self.tracked += 1
        self._enqueue(frame)
        return True

    def _relayed(self) -> bool:
        """The next frame tracked elsewhere, into the queue, with what happened there."""
        item = next(self._source, None)  # type: ignore[call-overload]
        if item is None:
            with self._lock:
                self._ended = True
                self._lock.notify_all()
            return False
        frame, arrivals, untracked, overflow = item
        with self._lock:
            self._arrivals.extend(arrivals)
            self.untracked, self._overflow_there = untracked, overflow
        self.tracked += 1
        self._enqueue(frame)
        return True

    def _enqueue(self, frame: TrackedFrame) -> None:
        with self._lock:
            if self.realtime:
                if len(self._queue) >= self.capacity:
                    self._queue.popleft()
                    self._overflow_here += 1
            else:
                while len(self._queue) >= self.capacity and not self._closed:
                    self._lock.wait()
            if not self._closed:
                self._queue.append(frame)
                self.deepest = max(self.deepest, len(self._queue))
            self._lock.notify_all()
