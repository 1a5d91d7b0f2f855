"""A live source read, paced and tracked in a process of its own: :class:`ProcessSource`.

In one process the live loop's tracking cannot keep up beside the smoother, whatever runs it:
gtsam's updates and the compiled kernels hold Python's interpreter lock while they work, so a
tracking thread waits for them, and frames it reaches too late are not tracked (on
``apcc-graph bench live``, two of three frames at the videos' pace, although tracking alone
takes under two-thirds of a frame). A process of its own has its own interpreter: there a
:class:`~apcc_graph.estimation.live_feed.TrackedFeed` reads the source at its pace and tracks
every frame whatever the smoother does, and the frames cross to the loop tracked (their tracks,
a few kilobytes). What crosses is pickled over the process's standard input and output.

The source must then be described, not given as an iterator: a :class:`SourceSpec` (video
files, a bag and its topics, or camera devices), which the process opens itself. The process
is a fresh interpreter running this module (``python -m``), so it never imports the caller's
main script. A source read there is not paused for the loop's start search: a camera cannot
pause either, and the frames that arrive meanwhile are tracked (the tracks stay continuous)
and dropped by the loop's queue as any frame that waited too long.
"""

from __future__ import annotations

import os
import pickle
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import IO, Any

from apcc_graph.estimation.live_feed import QUEUE_FRAMES, Relayed, TrackedFeed
from apcc_graph.estimation.live_sources import Frame
from apcc_graph.frontend.tracking_process import end_process

TRACKING_SLACK = 0.4
"""Seconds beyond :data:`~apcc_graph.estimation.live_feed.MAX_BEHIND` that tracking in its
own process may fall behind before it steps over a frame: it is faster than the frames on
average and catches up after a slow frame (new corners, the machine busy), and every frame it
steps over breaks tracks, while a frame it tracks late costs only latency (beside a busy
Python thread, stepping over frames 0.1 s late left 143 of 600 untracked, 0.5 s late 100)."""


@dataclass(frozen=True)
class SourceSpec:
    """A live source a process can open by itself.

    Attributes:
        kind: ``"video"`` (one file per camera), ``"bag"`` (a ROS 1 bag or ROS 2 folder) or
            ``"devices"`` (OpenCV device indices).
        cameras: the robot's cameras, in the order of the files, topics or devices.
        paths: the video files, or the bag (one).
        topics: a bag's image topics, one per camera (``None``: found in the bag).
        devices: the device indices (``"devices"``).
        tolerance: seconds between one frame's images of different cameras (video, bag).
    """

    kind: str
    cameras: tuple[int, ...]
    paths: tuple[str, ...] = ()
    topics: tuple[str, ...] | None = None
    devices: tuple[int, ...] = ()
    tolerance: float | None = None

    def __post_init__(self) -> None:
        if self.kind not in ("video", "bag", "devices"):
            raise ValueError(f"SourceSpec.kind = {self.kind!r}: expected 'video', 'bag' or "
                             "'devices'")

    def frames(self) -> Iterator[Frame]:
        """The source's frames (:mod:`~apcc_graph.estimation.live_sources`).

        Raises:
            ValueError: a file, bag, topic or device that cannot be opened (named).
        """
        from apcc_graph.estimation.live_sources import device_frames, recording_frames
        from apcc_graph.frontend.recordings import bag_streams, video_streams

        if self.kind == "devices":
            return device_frames(list(self.devices), list(self.cameras))
        if self.kind == "video":
            streams = video_streams(list(self.paths))
        else:
            streams = bag_streams(self.paths[0], None if self.topics is None
                                  else list(self.topics), len(self.cameras))
        return recording_frames(streams, list(self.cameras), self.tolerance)


class ProcessSource:
    """The frames of ``spec`` tracked in a process (module docstring), as the :data:`~apcc_graph
    .estimation.live_feed.Relayed` items a relaying
    :class:`~apcc_graph.estimation.live_feed.TrackedFeed` takes: iterate once; :meth:`close`
    ends the process.

    Args:
        spec: the source.
        sizes: camera -> ``(width, height)`` of its images.
        realtime: read the source at its pace (else every frame, as fast as it goes).
        capacity: tracked frames waiting in the process to cross, at most (real time: the
            oldest is pushed out; else tracking waits).
    """

    def __init__(self, spec: SourceSpec, sizes: dict[int, tuple[int, int]], realtime: bool,
                 capacity: int = QUEUE_FRAMES) -> None:
        self._process = subprocess.Popen(
            [sys.executable, "-m", "apcc_graph.estimation.live_process"],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE)
        assert self._process.stdin is not None
        pickle.dump((spec, sizes, realtime, capacity), self._process.stdin,
                    protocol=pickle.HIGHEST_PROTOCOL)
        self._process.stdin.flush()

    def __iter__(self) -> Iterator[Relayed]:
        assert self._process.stdout is not None
        while True:
            try:
                kind, payload = pickle.load(self._process.stdout)
            except (EOFError, OSError):
                try:
                    code = self._process.wait(timeout=5.0)
                except subprocess.TimeoutExpired:
                    code = None
                if code != 0:
                    raise RuntimeError("the tracking process ended without its last message "
                                       f"(exit code {code})") from None
                return
            if kind == "error":
                raise payload
            if kind == "end":
                return
            yield payload

    def close(self) -> None:
        """End the process (closing its input stops it at the next frame; killed after 2 s)."""
        end_process(self._process, 2.0)


def _serve(inbox: IO[bytes], outbox: IO[bytes]) -> None:
    """The process: reads ``(spec, sizes, realtime, capacity)``, then tracks the source in a
    feed of its own and sends ``("frame", Relayed)`` for each frame, ``("end", None)`` at the
    end or ``("error", exception)``; stops when its input closes."""
    from apcc_graph.frontend.tracking import KLTTracker

    spec, sizes, realtime, capacity = pickle.load(inbox)
    trackers = {cam: KLTTracker(size) for cam, size in sizes.items()}
    pool = ThreadPoolExecutor(max_workers=max(len(trackers), 1))

    def track(images: dict[int, Any]) -> dict[int, Any]:
        """The cameras in parallel threads (OpenCV releases the interpreter)."""
        cams = sorted(images)
        found = pool.map(lambda cam: trackers[cam].update(images[cam]), cams)
        return dict(zip(cams, found, strict=True))

    def send(message: tuple[str, Any]) -> None:
        pickle.dump(message, outbox, protocol=pickle.HIGHEST_PROTOCOL)
        outbox.flush()

    try:
        feed = TrackedFeed(spec.frames(), track, realtime, time.monotonic, time.sleep,
                           capacity)
        feed.allowance = TRACKING_SLACK
    except Exception as error:  # noqa: BLE001 (given to the caller, raised there)
        send(("error", error))
        return
    def watch() -> None:  # the loop closed its end: stop (raw reads hold no Python lock)
        while os.read(inbox.fileno(), 4096):
            pass
        feed.close()

    threading.Thread(target=watch, daemon=True).start()
    try:
        while (frame := feed.get()) is not None:
            send(("frame", (frame, feed.arrivals(), feed.untracked, feed.overflow)))
        send(("end", None))
    except (BrokenPipeError, OSError):
        pass  # the loop is gone
    except Exception as error:  # noqa: BLE001
        send(("error", error))
    finally:
        feed.close()


if __name__ == "__main__":  # the process (module docstring); prints go to stderr
    _inbox, _outbox = sys.stdin.buffer, sys.stdout.buffer
    sys.stdout = sys.stderr
    _serve(_inbox, _outbox)
