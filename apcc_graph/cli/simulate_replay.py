"""``apcc-graph simulate --motion POSES.csv``: tip cameras riding on a real robot's measured
segment ends (docs/estimation.md, "Replaying a real robot's motion")."""

from __future__ import annotations

import argparse
import math
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from apcc_graph.cli.common import UserError
from apcc_graph.model.robot import Robot

if TYPE_CHECKING:
    from apcc_graph.simulation.replay import MeasuredEnds, Replay

NOT_FOR_REPLAY = ("frames", "spatial", "moving_base", "lifetime", "blackout", "images")


def run_replay(args: argparse.Namespace, robot: Robot, out: Path, scene: str) -> str:
    """Replay, write the sequence folder (with ``truth_tips.csv``) and return the summary."""
    from apcc_graph.io import save_sequence
    from apcc_graph.io.backbone_poses import load_backbone_poses
    from apcc_graph.io.output_folder import staged_folder
    from apcc_graph.io.robot_file import load_markers
    from apcc_graph.simulation.replay import measured_ends

    given = [name for name in NOT_FOR_REPLAY if getattr(args, name, None) not in (None, False)]
    if given:
        raise UserError(f"--{given[0].replace('_', '-')} does not apply to --motion POSES.csv "
                        "(the recording gives the motion and its length)")
    poses_path = Path(args.motion)
    if poses_path.suffix.lower() != ".csv":
        raise UserError(f"--motion {args.motion}: expected smooth, paper, or a backbone poses "
                        "file (.csv)")
    markers = load_markers(args.robot)
    ends = measured_ends(load_backbone_poses(poses_path), robot, markers)
    rep = _replay(args, robot, ends, poses_path, scene)
    with staged_folder(out, replace=args.force) as staging:  # whole, or not at all
        save_sequence(rep.simulation.sequence, staging)
    lines = _summary(args, robot, rep, out, poses_path)
    if not markers:
        lines.insert(1, "note: the robot file has no [[markers]] offsets (calibrate it from "
                     "these poses first): the marker frames are taken as the backbone frames")
    return "\n".join(lines)


def _replay(args: argparse.Namespace, robot: Robot, ends: MeasuredEnds, poses_path: Path,
            scene: str) -> Replay:
    """The replay the options ask for (a stretch that is not there refused by number)."""
    from apcc_graph.simulation.replay import motion_stretches, replay_motion

    if args.stretch is not None:
        count = len(motion_stretches(ends, fps=args.fps, smoothing=_smoothing(args),
                                     max_gap=_max_gap(args)))
        if args.stretch > count:
            raise UserError(f"--stretch {args.stretch}: {poses_path} has {count} stretch(es) "
                            f"between gaps longer than {_max_gap(args):g} s (1 .. {count})")
    try:
        return replay_motion(robot, ends, fps=args.fps, smoothing=_smoothing(args),
                             max_gap=_max_gap(args), noise_px=args.noise_px,
                             outlier_fraction=args.outliers, seed=args.seed, scene=scene,
                             n_points=args.points,
                             decimals=3 if args.decimals is None else args.decimals,
                             stretch=None if args.stretch is None else args.stretch - 1)
    except ValueError as error:
        raise UserError(f"--motion {poses_path}: {error}") from error


def _smoothing(args: argparse.Namespace) -> float:
    return 0.05 if args.smoothing is None else float(args.smoothing)


def _max_gap(args: argparse.Namespace) -> float:
    return 0.25 if args.max_gap is None else float(args.max_gap)


def _summary(args: argparse.Namespace, robot: Robot, rep: Replay, out: Path,
             poses_path: Path) -> list[str]:
    """What was written: frames, stretches, tracks per camera, and the floor."""
    from apcc_graph.evaluation.tip_floor import tip_floor

    seq = rep.simulation.sequence
    rate = "the recording's sample times" if args.fps is None else f"{args.fps:g} fps"
    lines = [f"wrote {out}: {seq.n_frames} frames ({rate}, {seq.timestamps[-1]:.1f} s) of "
             f"{poses_path}, {rep.dropped} dropped for a gap in the motion capture, "
             f"smoothing {_smoothing(args):g} s, seed {args.seed}"]
    if args.stretch is not None:
        lines.append(f"stretch {args.stretch} of the recording: from {rep.start:.2f} s")
    elif len(rep.stretches) > 1:
        lines.append(f"{len(rep.stretches)} stretches between gaps longer than "
                     f"{_max_gap(args):g} s (every camera starts new tracks after each; "
                     "--stretch K replays one):")
        lines += [f"  {k}: frames {a}-{b - 1}, {rep.start + seq.timestamps[a]:.2f}-"
                  f"{rep.start + seq.timestamps[b - 1]:.2f} s" for k, (a, b) in
                  enumerate(rep.stretches, start=1)]
    for cam in seq.cameras:
        per_frame = np.bincount(seq.tracks[cam].frames, minlength=seq.n_frames)
        lines.append(f"  cam_{cam + 1}: {len(seq.tracks[cam])} observations, "
                     f"{per_frame.mean():.0f} tracks per frame (min {per_frame.min()}), "
                     f"{int(rep.simulation.outliers[cam].sum())} outliers")
    floor = tip_floor(robot, seq.truth_tips)
    lines.append("the floor (the model's tips at the bends that best fit the measured tips), "
                 "RMS per segment end: " + ", ".join(
                     f"{p * 1e3:.2f} mm / {math.degrees(t):.2f} deg" for p, t in
                     zip(floor.errors.rms_position, floor.errors.rms_tangent, strict=True)))
    return lines
