"""``apcc-graph bench live``: the live loop on rendered video files, beside the offline smoother.

Scenario: the three-segment robot (``data/robots/planar_three.toml``) moving through the
textured room, each tip camera's view rendered (``apcc_graph.simulation.render``, 640x480,
30 fps) into one video file per camera (OpenCV's ``mp4v``). Then, on the same files:

- **offline**: ``apcc-graph track --video`` and ``estimate --method smoother`` (every frame);
- **live**: :class:`~apcc_graph.estimation.live.LiveEstimator` at the videos' own pace (under
  overload it defers keyframes, then drops frames from smoothing, then from tracking), and
  every frame as fast as it can (which should give the offline answer), each with the smoother
  solving at every frame and at keyframes only (the default
  :class:`~apcc_graph.estimation.keyframes.KeyframeRule`); the videos read and tracked in a
  process of their own (the default), and, at the videos' pace with keyframes, also tracked in
  the loop between smoothings (``tracking="inline"``: the loop before it had a stage of its
  own, for the ratio); from
  the true start, from the start it searches in the first second itself (as ``apcc-graph
  live`` without ``--theta0-deg``; the start found is printed beside the true one) and from
  the robot straight (``--theta0-deg 0,0,0``).

Printed: frames estimated, the rate, the latency (median and 95th percentile), frames dropped
and, of those, not tracked at all, and RMS per segment against the simulated truth over the
frames each estimated and its ratio to the offline row's (targets: 29.5 frames per second
sustained, median latency at most one frame, at most 1.2x the offline RMS).
"""

from __future__ import annotations

import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from threadpoolctl import threadpool_limits

from apcc_graph.bench.smoother import ROBOT_FILE
from apcc_graph.model.arrays import FloatArray, rms

FPS = 30.0
THETA0_SIGMA = np.radians(0.1)


@dataclass(frozen=True)
class LiveRun:
    """One row: what an estimator made of the videos."""

    name: str
    frames: int  # frames estimated
    total: int  # frames in the videos
    seconds: float  # wall time of the run
    rms: FloatArray  # (S,) radians, over the frames estimated
    latency: tuple[float, float] | None  # median and 95th percentile, seconds
    dropped: int
    note: str = ""  # what the start search found, when it ran
    untracked: int | None = None  # frames not even tracked (live)


def render_videos(folder: Path, frames: int, seed: int) -> tuple[list[str], FloatArray]:
    """One ``mp4v`` video per camera of the robot moving for ``frames`` frames; the files and
    the true angles ``(F, S)``."""
    from apcc_graph.io.robot_file import load_robot
    from apcc_graph.simulation.render import render_images, textured_room
    from apcc_graph.simulation.simulator import simulate

    robot = load_robot(ROBOT_FILE)
    sim = simulate(robot, frames, noise_px=0.0, outlier_fraction=0.0, seed=seed, scene="room")
    room = textured_room(sim.scene_centre, sim.room_half_size)
    files = []
    for cam in robot.camera_segments:
        camera = robot.cameras[cam]
        assert camera is not None
        path = folder / f"cam_{cam + 1}.mp4"
        writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), FPS,
                                 (camera.width, camera.height), False)
        for image in render_images(room, camera, sim.world_T_cam[cam], seed=seed + cam):
            writer.write(image)
        writer.release()
        files.append(str(path))
    assert sim.sequence.thetas is not None
    return files, sim.sequence.thetas


def run_offline(files: list[str], truth: FloatArray) -> LiveRun:
    """``track --video`` then the smoother over every frame."""
    from apcc_graph.estimation.methods import estimate
    from apcc_graph.frontend.recordings import track_recording, video_streams
    from apcc_graph.io.robot_file import load_robot

    robot = load_robot(ROBOT_FILE)
    began = time.perf_counter()
    sequence, _ = track_recording(video_streams(files), robot)
    result = estimate(sequence, method="smoother", theta0=truth[0], theta0_sigma=THETA0_SIGMA,
                      progress=False)
    seconds = time.perf_counter() - began
    return LiveRun("offline: track, then estimate --method smoother", sequence.n_frames,
                   len(truth), seconds, rms(result.thetas - truth[:sequence.n_frames]), None, 0)


def run_live(files: list[str], truth: FloatArray, realtime: bool = True,
             start: str = "true", keyframes: bool = False, tracking: str = "process"
             ) -> LiveRun:
    """The live loop over the videos at their pace (or every frame), from the ``"true"``
    start, the start it searches (``"searched"``) or the robot ``"straight"``; with
    ``keyframes`` the smoother solves at keyframes only (the default rule); ``tracking``:
    where the cameras are tracked (:data:`~apcc_graph.estimation.live.TRACKING`)."""
    from apcc_graph.estimation.keyframes import KeyframeRule
    from apcc_graph.estimation.live import LiveEstimator
    from apcc_graph.estimation.live_process import SourceSpec
    from apcc_graph.estimation.smoother_options import SmootherOptions
    from apcc_graph.io.robot_file import load_robot

    robot = load_robot(ROBOT_FILE)
    theta0 = {"true": truth[0], "searched": None, "straight": np.zeros(truth.shape[1])}[start]
    settings = SmootherOptions(keyframes=KeyframeRule()) if keyframes else None
    live = LiveEstimator(robot, theta0, settings=settings, realtime=realtime, tracking=tracking)
    finals, latencies = {}, []
    began = time.perf_counter()
    source = SourceSpec("video", tuple(robot.camera_segments), paths=tuple(files))
    for est in live.run(source):
        latencies.append(est.latency)
        finals.update({fr.frame: fr.thetas for fr in est.final})
    finals.update({fr.frame: fr.thetas for fr in live.finish()})
    seconds = time.perf_counter() - began
    frames = np.array(sorted(finals))
    errors = np.array([finals[f] for f in frames]) - truth[frames]
    name = "live, at the videos' pace" if realtime else "live, every frame (not real time)"
    name += "" if start == "true" else f", start {start}"
    name += ", keyframes" if keyframes else ""
    name += ", tracked in the loop" if tracking == "inline" else ""
    assert live.feed is not None
    return LiveRun(name, len(frames), len(truth), seconds, rms(errors),
                   (float(np.median(latencies)), float(np.percentile(latencies, 95))),
                   live.dropped, live.start_search or "", live.feed.untracked)


def run_live_bench(frames: int = 600, seed: int = 1
                   ) -> tuple[list[LiveRun], float, FloatArray]:
    """Render the videos, then every row; returns the rows, the rendering time and the true
    start (radians)."""
    with tempfile.TemporaryDirectory(prefix="apcc-live-") as tmp, \
            threadpool_limits(limits=1, user_api="blas"):
        began = time.perf_counter()
        files, truth = render_videos(Path(tmp), frames, seed)
        rendered = time.perf_counter() - began
        rows = [run_offline(files, truth), run_live(files, truth),
                run_live(files, truth, keyframes=True),
                run_live(files, truth, keyframes=True, tracking="inline"),
                run_live(files, truth, realtime=False),
                run_live(files, truth, realtime=False, keyframes=True),
                run_live(files, truth, realtime=False, start="searched"),
                run_live(files, truth, realtime=False, start="straight")]
    return rows, rendered, truth[0]


def format_live(rows: list[LiveRun], frames: int, rendered: float,
                truth0: FloatArray | None = None) -> str:
    """The benchmark's table (and the start each search found, beside ``truth0``)."""
    out = [f"live: 3 rendered 640x480 videos at {FPS:.0f} fps, {frames} frames "
           f"({frames / FPS:.0f} s; rendered in {rendered:.0f} s); RMS per segment against "
           "the truth over the frames each estimated (deg)", "",
           f"{'estimator':<72} {'frames':>7} {'per s':>6} {'latency ms':>14} {'dropped':>8} "
           f"{'untracked':>9} {'RMS':>22} {'RMS / offline':>22}"]
    offline = rows[0].rms
    for r in rows:
        lat = "-" if r.latency is None else f"{1e3 * r.latency[0]:.0f} / {1e3 * r.latency[1]:.0f}"
        untracked = "-" if r.untracked is None else str(r.untracked)
        ratio = " ".join(f"{v:6.2f}" for v in r.rms / offline)
        out.append(f"{r.name:<72} {r.frames:>7} {r.frames / r.seconds:6.1f} {lat:>14} "
                   f"{r.dropped:>8} {untracked:>9} "
                   f"{' '.join(f'{v:6.3f}' for v in np.degrees(r.rms)):>22} {ratio:>22}")
    out += ["", "per s: frames estimated per second of wall time (offline: tracking and "
            "smoothing; live: while the videos play); latency: median / 95th percentile from a "
            "frame's arrival to its estimate; dropped: frames not smoothed, of which untracked: "
            "not even tracked; RMS / offline: per segment, the first row's; targets: 29.5 per "
            f"second, median latency at most one frame ({1e3 / FPS:.0f} ms), at most 1.2x the "
            "offline RMS"]
    true = ("" if truth0 is None else
            f" (true start {', '.join(f'{v:.2f}' for v in np.degrees(truth0))} deg)")
    out += [f"{r.name}: {r.note}{true}" for r in rows if r.note]
    return "\n".join(out)
