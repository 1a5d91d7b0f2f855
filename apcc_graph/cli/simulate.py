"""``apcc-graph simulate``: a sequence folder with ground truth, as simulated tracks or as rendered
images of a textured room, and the Cramér-Rao bound of its angles."""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np

from apcc_graph.cli.common import (
    FORMATTER,
    UserError,
    at_least,
    check_output_folder,
    force_option,
    fraction,
    non_negative,
    out_option,
    positive,
    robot_option,
    seed_option,
)

EXAMPLE = (
    "examples:\n  apcc-graph simulate --robot data/robots/planar_three.toml "
    "--frames 300 --out /tmp/seq --noise-px 1 --outliers 0.1 --seed 1\n"
    "  apcc-graph simulate --robot data/robots/planar_three.toml --frames 150 --out /tmp/img "
    "--images --seed 1 && apcc-graph track /tmp/img")


def add_parser(commands: argparse._SubParsersAction) -> None:
    """Add ``simulate`` to the subcommands."""
    simp = commands.add_parser(
        "simulate", help="simulate a sequence of tip-camera tracks with ground truth",
        description="Simulate what the tip cameras of a robot see along a random motion and "
        "write the sequence folder (robot.toml, frames.csv with ground truth, tracks/).",
        epilog=EXAMPLE, formatter_class=FORMATTER,
        parents=[out_option("output sequence folder"), seed_option(0),
                 force_option("write into a non-empty --out"), robot_option()],
    )
    simp.add_argument("--frames", type=at_least(2), default=None,
                      help="number of frames (required, except with --motion POSES.csv)")
    simp.add_argument("--noise-px", type=non_negative, default=0.5,
                      help="pixel noise std (default 0.5)")
    simp.add_argument("--outliers", type=fraction, default=0.0,
                      help="fraction of wrong associations, 0 <= p < 1 (default 0)")
    simp.add_argument("--fps", type=positive, default=None,
                      help="frame rate (default 30; with --motion POSES.csv: the recording's "
                      "own sample times, or resampled to this rate)")
    simp.add_argument("--motion", default="smooth", metavar="{smooth,paper,POSES.csv}",
                      type=_motion,
                      help="smooth random motion, the paper's random steps under 5 deg, or a "
                      "real robot's measured backbone poses: the tip cameras ride on its "
                      "measured segment ends (ground truth in truth_tips.csv)")
    simp.add_argument("--smoothing", type=non_negative, default=None,
                      help="with --motion POSES.csv: width (s) of the local fit that removes "
                      "the motion capture's noise (default 0.05; 0 interpolates)")
    simp.add_argument("--max-gap", type=positive, default=None,
                      help="with --motion POSES.csv: frames are written only where the samples "
                      "around them are at most this far apart (seconds, default 0.25); the "
                      "gaps split the recording into stretches, and no track crosses a gap")
    simp.add_argument("--stretch", type=at_least(1), default=None,
                      help="with --motion POSES.csv: replay only this stretch (1 = the first; "
                      "default: all, the tracks cut at each gap)")
    simp.add_argument("--spatial", action="store_true", help="also vary the bending planes psi")
    simp.add_argument("--moving-base", action="store_true",
                      help="move the base (rotation up to 5 deg, translation up to 0.1 m)")
    simp.add_argument("--scene", choices=("points", "room"), default=None,
                      help="random points around the robot, or points on the walls of a room "
                      "(default: points; room with --images)")
    simp.add_argument("--points", type=at_least(1), default=2700, help="scene points")
    simp.add_argument("--lifetime", type=positive, default=None,
                      help="mean track length in frames (default: while in view)")
    simp.add_argument("--blackout", type=fraction, default=0.0,
                      help="fraction of frames in which a camera sees nothing")
    simp.add_argument("--decimals", type=int, default=None,
                      help="round pixels to this many decimals (default: full precision)")
    _add_image_options(simp)
    simp.set_defaults(run=run)


def _motion(value: str) -> str:
    """``--motion``: smooth, paper, or a backbone poses file (.csv)."""
    if value in ("smooth", "paper") or value.lower().endswith(".csv"):
        return value
    raise argparse.ArgumentTypeError(f"{value!r}: expected smooth, paper, or a backbone poses "
                                     "file (.csv)")


def _add_image_options(simp: argparse.ArgumentParser) -> None:
    img = simp.add_argument_group(
        "images", "--images renders what each tip camera sees of a textured room into\n"
        "images/cam_<i>/<frame:06d>.png instead of writing simulated tracks (run\n"
        "`apcc-graph track` next)")
    img.add_argument("--images", action="store_true", help="render images of the room")
    img.add_argument("--texture", choices=("skimage", "procedural"), default=None,
                     help="wall textures: scikit-image's bundled photos (pip install "
                     "'apcc-graph[images]') or seeded noise (default: skimage)")
    img.add_argument("--image-noise", type=non_negative, default=None,
                     help="sensor noise, grey levels (default 2)")
    img.add_argument("--blur", type=non_negative, default=None,
                     help="Gaussian blur, pixels (default 0)")
    img.add_argument("--exposure", type=fraction, default=None,
                     help="largest relative exposure change over the sequence (default 0)")
    img.add_argument("--supersample", type=int, choices=(1, 2, 3, 4), default=None,
                     help="rays per pixel side (default 2)")


def run(args: argparse.Namespace) -> str:
    """Simulate, write the sequence folder and return the summary with the bound."""
    from apcc_graph.io import load_robot, save_sequence
    from apcc_graph.io.output_folder import staged_folder
    from apcc_graph.simulation.simulator import simulate

    poses = [] if args.motion in ("smooth", "paper") else [args.motion]  # a recording
    out = check_output_folder(args.out, args.force, inputs=[args.robot, *poses])
    scene = args.scene or ("room" if args.images else "points")
    if args.images and scene != "room":
        raise UserError("--images renders the textured room: use --scene room (or leave "
                        "--scene out)")
    image_options = [name for name in ("texture", "image_noise", "blur", "exposure",
                                       "supersample") if getattr(args, name) is not None]
    if image_options and not args.images:
        raise UserError(f"--{image_options[0].replace('_', '-')} applies to --images only")
    robot = load_robot(args.robot)
    if args.motion not in ("smooth", "paper"):
        from apcc_graph.cli.simulate_replay import run_replay

        return run_replay(args, robot, out, scene)
    for name in ("smoothing", "max_gap", "stretch"):
        if getattr(args, name) is not None:
            raise UserError(f"--{name.replace('_', '-')} applies to --motion POSES.csv only")
    if args.frames is None:
        raise UserError("--frames is required (except with --motion POSES.csv)")
    args.fps = 30.0 if args.fps is None else args.fps
    sim = simulate(
        robot, args.frames, noise_px=args.noise_px, outlier_fraction=args.outliers,
        seed=args.seed, fps=args.fps, motion=args.motion, spatial=args.spatial,
        moving_base=args.moving_base, scene=scene, n_points=args.points,
        track_lifetime=args.lifetime, blackout_fraction=args.blackout, decimals=args.decimals,
        progress=True,
    )
    with staged_folder(out, replace=args.force) as staging:  # whole, or not at all
        if args.images:
            return _simulate_images(args, sim, out, staging)
        save_sequence(sim.sequence, staging)
    seq = sim.sequence
    lines = [f"wrote {out}: {seq.n_frames} frames at {args.fps:g} fps, "
             f"{len(seq.cameras)} camera(s), seed {args.seed}"]
    for cam in seq.cameras:
        per_frame = np.bincount(seq.tracks[cam].frames, minlength=seq.n_frames)
        lines.append(f"  cam_{cam + 1}: {len(seq.tracks[cam])} observations, "
                     f"{per_frame.mean():.0f} tracks per frame (min {per_frame.min()}), "
                     f"{int(sim.outliers[cam].sum())} outliers")
    lines.append(_bound_line(sim, args.noise_px))
    return "\n".join(lines)


BOUND_LIMIT = 6000
"""Most angles (frames x segments) for which ``simulate`` prints the Cramer-Rao bound: its
information matrix is dense."""


def _bound_line(sim: object, noise_px: float) -> str:
    """The Cramer-Rao bound of a simulation's angles, as ``simulate`` prints it."""
    from apcc_graph.evaluation.sequence_bound import sequence_bound
    from apcc_graph.simulation.simulator import Simulation

    assert isinstance(sim, Simulation)
    seq = sim.sequence
    if noise_px <= 0.0:
        return "Cramer-Rao bound: none (noise-free pixels)"
    if seq.n_frames * seq.n_segments > BOUND_LIMIT:
        return (f"Cramer-Rao bound: not computed ({seq.n_frames} frames x {seq.n_segments} "
                f"segments > {BOUND_LIMIT} angles)")
    spatial = seq.psis is not None
    bound = sequence_bound(sim, noise_px, math.radians(0.1), spatial=spatial)
    what = "bending vectors theta (cos psi, sin psi)" if spatial else "angles"
    return (f"Cramer-Rao bound of the {what} (every observation once, each track's point "
            "unknown, 0.1 deg start prior), RMS per segment: "
            + ", ".join(f"{v:.3f}" for v in np.degrees(bound.rms())) + " deg")


def _simulate_images(args: argparse.Namespace, sim: object, out: Path, staging: Path) -> str:
    """``simulate --images``: the sequence without tracks, and rendered images of the room,
    written into ``staging`` (which becomes ``out``)."""
    from apcc_graph.io import save_sequence
    from apcc_graph.model.sequence import Sequence
    from apcc_graph.simulation.render import SensorModel, textured_room, write_sequence_images
    from apcc_graph.simulation.simulator import Simulation

    assert isinstance(sim, Simulation)
    seq = sim.sequence
    try:
        room = textured_room(sim.scene_centre, sim.room_half_size, args.texture or "skimage",
                             seed=args.seed)
        noise = SensorModel.noise_grey if args.image_noise is None else args.image_noise
        sensor = SensorModel(noise_grey=noise,
                             blur_sigma=args.blur or 0.0, exposure_change=args.exposure or 0.0)
    except ImportError as error:
        raise UserError(str(error)) from None
    cameras = {cam: seq.robot.cameras[cam] for cam in seq.robot.camera_segments}
    # The images are the observations: tracks come from `apcc-graph track`.
    bare = Sequence(seq.robot, seq.timestamps, {}, world_T_base=seq.world_T_base,
                    thetas=seq.thetas, psis=seq.psis)
    save_sequence(bare, staging)
    write_sequence_images(staging, room, cameras, sim.world_T_cam, sensor, seed=args.seed,
                          supersample=args.supersample or 2, progress=True)
    images = out / "images"
    return "\n".join([
        f"wrote {out}: {seq.n_frames} frames at {args.fps:g} fps, {len(cameras)} camera(s), "
        f"seed {args.seed}, rendered images in {images} ({args.texture or 'skimage'} "
        f"textures, noise {sensor.noise_grey:g} grey levels)",
        f"next: apcc-graph track {out}",
    ])
