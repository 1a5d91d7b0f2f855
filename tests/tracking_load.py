"""Does tracking keep up beside the smoother? ``python tests/tracking_load.py [frames] [seed]``.

Renders the live benchmark's three 640x480 videos (``apcc-graph bench live``'s robot and room,
30 fps; ``frames`` of them, default 300, seeded), then tracks them at the videos' pace:

- **alone**: a tracking stage (:class:`~apcc_graph.estimation.live_feed.TrackedFeed`) with
  nothing else running, tracked in a thread of this process and in a process of its own;
- **beside the smoother**: the same while this process runs the fixed-lag smoother over a
  simulated recording as fast as it can (the load of the live loop: gtsam's updates and the
  compiled kernels hold Python's interpreter lock while they work).

Prints, per case, the frames tracked and not tracked (a frame that tracking reaches too late
while a newer one has arrived is stepped over) and the milliseconds a frame took to cross the
stage (arrival to queue: median and 95th percentile).
"""

from __future__ import annotations

import sys
import tempfile
import threading
import time
import warnings
from pathlib import Path

import numpy as np

from apcc_graph.bench.live import ROBOT_FILE, render_videos
from apcc_graph.bench.smoother import room_simulation
from apcc_graph.estimation.live_feed import TrackedFeed
from apcc_graph.estimation.live_process import ProcessSource, SourceSpec
from apcc_graph.estimation.smoother import FixedLagSmoother
from apcc_graph.frontend.tracking import KLTTracker
from apcc_graph.io.robot_file import load_robot


def _load(stop: threading.Event) -> None:
    """The smoother over a simulated recording, again and again, until ``stop``."""
    robot = load_robot(ROBOT_FILE)
    seq = room_simulation(robot, 300, 0.1, 0).sequence
    warnings.simplefilter("ignore")
    while not stop.is_set():
        smoother = FixedLagSmoother(robot, theta0=seq.thetas[0])
        for f in range(seq.n_frames):
            if stop.is_set():
                return
            smoother.update(seq.frame(f))
            smoother.pop_final()


def _stage(spec: SourceSpec, where: str) -> TrackedFeed:
    sizes = {cam: (640, 480) for cam in spec.cameras}
    if where == "process":
        source = ProcessSource(spec, sizes, realtime=True)
        feed = TrackedFeed(iter(source), None, True, time.monotonic, time.sleep)
        feed.source = source  # type: ignore[attr-defined]
        return feed
    trackers = {cam: KLTTracker(size) for cam, size in sizes.items()}
    return TrackedFeed(spec.frames(), lambda images: {c: trackers[c].update(im)
                                                      for c, im in images.items()},
                       True, time.monotonic, time.sleep)


def run(spec: SourceSpec, where: str, loaded: bool) -> str:
    """One case's line."""
    stop = threading.Event()
    load = threading.Thread(target=_load, args=(stop,), daemon=True)
    if loaded:
        load.start()
        time.sleep(3.0)  # the smoother under way
    feed = _stage(spec, where)
    crossing = []
    while (frame := feed.get()) is not None:
        crossing.append(time.monotonic() - frame.arrival)
    feed.close()
    if hasattr(feed, "source"):
        feed.source.close()
    stop.set()
    if loaded:
        load.join()
    ms = 1e3 * np.array(crossing)
    return (f"{where:>8}, {'beside the smoother' if loaded else 'alone':<20} tracked "
            f"{feed.tracked:4d}, not tracked {feed.untracked:4d}, crossing "
            f"{np.median(ms):6.1f} / {np.percentile(ms, 95):6.1f} ms")


def main() -> None:
    frames = int(sys.argv[1]) if len(sys.argv) > 1 else 300
    seed = int(sys.argv[2]) if len(sys.argv) > 2 else 1
    with tempfile.TemporaryDirectory(prefix="apcc-track-") as tmp:
        files, _ = render_videos(Path(tmp), frames, seed)
        spec = SourceSpec("video", tuple(load_robot(ROBOT_FILE).camera_segments),
                          paths=tuple(files))
        print(f"{frames} frames of 3 rendered 640x480 videos at 30 fps (seed {seed})")
        for loaded in (False, True):
            for where in ("thread", "process"):
                print(run(spec, where, loaded), flush=True)


if __name__ == "__main__":
    main()
