"""``apcc-graph simulate --motion POSES.csv``: tip cameras riding on a real robot's measured
segment ends (docs/estimation.md, "Replaying a real robot's motion")."""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np

from apcc_graph.cli.common import UserError
from apcc_graph.model.robot import Robot

NOT_FOR_REPLAY = ("frames", "spatial", "moving_base", "lifetime", "blackout", "images")


def run_replay(args: argparse.Namespace, robot: Robot, out: Path, scene: str) -> str:
    """Replay, write the sequence folder (with ``truth_tips.csv``) and return the summary."""
    from apcc_graph.evaluation.tip_floor import tip_floor
    from apcc_graph.io import save_sequence
    from apcc_graph.io.backbone_poses import load_backbone_poses
    from apcc_graph.io.robot_file import load_markers
    from apcc_graph.simulation.replay import measured_ends, replay_motion

    given = [name for name in NOT_FOR_REPLAY if getattr(args, name, None) not in (None, False)]
    if given:
        raise UserError(f"--{given[0].replace('_', '-')} does not apply to --motion POSES.csv "
                        "(the recording gives the motion and its length)")
    poses_path = Path(args.motion)
    if poses_path.suffix.lower() != ".csv":
        raise UserError(f"--motion {args.motion}: expected smooth, paper, or a backbone poses "
                        "file (.csv)")
    markers = load_markers(args.robot)
    poses = load_backbone_poses(poses_path)
    ends = measured_ends(poses, robot, markers)
    smoothing = 0.05 if args.smoothing is None else args.smoothing
    rep = replay_motion(robot, ends, fps=args.fps, smoothing=smoothing,
                        noise_px=args.noise_px, outlier_fraction=args.outliers, seed=args.seed,
                        scene=scene, n_points=args.points,
                        decimals=3 if args.decimals is None else args.decimals)
    seq = rep.simulation.sequence
    save_sequence(seq, out)
    floor = tip_floor(robot, seq.truth_tips)
    rate = "the recording's sample times" if args.fps is None else f"{args.fps:g} fps"
    lines = [f"wrote {out}: {seq.n_frames} frames ({rate}, {seq.timestamps[-1]:.1f} s) of "
             f"{poses_path}, {rep.dropped} dropped for a gap in the motion capture, "
             f"smoothing {smoothing:g} s, seed {args.seed}"]
    if not markers:
        lines.append("note: the robot file has no [[markers]] offsets (calibrate it from these "
                     "poses first): the marker frames are taken as the backbone frames")
    for cam in seq.cameras:
        per_frame = np.bincount(seq.tracks[cam].frames, minlength=seq.n_frames)
        lines.append(f"  cam_{cam + 1}: {len(seq.tracks[cam])} observations, "
                     f"{per_frame.mean():.0f} tracks per frame (min {per_frame.min()}), "
                     f"{int(rep.simulation.outliers[cam].sum())} outliers")
    lines.append("the floor (the model's tips at the bends that best fit the measured tips), "
                 "RMS per segment end: " + ", ".join(
                     f"{p * 1e3:.2f} mm / {math.degrees(t):.2f} deg" for p, t in
                     zip(floor.errors.rms_position, floor.errors.rms_tangent, strict=True)))
    return "\n".join(lines)
