"""``apcc-graph robot``: edit a ``robot.toml``. ``robot import-camera`` takes a camera's
intrinsics and distortion from an OpenCV or Kalibr calibration file
(:mod:`apcc_graph.io.camera_calibration`) into the camera of one segment, keeping its mount."""

from __future__ import annotations

import argparse
from pathlib import Path

from apcc_graph.cli.common import FORMATTER, UserError, at_least, check_output_file

EXAMPLE = (
    "examples:\n"
    "  apcc-graph robot import-camera ost.yaml --robot robot.toml --segment 1 --out robot2.toml\n"
    "  apcc-graph robot import-camera camchain.yaml --camera cam2 --robot robot.toml "
    "--segment 3 \\\n      --out robot.toml --force")


def add_parser(commands: argparse._SubParsersAction) -> None:
    """Add ``robot`` (and its ``import-camera``) to the subcommands."""
    robot = commands.add_parser(
        "robot", help="edit a robot.toml (import a camera calibration)",
        description="Edit a robot.toml.", epilog=EXAMPLE, formatter_class=FORMATTER)
    actions = robot.add_subparsers(dest="action", metavar="ACTION", required=True)
    imp = actions.add_parser(
        "import-camera", help="a camera's intrinsics from an OpenCV or Kalibr calibration file",
        description="Read a camera's intrinsics and distortion from an OpenCV calibration "
        "(cv::FileStorage YAML, XML or JSON: camera_matrix, distortion_coefficients, "
        "image_width, image_height) or a Kalibr camchain YAML (camN: intrinsics, resolution, "
        "distortion_model, distortion_coeffs) into the camera of one segment of a robot.toml. "
        "Kalibr's radtan becomes OpenCV's k1, k2, p1, p2, its equidistant OpenCV's fisheye "
        "model; other models are refused. The camera's mount (tip_T_cam) stays as it was "
        "(identity for a segment without a camera). See docs/formats.md.",
        epilog=EXAMPLE, formatter_class=FORMATTER)
    imp.add_argument("file", help="the calibration file (OpenCV or Kalibr)")
    imp.add_argument("--robot", required=True, help="the robot.toml to start from")
    imp.add_argument("--segment", required=True, type=at_least(1),
                     help="the segment whose tip camera it is (1 = at the base)")
    imp.add_argument("--camera", default=None,
                     help="in a Kalibr camchain of several cameras, which (cam0, cam1, ...)")
    imp.add_argument("--out", required=True, help="the robot.toml to write")
    imp.add_argument("--force", action="store_true", help="overwrite --out if it exists")
    imp.set_defaults(run=run)


def run(args: argparse.Namespace) -> str:
    """Import the camera and write the robot file; returns what changed."""
    from apcc_graph.io.camera_calibration import read_camera_file
    from apcc_graph.io.robot_file import load_markers, load_robot, save_robot
    from apcc_graph.model.robot import Robot

    robot = load_robot(args.robot)
    segment = int(args.segment)
    if segment > robot.n_segments:
        raise UserError(f"--segment {segment}: {args.robot} has {robot.n_segments} segments")
    out = check_output_file(args.out, args.force)
    try:
        found = read_camera_file(args.file, args.camera)
    except ValueError as exc:
        raise UserError(str(exc)) from None
    old = robot.cameras[segment - 1]
    camera = found.camera(None if old is None else old.tip_T_cam)
    cameras = list(robot.cameras)
    cameras[segment - 1] = camera
    save_robot(Robot(robot.segments, cameras), out, load_markers(args.robot) or None)
    dist = ", ".join(f"{d:.6g}" for d in camera.distortion) or "none"
    return "\n".join([
        f"segment {segment}'s camera from {found.source}:",
        f"  fx, fy = {camera.fx:.6g}, {camera.fy:.6g}; cx, cy = {camera.cx:.6g}, "
        f"{camera.cy:.6g}; {camera.width} x {camera.height} pixels",
        f"  distortion ({camera.model} model): {dist}",
        "  mount (tip_T_cam): " + ("kept" if old is not None else "identity (no camera before)"),
        f"wrote {Path(out)}"])
