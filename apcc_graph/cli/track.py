"""``apcc-graph track``: a recording's images into tracks (OpenCV KLT): a sequence folder's
images, a ROS 1 or ROS 2 bag, or one video file per camera."""

from __future__ import annotations

import argparse
from pathlib import Path

from apcc_graph.cli.common import (
    FORMATTER,
    UserError,
    check_output_folder,
    force_option,
    non_negative,
)

EXAMPLE = (
    "examples:\n"
    "  apcc-graph track my_recording --force\n"
    "  apcc-graph track run.bag --robot robot.toml --out seq \\\n"
    "      --topics /tip1/image_raw,/tip2/image_raw,/tip3/image_raw\n"
    "  apcc-graph track --video a.mp4,b.mp4,c.mp4 --robot robot.toml --out seq")


def add_parser(commands: argparse._SubParsersAction) -> None:
    """Add ``track`` to the subcommands."""
    trk = commands.add_parser(
        "track", help="turn a recording's images into tracks (OpenCV KLT)",
        description="Detect Shi-Tomasi corners and follow them with pyramidal Lucas-Kanade "
        "(forward-backward checked). SOURCE is a sequence folder (images/cam_<i>/<frame:06d>.png;"
        " writes its tracks/cam_<i>.csv), or a ROS 1 bag file or ROS 2 bag folder (sqlite3 or "
        "MCAP; sensor_msgs/Image or CompressedImage, one topic per camera, timed by the header "
        "stamps; needs rosbags: pip install \"apcc-graph[ros]\"); or give --video with one video "
        "file per camera. A bag or videos become a new sequence folder --out with --robot's "
        "robot.toml; cameras that are not synchronised are matched to common frames by time "
        "(the first camera's frames; each other camera's nearest image within "
        "--sync-tolerance), and what was dropped is counted. See docs/formats.md.",
        epilog=EXAMPLE, formatter_class=FORMATTER,
        parents=[force_option("replace tracks files, or an --out folder, that already exist")],
    )
    trk.add_argument("source", nargs="?", default=None,
                     help="a sequence folder with images/, or a ROS bag (file or folder)")
    trk.add_argument("--robot", default=None, help="robot.toml of a bag or videos (required "
                     "with them)")
    trk.add_argument("--out", default=None, help="the sequence folder a bag or videos become")
    trk.add_argument("--topics", default=None,
                     help="a bag's image topics, comma-separated, one per camera from the base "
                     "(default: each camera's topic in robot.toml, else the bag's image topics "
                     "sorted, if there is one per camera)")
    trk.add_argument("--video", default=None,
                     help="video files, comma-separated, one per camera from the base")
    trk.add_argument("--sync-tolerance", type=non_negative, default=None,
                     help="seconds: how far apart the cameras' images of one frame may be "
                     "(default: half the first camera's median frame interval)")
    trk.set_defaults(run=run)


def run(args: argparse.Namespace) -> str:
    """Track the recording and return what was written."""
    if args.source is not None and not Path(args.source).exists():
        raise UserError(f"{args.source}: no such sequence folder or ROS bag")
    if args.video is None and args.source is not None and _is_sequence_folder(args.source):
        if args.robot is not None or args.out is not None or args.topics is not None:
            raise UserError(f"{args.source} is a sequence folder: its tracks are written in it "
                            "(--robot, --out and --topics are for bags and videos)")
        from apcc_graph.frontend.tracking import track_sequence
        from apcc_graph.io.output_folder import check_writable

        check_writable(Path(args.source) / "tracks")  # before tracking
        written = track_sequence(args.source, force=args.force, progress=True)
        return "wrote " + ", ".join(str(p) for p in written)
    return _track_recording(args)


def _is_sequence_folder(source: str) -> bool:
    """A folder that is not a ROS 2 bag (which holds ``metadata.yaml``)."""
    path = Path(source)
    return path.is_dir() and not (path / "metadata.yaml").is_file()


def _track_recording(args: argparse.Namespace) -> str:
    """A bag or video files into a new sequence folder."""
    from apcc_graph.frontend.recordings import bag_streams, track_recording, video_streams
    from apcc_graph.io.output_folder import staged_folder
    from apcc_graph.io.robot_file import load_robot
    from apcc_graph.io.sequence_folder import save_sequence

    if (args.video is None) == (args.source is None):
        raise UserError("give a SOURCE (a sequence folder or a ROS bag) or --video, not both")
    if args.robot is None or args.out is None:
        raise UserError("a bag or videos need --robot (its robot.toml) and --out (the sequence "
                        "folder to write)")
    robot = load_robot(args.robot)
    inputs = [args.robot, *([] if args.source is None else [args.source]),
              *([] if args.video is None else [v for v in args.video.split(",") if v])]
    out = check_output_folder(args.out, args.force, inputs=inputs)
    n = len(robot.camera_segments)
    if args.video is not None:
        if args.topics is not None:
            raise UserError("--topics is for a bag, not for --video")
        files = [v for v in args.video.split(",") if v]
        if len(files) != n:
            raise UserError(f"--video names {len(files)} files for {n} cameras (one per "
                            "camera, from the base)")
        streams = video_streams(files)
    else:
        topics = _topics(args.topics, args.robot, robot)
        streams = bag_streams(args.source, topics, n)
    sequence, matched = track_recording(streams, robot, args.sync_tolerance, progress=True)
    with staged_folder(out, replace=args.force) as staging:  # whole, or not at all
        save_sequence(sequence, staging)
    lines = [f"{sequence.n_frames} frames ({matched.unmatched} of the first camera's images "
             f"had no match within {matched.tolerance:.4g} s)"]
    lines += [f"  {s.name}: {len(s.timestamps)} images, {d} dropped"
              for s, d in zip(streams, matched.dropped, strict=True)]
    return "\n".join([*lines, f"wrote {out}"])


def _topics(text: str | None, robot_file: str, robot: object) -> list[str] | None:
    """A bag's topics, one per camera from the base: ``--topics``, else the ``topic`` of every
    camera in ``robot.toml``, else ``None`` (the bag's image topics, sorted)."""
    from apcc_graph.io.robot_file import camera_topics

    cams = list(robot.camera_segments)  # type: ignore[attr-defined]
    if text is not None:
        topics = [t for t in text.split(",") if t]
        if len(topics) != len(cams):
            raise UserError(f"--topics names {len(topics)} topics for {len(cams)} cameras")
        return topics
    named = camera_topics(robot_file)
    if not named:
        return None
    missing = [c + 1 for c in cams if c not in named]
    if missing:
        raise UserError(f"{robot_file}: cameras of segments {missing} name no topic (give "
                        "every camera a topic, or --topics)")
    return [named[c] for c in cams]
