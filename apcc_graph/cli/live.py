"""``apcc-graph live``: track and smooth a recording or cameras frame by frame as frames arrive,
appending each final estimate to ``theta.csv`` and the TUM files
(:mod:`apcc_graph.estimation.live`)."""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from apcc_graph.cli.common import (
    FORMATTER,
    UserError,
    add_model_options,
    check_output_folder,
    chosen_model_sigma,
    force_option,
    int_list,
    non_negative,
)

if TYPE_CHECKING:
    from apcc_graph.estimation.live import LiveEstimate, LiveEstimator
    from apcc_graph.estimation.live_process import SourceSpec
    from apcc_graph.io.estimates import AppendedEstimate

TRACKING = ("process", "thread", "inline")  # as apcc_graph.estimation.live.TRACKING

EXAMPLE = (
    "examples:\n"
    "  apcc-graph live --video a.mp4,b.mp4,c.mp4 --robot robot.toml --out /tmp/live\n"
    "  apcc-graph live run.bag --robot robot.toml --out /tmp/live --theta0-deg 20,-15,21\n"
    "  apcc-graph live --devices 0,1,2 --robot robot.toml --out /tmp/live")


def add_parser(commands: argparse._SubParsersAction) -> None:
    """Add ``live`` to the subcommands."""
    live = commands.add_parser(
        "live", help="track and smooth frame by frame as frames arrive (bag, videos, cameras)",
        description="Track each frame's images (KLT) and smooth them (the fixed-lag smoother) "
        "as they arrive, from a ROS bag (SOURCE), one video file per camera (--video) or "
        "cameras plugged in (--devices). Each frame's final estimate is appended to "
        "--out/theta.csv and tips_seg_<i>.tum and flushed, so a crash loses nothing already "
        "estimated (so --force cannot replace the folder once complete, as estimate does: it "
        "deletes whatever --out held first); on a terminal a line on stderr shows the rate, "
        "the latency and the current "
        "angles (an angle beyond its segment's limit is written clamped to it and flagged in "
        "clamped_<i>, with a warning). Ctrl-C stops at the next frame: the frames still in the "
        "window are smoothed and written, then the command exits with code 130. Without "
        "--theta0-deg the start is searched in the first second of frames, as estimate does (a "
        "Ctrl-C before then searches it in the frames so far and writes them). A "
        "recording plays at its own pace: every frame is tracked (in a process of its own, "
        "beside the smoother), but when the smoother falls behind it first defers keyframes "
        "(--keyframes), then smooths the newest of the frames that waited and counts the "
        "others as dropped (--no-realtime smooths every frame, as fast as it can). Every "
        "estimate as it comes out is appended to --out/theta_now.csv, which says whether it "
        "is the filtered estimate or a frame's fit awaiting the next keyframe, and its "
        "latency. See docs/estimation.md, \"Live\".",
        epilog=EXAMPLE, formatter_class=FORMATTER,
        parents=[force_option("empty an --out folder that is not empty first (it must not "
                              "be or hold an input, the current folder or your home)")])
    live.add_argument("source", nargs="?", default=None, help="a ROS 1 bag file or ROS 2 folder")
    live.add_argument("--video", default=None, help="video files, one per camera, comma-separated")
    live.add_argument("--devices", default=None,
                      help="camera device indices (OpenCV), one per camera, comma-separated")
    live.add_argument("--topics", default=None, help="a bag's image topics, one per camera")
    live.add_argument("--robot", required=True, help="robot.toml")
    live.add_argument("--out", required=True, help="folder for theta.csv and tips_seg_<i>.tum")
    live.add_argument("--theta0-deg", default=None,
                      help="starting configuration, degrees, one per segment (default: searched in "
                      "the first second of frames)")
    live.add_argument("--lag", type=float, default=1.0, help="smoother lag, seconds (default 1)")
    add_model_options(live)
    live.add_argument("--sync-tolerance", type=non_negative, default=None,
                      help="seconds between the cameras' images of one frame (bag, videos)")
    live.add_argument("--no-realtime", action="store_true",
                      help="process every frame as fast as possible instead of at the "
                      "recording's pace")
    live.add_argument("--keyframes", action="store_true",
                      help="the smoother solves at keyframes only; the frames between return "
                      "their per-frame fit at once and are smoothed at the next keyframe "
                      "(docs/estimation.md, keyframes)")
    live.add_argument("--tracking", choices=TRACKING, default="process",
                      help="where the cameras are tracked: a process of its own that reads the "
                      "source (default: keeps up beside the smoother), a thread of this one, or "
                      "inline between smoothings")
    live.set_defaults(run=run)


def run(args: argparse.Namespace) -> str:
    """Run the live loop; returns the summary (on Ctrl-C: writes the final rows, prints the
    summary, then raises ``KeyboardInterrupt`` for the exit code 130)."""
    from apcc_graph.cli.estimate import _theta0
    from apcc_graph.estimation.keyframes import KeyframeRule
    from apcc_graph.estimation.live import LiveEstimator
    from apcc_graph.estimation.live_guards import deferred_interrupts
    from apcc_graph.estimation.options import GraphOptions
    from apcc_graph.estimation.smoother_options import SmootherOptions, WindowOptions
    from apcc_graph.io.console import StatusLine
    from apcc_graph.io.estimates import AppendedEstimate
    from apcc_graph.io.live_rows import NowEstimates
    from apcc_graph.io.robot_file import load_robot

    robot = load_robot(args.robot)
    if not (args.lag > 0.0):
        raise UserError(f"--lag {args.lag}: expected seconds > 0")
    theta0 = _theta0(args.theta0_deg, robot)
    frames = _frames(args, robot)
    inputs = [args.robot, *([args.source] if args.source else []),
              *(v for v in (args.video or "").split(",") if v)]
    out = check_output_folder(args.out, args.force, inputs=inputs)
    if args.force and out.is_dir():
        _empty(out)  # rows are appended as they come: the old run's files must not stay
    settings = SmootherOptions(window=WindowOptions(lag=args.lag),
                               keyframes=KeyframeRule() if args.keyframes else None)
    estimator = LiveEstimator(robot, theta0, settings,
                              realtime=not args.no_realtime,
                              graph=GraphOptions(model_sigma=chosen_model_sigma(args)),
                              tracking=args.tracking)
    files = AppendedEstimate(out, robot.n_segments, lambda th: robot.forward(th))
    now = NowEstimates(out, robot.n_segments)
    status = StatusLine()
    latencies, began = [], time.monotonic()
    with deferred_interrupts() as stop:
        try:
            shown = 0.0
            for est in estimator.run(frames, stop):
                now.append(est.index, est.timestamp, est.thetas, est.sigmas, est.clamped,
                           est.pending, est.latency)
                for fr in est.final:
                    files.append(fr.frame, fr.timestamp, fr.thetas, fr.sigmas, fr.clamped)
                latencies.append(est.latency)
                if time.monotonic() - shown > 0.5:
                    shown = time.monotonic()
                    status.show(_status_text(est))
        finally:
            status.close()
            for fr in estimator.finish():
                files.append(fr.frame, fr.timestamp, fr.thetas, fr.sigmas, fr.clamped)
            files.close()
            now.close()
    estimator.interrupted = estimator.interrupted or stop.is_set()  # also while finishing
    summary = _summary(estimator, time.monotonic() - began, latencies, files, now.rows, out)
    if estimator.interrupted:
        print(summary, flush=True)
        raise KeyboardInterrupt
    return summary


def _summary(estimator: LiveEstimator, wall: float, latencies: list[float],
             files: AppendedEstimate, now_rows: int, out: Path) -> str:
    """The line ``live`` ends with (``wall``: seconds of the run)."""
    processed = len(latencies)
    median = 1e3 * float(np.median(latencies)) if latencies else float("nan")
    clamped = (f"; {files.clamped_rows} rows with an angle clamped to its limit (clamped_i)"
               if files.clamped_rows else "")
    return (f"{'interrupted: ' if estimator.interrupted else ''}{processed} frames estimated "
            f"in {wall:.1f} s ({processed / max(wall, 1e-9):.1f} per second), "
            f"{estimator.dropped} dropped, median latency {median:.0f} ms; wrote {files.rows} "
            f"rows to {Path(out) / 'theta.csv'} and tips_seg_<i>.tum, {now_rows} to "
            f"theta_now.csv{clamped}"
            + (f"; {estimator.start_search}" if estimator.start_search else ""))


def _empty(folder: Path) -> None:
    """Delete everything in ``folder`` (links themselves, not what they point to)."""
    import shutil

    for entry in folder.iterdir():
        if entry.is_dir() and not entry.is_symlink():
            shutil.rmtree(entry)
        else:
            entry.unlink()


def _status_text(est: LiveEstimate) -> str:
    """The status line of one estimate (an angle clamped to its limit marked ``!``)."""
    clamped = np.zeros(len(est.thetas), bool) if est.clamped is None else est.clamped
    angles = " / ".join(f"{np.degrees(v):6.1f}{'!' if c else ''}"
                        for v, c in zip(est.thetas, clamped, strict=True))
    return (f"frame {est.index:6d}  {est.fps:5.1f} fps  latency {1e3 * est.latency:6.0f} ms  "
            f"dropped {est.dropped:5d}  theta {angles} deg")


def _frames(args: argparse.Namespace, robot: object) -> SourceSpec:
    """The frame source the arguments name, checked here (a file, bag or topic that cannot be
    opened is named before the run starts)."""
    import cv2

    from apcc_graph.estimation.live_process import SourceSpec
    from apcc_graph.frontend.recordings import bag_streams

    cams = tuple(robot.camera_segments)  # type: ignore[attr-defined]
    given = [x is not None for x in (args.source, args.video, args.devices)]
    if sum(given) != 1:
        raise UserError("give one source: a bag (SOURCE), --video or --devices")
    if args.devices is not None:
        devices = int_list(args.devices, "--devices")
        if len(devices) != len(cams):
            raise UserError(f"--devices names {len(devices)} devices for {len(cams)} cameras")
        return SourceSpec("devices", cams, devices=tuple(devices))
    if args.video is not None:
        files = [v for v in args.video.split(",") if v]
        if len(files) != len(cams):
            raise UserError(f"--video names {len(files)} files for {len(cams)} cameras")
        for file in files:  # each opens and has an image (read in the tracking process)
            capture = cv2.VideoCapture(file)
            ok = capture.isOpened() and capture.grab()
            capture.release()
            if not ok:
                raise UserError(f"{file}: OpenCV cannot open it as a video, or it has no "
                                "frames")
        return SourceSpec("video", cams, paths=tuple(files), tolerance=args.sync_tolerance)
    from apcc_graph.cli.track import _topics

    topics = _topics(args.topics, args.robot, robot)
    bag_streams(args.source, topics, len(cams))  # the bag and its topics open
    return SourceSpec("bag", cams, paths=(str(args.source),),
                      topics=None if topics is None else tuple(topics),
                      tolerance=args.sync_tolerance)
