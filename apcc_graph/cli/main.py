"""The ``apcc-graph`` command line.

Layered as in STYLE.md 8: :func:`build_parser` describes the commands, each ``_run_*`` turns parsed
arguments into a call of a pure library function that returns a result object, and a ``_format_*``
function turns that result into text. User mistakes (a missing or malformed file, a bad value) end
in one line on stderr and exit code 1; ``--debug`` shows the traceback instead.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import NoReturn

import numpy as np

from apcc_graph import __version__

_EXAMPLES = {
    "estimate": "example:\n  apcc-graph estimate data/sequences/planar_three --method batch "
    "--out /tmp/est --theta0-deg 20.5,-15.2,21.3",
    "evaluate": "example:\n  apcc-graph evaluate /tmp/est --truth data/sequences/planar_three",
    "plot": "example:\n  apcc-graph plot /tmp/est --truth data/sequences/planar_three "
    "--output /tmp/angles.png",
    "simulate": "examples:\n  apcc-graph simulate --robot data/robots/planar_three.toml "
    "--frames 300 --out /tmp/seq --noise-px 1 --outliers 0.1 --seed 1\n"
    "  apcc-graph simulate --robot data/robots/planar_three.toml --frames 150 --out /tmp/img "
    "--images --seed 1 && apcc-graph track /tmp/img",
    "calibrate": "examples:\n  apcc-graph calibrate data/calibration/paper_example.toml\n"
    "  apcc-graph calibrate data/calibration/images_sweep --output /tmp/robot.toml\n"
    "  apcc-graph calibrate /tmp/sweep --render --length 0.4 --k 0.21 --delta-max-deg 7 "
    "--theta-max-deg 80 --bends-deg=-80,-40,0,40,80 --seed 0",
    "bench kinematics": "example:\n  apcc-graph bench kinematics --frames 1000000",
    "bench sequences": "example:\n  apcc-graph bench sequences --frames 1000 --rows 1000000",
    "bench solver": "example:\n  apcc-graph bench solver --trials 20",
    "bench accuracy": "example:\n  apcc-graph bench accuracy --trials 1000 --plot /tmp/fig10.png",
    "bench calibration": "example:\n  apcc-graph bench calibration --growth 2 --seed 0",
    "bench tracking": "example:\n  apcc-graph bench tracking --frames 200",
    "bench selfcal": "example:\n  apcc-graph bench selfcal --frames 600 --seeds 1,2,3",
    "bench images": "example:\n  apcc-graph bench images --frames 150 --seeds 1,2,3,4,5",
    "track": "example:\n  apcc-graph track my_recording --force",
    "bench smoother": "example:\n  apcc-graph bench smoother\n  apcc-graph bench smoother "
    "--frames 120 --seeds 1,2 --long-frames 0 --memory-frames 0 --methods chain,smoother",
}


class UserError(Exception):
    """A mistake in what the user asked for; printed as one line, exit code 1."""


def _deg(radians: float) -> str:
    return "-" if math.isnan(radians) else f"{math.degrees(radians):.3f} deg"


# ----------------------------------------------------------------------------------- calibrate
_RENDER_OPTIONS = ("length", "k", "delta_max_deg", "theta_max_deg", "bends_deg", "seed", "noise",
                   "tilt_deg", "force")


def _run_calibrate(args: argparse.Namespace) -> str:
    from apcc_graph.calibration.files import calibrate_measurements, load_tip_measurements

    path = Path(args.file)
    lines = []
    if args.render:
        lines.append(_render_calibration_images(args, path))
    elif given := [name for name in _RENDER_OPTIONS
                   if getattr(args, name) is not None and getattr(args, name) is not False]:
        option = "--" + given[0].replace("_", "-")
        raise UserError(f"{option} applies to --render only")
    if path.is_dir():
        from apcc_graph.calibration.photos import calibrate_images

        result = calibrate_images(path)
        report = result.report
        lines.append(_format_image_measurements(result))
    else:
        report = calibrate_measurements(load_tip_measurements(path))
    if args.output is not None:
        from apcc_graph.io.robot_file import save_robot
        from apcc_graph.model.robot import Robot

        save_robot(Robot([report.segment]), args.output)
    lines.append(_format_calibration(report, args.file, args.output))
    return "\n".join(lines)


def _render_calibration_images(args: argparse.Namespace, path: Path) -> str:
    """``calibrate --render``: write a seeded synthetic image folder to ``path``."""
    from apcc_graph.model.segment import Segment
    from apcc_graph.simulation.calibration_photos import write_calibration_images

    missing = [f"--{name.replace('_', '-')}" for name in ("length", "k", "bends_deg")
               if getattr(args, name) is None]
    if missing:
        raise UserError(f"--render needs {', '.join(missing)}")
    try:
        bends = [math.radians(float(v)) for v in args.bends_deg.split(",")]
    except ValueError:
        raise UserError(f"--bends-deg {args.bends_deg!r}: expected comma-separated degrees "
                        "(write --bends-deg=-80,-40,0 when the first is negative)") from None
    theta_max = max(abs(b) for b in bends) if args.theta_max_deg is None else math.radians(
        args.theta_max_deg)
    segment = Segment(args.length, k=args.k, delta_max=math.radians(args.delta_max_deg or 0.0),
                      theta_max=theta_max)
    tilt = math.radians(args.tilt_deg or 0.0) / math.sqrt(2.0)
    seed = 0 if args.seed is None else args.seed
    noise = 1.0 if args.noise is None else args.noise
    written = write_calibration_images(path, segment, bends, seed=seed, noise=noise,
                                       tilt=(tilt, tilt), force=args.force)
    return (f"wrote {path}: {len(written) - 1} synthetic image(s) and {written[-1].name} "
            f"(seed {seed}, noise {noise:g} grey levels)")


def _format_image_measurements(result: object) -> str:
    """One line per image: chord angle, tip angle, |OP|, fitted theta and corner RMS."""
    from apcc_graph.calibration.fit import MIN_BEND
    from apcc_graph.calibration.photos import ImagesCalibration

    assert isinstance(result, ImagesCalibration)
    m = result.setup.markers
    lines = [
        f"images in {result.folder} ({m.dictionary}, base id {m.base_id}, tip id {m.tip_id}):",
        f"  {'image':<20} {'chord angle':>12} {'tip angle':>12} {'|OP|':>10} "
        f"{'fitted theta':>13} {'corner RMS':>11}",
    ]
    thetas = result.report.apcc.thetas
    for measured, theta in zip(result.measurements, thetas, strict=True):
        tip = measured.tip
        op = tip.op_distance(result.setup.length)
        op_text = "-" if abs(2.0 * tip.chord_angle) < MIN_BEND else f"{op:.4f} m"
        lines.append(
            f"  {Path(measured.name).name:<20} {_deg(tip.chord_angle):>12} {_deg(tip.angle):>12} "
            f"{op_text:>10} {_deg(float(theta)):>13} {measured.rms_px:>8.3f} px"
        )
    return "\n".join(lines)


def _format_calibration(report: object, path: str, output: str | None) -> str:
    from apcc_graph.calibration.files import CalibrationReport

    assert isinstance(report, CalibrationReport)
    seg = report.segment
    method = (
        "one pose, closed form (paper III.C)"
        if report.method == "one-pose"
        else "least squares over the sweep"
    )

    def pm(value: str, std: float, unit: Callable[[float], str]) -> str:
        return value if math.isnan(std) else f"{value} +/- {unit(std)}"

    lines = [
        f"calibration of {path}: {report.n_poses} pose(s), {method}",
        f"  length     = {seg.length:.4f} m",
        f"  k          = {pm(f'{seg.k:.4f}', report.k_std, lambda s: f'{s:.4f}')}",
        f"  delta_max  = {pm(_deg(seg.delta_max), report.delta_max_std, _deg)}",
        f"  theta_max  = {_deg(seg.theta_max)}",
        f"  link lengths l1 = (1-k) L = {seg.l1:.4f} m, l2 = k L = {seg.l2:.4f} m",
        "residuals on the measured poses (RMS):",
        f"  {'model':<6} {'tip position':>14} {'tip angle':>14}",
        f"  {'APCC':<6} {report.apcc.rms_position * 1e3:>11.4f} mm "
        f"{math.degrees(report.apcc.rms_angle):>10.4f} deg",
        f"  {'PCC':<6} {report.pcc.rms_position * 1e3:>11.4f} mm "
        f"{math.degrees(report.pcc.rms_angle):>10.4f} deg",
        "robot.toml entry:",
        *("  " + line for line in _segment_toml(seg).splitlines()),
    ]
    if output is not None:
        lines.append(f"wrote {output}")
    return "\n".join(lines)


def _segment_toml(segment: object) -> str:
    """The ``[[segments]]`` table of ``segment`` exactly as ``save_robot`` writes its values."""
    from apcc_graph.io.robot_file import robot_to_toml
    from apcc_graph.model.robot import Robot

    entry = robot_to_toml(Robot([segment]))["segments"][0]
    return "\n".join(["[[segments]]"] + [f"{key} = {value!r}" for key, value in entry.items()])


# ------------------------------------------------------------------------------------ simulate
def _run_track(args: argparse.Namespace) -> str:
    from apcc_graph.frontend.tracking import track_sequence

    written = track_sequence(args.sequence, force=args.force, progress=True)
    return "wrote " + ", ".join(str(p) for p in written)


def _run_simulate(args: argparse.Namespace) -> str:
    from apcc_graph.io.robot_file import load_robot
    from apcc_graph.io.sequence_folder import save_sequence
    from apcc_graph.simulation.simulator import simulate

    out = Path(args.out)
    if out.exists() and (not out.is_dir() or any(out.iterdir())) and not args.force:
        raise UserError(f"{out}: exists and is not empty; choose another --out or add --force")
    scene = args.scene or ("room" if args.images else "points")
    if args.images and scene != "room":
        raise UserError("--images renders the textured room: use --scene room (or leave "
                        "--scene out)")
    image_options = [name for name in ("texture", "image_noise", "blur", "exposure",
                                       "supersample") if getattr(args, name) is not None]
    if image_options and not args.images:
        raise UserError(f"--{image_options[0].replace('_', '-')} applies to --images only")
    robot = load_robot(args.robot)
    sim = simulate(
        robot, args.frames, noise_px=args.noise_px, outlier_fraction=args.outliers,
        seed=args.seed, fps=args.fps, motion=args.motion, spatial=args.spatial,
        moving_base=args.moving_base, scene=scene, n_points=args.points,
        track_lifetime=args.lifetime, blackout_fraction=args.blackout, decimals=args.decimals,
        progress=True,
    )
    if args.images:
        return _simulate_images(args, sim, out)
    save_sequence(sim.sequence, out)
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
    bound = sequence_bound(sim, noise_px, math.radians(0.1))
    return ("Cramer-Rao bound of the angles (every observation once, each track's point "
            "unknown, 0.1 deg start prior), RMS per segment: "
            + ", ".join(f"{v:.3f}" for v in np.degrees(bound.rms())) + " deg")


def _simulate_images(args: argparse.Namespace, sim: object, out: Path) -> str:
    """``simulate --images``: the sequence without tracks, and rendered images of the room."""
    from apcc_graph.io.sequence_folder import save_sequence
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
    save_sequence(bare, out)
    images = write_sequence_images(out, room, cameras, sim.world_T_cam, sensor, seed=args.seed,
                                   supersample=args.supersample or 2, progress=True)
    return "\n".join([
        f"wrote {out}: {seq.n_frames} frames at {args.fps:g} fps, {len(cameras)} camera(s), "
        f"seed {args.seed}, rendered images in {images} ({args.texture or 'skimage'} "
        f"textures, noise {sensor.noise_grey:g} grey levels)",
        f"next: apcc-graph track {out}",
    ])


# ------------------------------------------------------------------------- estimate / evaluate
def _theta0(text: str | None, n_segments: int) -> np.ndarray | None:
    if text is None:
        return None
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        raise UserError(f"--theta0-deg {text!r}: expected comma-separated degrees") from None
    if len(values) != n_segments or not all(math.isfinite(v) for v in values):
        raise UserError(f"--theta0-deg {text!r}: expected {n_segments} finite angles in degrees "
                        "(one per segment)")
    return np.radians(values)


DEFAULT_LAG = 1.0


def _run_estimate(args: argparse.Namespace) -> str:
    from apcc_graph.estimation.methods import estimate
    from apcc_graph.io.estimates import save_estimate
    from apcc_graph.io.sequence_folder import load_sequence

    sequence = load_sequence(args.sequence)
    theta0 = _theta0(args.theta0_deg, sequence.n_segments)
    options: dict = {"progress": True}
    if args.method == "smoother":
        if not (args.lag > 0.0 and math.isfinite(args.lag)):
            raise UserError(f"--lag {args.lag!r}: expected a positive number of seconds")
        options["lag"] = args.lag
    elif args.lag is not None and args.lag != DEFAULT_LAG:
        raise UserError("--lag applies to --method smoother only")
    if args.method != "chain":
        if not (math.isfinite(args.theta0_sigma_deg) and args.theta0_sigma_deg > 0.0):
            raise UserError(f"--theta0-sigma-deg {args.theta0_sigma_deg!r}: expected a "
                            "positive number of degrees")
        if not (math.isfinite(args.noise_px) and args.noise_px > 0.0):
            raise UserError(f"--noise-px {args.noise_px!r}: expected a positive number of "
                            "pixels")
        options["theta0_sigma"] = math.radians(args.theta0_sigma_deg)
        options["vision"] = args.vision
        options["threshold_px"] = args.noise_px
    elif args.vision is not None:
        raise UserError("--vision applies to --method batch and smoother only")
    if args.calibrate:
        if args.method == "chain" or (args.method == "smoother" and args.vision != "epipolar"):
            raise UserError("--calibrate: self-calibration runs in --method batch, or in "
                            "--method smoother --vision epipolar")
        options["calibrate"] = True
    try:
        result = estimate(sequence, method=args.method, theta0=theta0, **options)
    except ValueError as error:
        raise UserError(str(error)) from None
    written = save_estimate(result, args.out)
    if args.calibrate and args.method == "batch":
        from apcc_graph.io.robot_file import save_robot

        robot_path = Path(args.out) / "robot_calibrated.toml"
        save_robot(result.robot, robot_path)
        written = [*written, robot_path]
    lines = [f"{args.method}: {result.n_frames} frames, {sequence.n_segments} segments -> "
             f"{args.out} ({', '.join(p.name for p in written)})"]
    if args.calibrate and result.calibration_sigmas is not None:
        for i, (seg, sig) in enumerate(zip(result.robot.segments, result.calibration_sigmas,
                                           strict=True)):
            lines.append(f"segment {i + 1}: k = {seg.k:.4f} +/- {sig[0]:.4f}, delta_max = "
                         f"{math.degrees(seg.delta_max):.3f} +/- {math.degrees(sig[1]):.3f} deg")
    if sequence.thetas is not None:  # evaluation only: the estimator never read these
        rms = np.degrees(result.rms(sequence.thetas))
        lines.append("RMS error vs the sequence's ground truth: "
                     + ", ".join(f"segment {i + 1} {v:.3f} deg" for i, v in enumerate(rms)))
    return "\n".join(lines)


def _truth_for(estimate: str, thetas: np.ndarray, truth: str) -> np.ndarray:
    """The ground-truth angles of sequence folder ``truth``, checked against an estimate's."""
    from apcc_graph.io.sequence_folder import load_sequence

    seq = load_sequence(truth)
    if seq.thetas is None:
        raise UserError(f"{truth}: frames.csv has no ground-truth theta columns")
    if seq.thetas.shape != thetas.shape:
        raise UserError(f"{estimate}: {thetas.shape[0]} frames x {thetas.shape[1]} segments, "
                        f"but {truth} has {seq.thetas.shape[0]} x {seq.thetas.shape[1]}")
    return seq.thetas


def _run_evaluate(args: argparse.Namespace) -> str:
    from apcc_graph.evaluation.accuracy import compare
    from apcc_graph.io.estimates import load_theta_csv

    _, thetas, _ = load_theta_csv(Path(args.estimate) / "theta.csv")
    report = compare(thetas, _truth_for(args.estimate, thetas, args.truth), window=args.window)
    n_seg = thetas.shape[1]
    lines = [f"{'':<16}" + "".join(f"{f'segment {i + 1}':>12}" for i in range(n_seg)),
             f"{'RMS (deg)':<16}" + "".join(f"{v:>12.4f}" for v in np.degrees(report.rms)),
             f"{'max |err| (deg)':<16}" + "".join(f"{v:>12.4f}"
                                                  for v in np.degrees(report.max_abs)),
             f"RMS per window of {report.window} frames (deg):"]
    for start, row in zip(report.window_starts, report.window_rms, strict=True):
        lines.append(f"  frames {start:>6}-{min(start + report.window, thetas.shape[0]) - 1:<6}"
                     + "".join(f"{v:>12.4f}" for v in np.degrees(row)))
    return "\n".join(lines)


# --------------------------------------------------------------------------------------- bench
def _run_bench_kinematics(args: argparse.Namespace) -> str:
    from apcc_graph.bench.kinematics import run_kinematics_benchmark
    from apcc_graph.io.robot_file import load_robot

    if args.frames < 1 or args.repeats < 1:
        raise UserError("--frames and --repeats must be at least 1")
    robot = load_robot(args.robot)
    result = run_kinematics_benchmark(
        robot, n_frames=args.frames, repeats=args.repeats, seed=args.seed
    )
    lines = [
        f"forward kinematics, {result.n_segments}-segment robot ({args.robot}), "
        f"best of {args.repeats}:",
        f"  {'method':<34} {'frames':>9} {'wall time':>11} {'per frame':>11} {'ratio':>8}",
    ]
    for row in result.rows:
        lines.append(
            f"  {row.method:<34} {row.frames:>9} {row.seconds:>9.3f} s "
            f"{row.per_frame_ns:>8.0f} ns {result.ratio(row):>7.1f}x"
        )
    lines.append(f"  largest |difference| to the peers: {result.max_abs_difference:.2e}")
    ref = result.reference
    target = "met" if ref.seconds < 1.0 else "NOT met"
    if ref.frames == 1_000_000:
        lines.append(f"target: 10^6 frames under 1 s -> {ref.seconds:.3f} s ({target})")
    else:
        lines.append("target (10^6 frames under 1 s): run with --frames 1000000")
    return "\n".join(lines)


def _run_bench_sequences(args: argparse.Namespace) -> str:
    from apcc_graph.bench.sequences import run_sequence_benchmark
    from apcc_graph.io.robot_file import load_robot

    robot = load_robot(args.robot)
    if not robot.camera_segments:
        raise UserError(f"{args.robot}: the robot has no camera")
    r = run_sequence_benchmark(robot, n_frames=args.frames, target_rows=args.rows,
                               repeats=args.repeats, seed=args.seed)
    lines = [
        f"sequences: {robot.n_segments} segments, {r.n_frames} frames, "
        f"{r.tracks_per_camera:.0f} tracks per camera and frame:",
        f"  {r.simulate.step:<40} {r.simulate.rows:>9} rows {r.simulate.seconds:>8.3f} s",
        f"  {r.save.step:<40} {r.save.rows:>9} rows {r.save.seconds:>8.3f} s",
        f"  {r.load.step:<40} {r.load.rows:>9} rows {r.load.seconds:>8.3f} s   1.0x",
    ]
    for peer in r.peers:
        lines.append(f"  {peer.step:<40} {peer.rows:>9} rows {peer.seconds:>8.3f} s "
                     f"{peer.seconds / r.load.seconds:>5.1f}x")
    per_million = r.load.seconds * 1e6 / r.load.rows
    lines.append(f"load time per million track rows: {per_million:.2f} s (target: well under 2 s)")
    return "\n".join(lines)


def _run_bench_solver(args: argparse.Namespace) -> str:
    from apcc_graph.bench.solver import run_solver_benchmark

    r = run_solver_benchmark(trials=args.trials, seed=args.seed)
    ours = "one_point_ransac"
    lines = [f"1-point RANSAC vs essential-matrix peers, {r.trials} trials per setting, 0.5 px, "
             "0.5 m segment moving 3-5 deg, f = 500 px (median time, median |theta error|):",
             f"  {'method':<32} {'N':>5} {'out':>4} {'time':>10} {'|error|':>11} "
             f"{'time/ours':>9} {'err/ours':>8} {'fail':>4}"]
    for row in r.rows:
        ref = r.row(ours, row.n_points, row.outlier_fraction)
        lines.append(
            f"  {row.method:<32} {row.n_points:>5} {row.outlier_fraction:>4.0%} "
            f"{row.median_seconds * 1e3:>7.2f} ms {math.degrees(row.median_error):>7.4f} deg "
            f"{row.median_seconds / ref.median_seconds:>8.1f}x "
            f"{row.median_error / ref.median_error:>7.2f}x {row.failures:>4}")
    if "poselib.estimate_relative_pose" not in r.methods:
        lines.append("  (PoseLib not installed: pip install 'apcc-graph[bench]' adds it)")
    lines.append(f"minimal solver: {r.minimal_cost * 1e6:.2f} us per correspondence in a batch "
                 "of 1000 (target: under 2 us)")
    return "\n".join(lines)


def _run_bench_accuracy(args: argparse.Namespace) -> str:
    from apcc_graph.bench.accuracy import run_accuracy_benchmark

    if args.plot is not None:
        from apcc_graph.plots import check_figure_path

        check_figure_path(args.plot)
    r = run_accuracy_benchmark(trials=args.trials, points=args.points, seed=args.seed,
                               progress=True)
    lines = [f"Fig. 10 protocol: {r.points} points, no outliers, {r.rows[0].trials} trials per "
             "point; efficiency = median(|error| / CRB) / 0.6745 (1.0 = at the bound)",
             f"  {'base':<7} {'noise':>6} {'mean |err|':>12} {'median |err|':>13} "
             f"{'median CRB':>12} {'efficiency':>10} {'fail':>5}"]
    for row in r.rows:
        eff = "-" if math.isnan(row.efficiency) else f"{row.efficiency:.2f}"
        lines.append(
            f"  {row.base:<7} {row.noise_px:>4.1f}px {math.degrees(row.mean_error):>8.4f} deg "
            f"{math.degrees(row.median_error):>9.4f} deg {math.degrees(row.median_bound):>8.4f}"
            f" deg {eff:>10} {row.failures:>5}")
    if args.plot is not None:
        from apcc_graph.plots import noise_figure, save_figure

        lines.append(f"wrote {save_figure(noise_figure(r), args.plot)}")
    return "\n".join(lines)


# ------------------------------------------------------------------------------------------ plot
def _run_plot(args: argparse.Namespace) -> str:
    from apcc_graph.io.estimates import load_theta_csv
    from apcc_graph.plots import angles_figure, check_figure_path, save_figure

    check_figure_path(args.output)
    timestamps, thetas, sigmas = load_theta_csv(Path(args.estimate) / "theta.csv")
    truth = None if args.truth is None else _truth_for(args.estimate, thetas, args.truth)
    fig = angles_figure(timestamps, thetas, sigmas, truth, n_sigma=args.sigmas,
                        label=Path(args.estimate).name or "estimate")
    return f"wrote {save_figure(fig, args.output)}"


def _run_bench_tracking(args: argparse.Namespace) -> str:
    from apcc_graph.bench.tracking import format_tracking_benchmark, run_tracking_benchmark

    if not (args.noise >= 0.0 and math.isfinite(args.noise)):
        raise UserError(f"--noise {args.noise!r}: expected grey levels >= 0")
    rows = run_tracking_benchmark(frames=args.frames, seed=args.seed, noise=args.noise)
    return format_tracking_benchmark(rows, args.frames, args.noise)


def _run_bench_images(args: argparse.Namespace) -> str:
    from apcc_graph.bench.images import format_images_benchmark, run_images_benchmark

    seeds = _int_list(args.seeds, "--seeds")
    try:
        runs = run_images_benchmark(frames=args.frames, seeds=tuple(seeds),
                                    noise_grey=args.noise, texture_source=args.texture,
                                    progress=True)
    except ImportError as error:
        raise UserError(str(error)) from None
    return format_images_benchmark(runs, args.frames, args.noise)


def _int_list(text: str, option: str) -> list[int]:
    try:
        values = [int(v) for v in text.split(",") if v.strip()]
    except ValueError:
        values = []
    if not values:
        raise UserError(f"{option} {text!r}: expected comma-separated integers, e.g. 1,2,3")
    return values


def _run_bench_smoother(args: argparse.Namespace) -> str:
    from apcc_graph.bench.smoother import METHODS, format_smoother_benchmark, run_smoother_benchmark

    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    unknown = [m for m in methods if m not in METHODS]
    if unknown or not methods:
        raise UserError(f"--methods {args.methods!r}: expected a comma-separated subset of "
                        f"{', '.join(METHODS)}")
    if args.long_frames and args.long_frames < 400:
        raise UserError(f"--long-frames {args.long_frames}: expected 0 (skip) or at least 400")
    if args.memory_frames and args.memory_frames < 1000:
        raise UserError(f"--memory-frames {args.memory_frames}: expected 0 (skip) or at least "
                        "1000")
    try:
        outliers = [float(v) for v in args.outliers.split(",") if v.strip()]
    except ValueError:
        outliers = []
    if not outliers or not all(0.0 <= v < 1.0 for v in outliers):
        raise UserError(f"--outliers {args.outliers!r}: expected comma-separated fractions in "
                        "[0, 1), e.g. 0.1,0.3")
    result = run_smoother_benchmark(frames=args.frames, seeds=_int_list(args.seeds, "--seeds"),
                                    outliers=outliers, methods=methods,
                                    long_frames=args.long_frames,
                                    memory_frames=args.memory_frames, progress=True)
    return format_smoother_benchmark(result)


def _run_bench_selfcal(args: argparse.Namespace) -> str:
    from apcc_graph.bench.self_calibration import (
        format_self_calibration_benchmark,
        run_self_calibration_benchmark,
    )

    if not 0.0 <= args.outliers < 1.0:
        raise UserError(f"--outliers {args.outliers!r}: expected a fraction in [0, 1)")
    result = run_self_calibration_benchmark(
        frames=args.frames, seeds=_int_list(args.seeds, "--seeds"), outliers=args.outliers,
        dk=args.dk, dd=math.radians(args.dd_deg), progress=True)
    return format_self_calibration_benchmark(result)


def _run_bench_calibration(args: argparse.Namespace) -> str:
    from apcc_graph.bench.calibration import run_calibration_benchmark

    if args.poses < 2:
        raise UserError("--poses must be at least 2")
    if not 0.0 < args.theta_max_deg <= 180.0:
        raise UserError("--theta-max-deg must be in (0, 180]")
    if args.growth <= -1.0:
        raise UserError("--growth must be > -1")
    if args.length <= 0.0 or args.noise_mm < 0.0 or args.noise_deg < 0.0:
        raise UserError("--length must be > 0, --noise-mm and --noise-deg >= 0")
    result = run_calibration_benchmark(
        length=args.length,
        growth=args.growth,
        n_poses=args.poses,
        theta_max=math.radians(args.theta_max_deg),
        noise_position=args.noise_mm * 1e-3,
        noise_angle=math.radians(args.noise_deg),
        seed=args.seed,
    )
    lines = [
        f"calibration on a rod of {result.length} m whose curvature grows {1 + result.growth:g}x "
        f"from base to tip;",
        f"{result.n_poses} poses in +/-{math.degrees(result.theta_max):g} deg, noise "
        f"{result.noise_position * 1e3:g} mm and {math.degrees(result.noise_angle):g} deg "
        f"(seed {args.seed}); errors against the true tips:",
        f"  {'model':<44} {'RMS tip pos':>12} {'RMS tip angle':>14} {'k':>7} {'delta_max':>10}",
    ]
    for row in result.rows:
        k = "-" if math.isnan(row.k) else f"{row.k:.4f}"
        lines.append(
            f"  {row.model:<44} {row.rms_position * 1e3:>9.3f} mm "
            f"{math.degrees(row.rms_angle):>10.3f} deg {k:>7} {_deg(row.delta_max):>10}"
        )
    sweep, pcc = result.rows[0], result.row("PCC (best fit)")
    lines.append(f"PCC / APCC sweep tip error ratio: {pcc.rms_position / sweep.rms_position:.1f}x")
    return "\n".join(lines)


# -------------------------------------------------------------------------------------- parser
class _Parser(argparse.ArgumentParser):
    """An argument parser whose usage errors are one line on stderr and exit code 1."""

    def error(self, message: str) -> NoReturn:
        self.exit(1, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of ``apcc-graph`` (subcommands and their options)."""
    parser = _Parser(
        prog="apcc-graph",
        description="Continuum-robot shape from tip cameras (APCC 2L-5R).",
    )
    parser.add_argument("--version", action="version", version=f"apcc-graph {__version__}")
    parser.add_argument("--debug", action="store_true", help="show tracebacks on errors")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)

    fmt = argparse.RawDescriptionHelpFormatter
    cal = sub.add_parser(
        "calibrate",
        help="calibrate k and delta_max of a segment from measured tip poses or marker images",
        description="Calibrate one segment from a TOML file of measured tip poses "
        "(format apcc-graph/calibration@1) or from a folder of side-camera images with ArUco "
        "markers on the base and the tip (calibration.toml, format "
        "apcc-graph/calibration-images@1, and *.png): one pose by the paper's closed form, "
        "several by least squares. Prints the tip measured in each image, the model and the "
        "APCC-vs-PCC residuals.",
        epilog=_EXAMPLES["calibrate"],
        formatter_class=fmt,
    )
    cal.add_argument("file", metavar="PATH",
                     help="calibration TOML file, or folder of calibration images")
    cal.add_argument(
        "--output",
        metavar="ROBOT.toml",
        help="also write a one-segment robot.toml with the calibrated segment",
    )
    syn = cal.add_argument_group(
        "synthetic images", "--render first writes a seeded synthetic image folder to PATH (the\n"
        "segment below bent to each of --bends-deg, seen by a 640x480 side camera), then\n"
        "calibrates it")
    syn.add_argument("--render", action="store_true", help="render synthetic images into PATH")
    syn.add_argument("--length", type=_positive, help="segment length, metres")
    syn.add_argument("--k", type=float, help="true k, 0 < k < 0.5")
    syn.add_argument("--delta-max-deg", type=float, help="true delta_max, degrees (default 0)")
    syn.add_argument("--theta-max-deg", type=float,
                     help="true theta_max, degrees (default: the largest |bend|)")
    syn.add_argument("--bends-deg", help="comma-separated bends, degrees, one image each "
                     "(write --bends-deg=-80,-40,0 when the first is negative)")
    syn.add_argument("--seed", type=int, help="random seed (default 0)")
    syn.add_argument("--noise", type=_non_negative,
                     help="sensor noise, grey levels (default 1)")
    syn.add_argument("--tilt-deg", type=float,
                     help="camera tilt away from parallel, degrees, about the image diagonal "
                     "(default 0)")
    syn.add_argument("--force", action="store_true",
                     help="render into a non-empty PATH (replaces its calibration.toml and *.png)")
    cal.set_defaults(run=_run_calibrate)

    simp = sub.add_parser(
        "simulate", help="simulate a sequence of tip-camera tracks with ground truth",
        description="Simulate what the tip cameras of a robot see along a random motion and "
        "write the sequence folder (robot.toml, frames.csv with ground truth, tracks/).",
        epilog=_EXAMPLES["simulate"], formatter_class=fmt,
    )
    simp.add_argument("--robot", required=True, help="robot.toml")
    simp.add_argument("--frames", type=_at_least(2), required=True, help="number of frames")
    simp.add_argument("--out", required=True, help="output sequence folder")
    simp.add_argument("--noise-px", type=_non_negative, default=0.5,
                      help="pixel noise std (default 0.5)")
    simp.add_argument("--outliers", type=_fraction, default=0.0,
                      help="fraction of wrong associations, 0 <= p < 1 (default 0)")
    simp.add_argument("--seed", type=int, default=0)
    simp.add_argument("--fps", type=_positive, default=30.0)
    simp.add_argument("--motion", choices=("smooth", "paper"), default="smooth",
                      help="smooth random motion, or the paper's random steps under 5 deg")
    simp.add_argument("--spatial", action="store_true", help="also vary the bending planes psi")
    simp.add_argument("--moving-base", action="store_true",
                      help="move the base (rotation up to 5 deg, translation up to 0.1 m)")
    simp.add_argument("--scene", choices=("points", "room"), default=None,
                      help="random points around the robot, or points on the walls of a room "
                      "(default: points; room with --images)")
    simp.add_argument("--points", type=_at_least(1), default=2700, help="scene points")
    simp.add_argument("--lifetime", type=_positive, default=None,
                      help="mean track length in frames (default: while in view)")
    simp.add_argument("--blackout", type=_fraction, default=0.0,
                      help="fraction of frames in which a camera sees nothing")
    simp.add_argument("--decimals", type=int, default=None,
                      help="round pixels to this many decimals (default: full precision)")
    simp.add_argument("--force", action="store_true", help="write into a non-empty --out")
    img = simp.add_argument_group(
        "images", "--images renders what each tip camera sees of a textured room into\n"
        "images/cam_<i>/<frame:06d>.png instead of writing simulated tracks (run\n"
        "`apcc-graph track` next)")
    img.add_argument("--images", action="store_true", help="render images of the room")
    img.add_argument("--texture", choices=("skimage", "procedural"), default=None,
                     help="wall textures: scikit-image's bundled photos (pip install "
                     "'apcc-graph[images]') or seeded noise (default: skimage)")
    img.add_argument("--image-noise", type=_non_negative, default=None,
                     help="sensor noise, grey levels (default 2)")
    img.add_argument("--blur", type=_non_negative, default=None,
                     help="Gaussian blur, pixels (default 0)")
    img.add_argument("--exposure", type=_fraction, default=None,
                     help="largest relative exposure change over the sequence (default 0)")
    img.add_argument("--supersample", type=int, choices=(1, 2, 3, 4), default=None,
                     help="rays per pixel side (default 2)")
    simp.set_defaults(run=_run_simulate)

    trk = sub.add_parser(
        "track", help="turn a sequence folder's images into tracks (OpenCV KLT)",
        description="Detect Shi-Tomasi corners in images/cam_<i>/<frame:06d>.png and follow "
        "them with pyramidal Lucas-Kanade (forward-backward checked); write tracks/cam_<i>.csv.",
        epilog=_EXAMPLES["track"], formatter_class=fmt,
    )
    trk.add_argument("sequence", help="sequence folder with images/")
    trk.add_argument("--force", action="store_true",
                     help="replace tracks files that already hold observations")
    trk.set_defaults(run=_run_track)

    est = sub.add_parser(
        "estimate", help="estimate every frame's segment angles of a sequence folder",
        description="Estimate the bending angles of a sequence and write theta.csv and one "
        "TUM trajectory per segment tip (tips_seg_<i>.tum) into --out.",
        epilog=_EXAMPLES["estimate"], formatter_class=fmt,
    )
    est.add_argument("sequence", help="sequence folder")
    est.add_argument("--method", choices=("chain", "batch", "smoother"), default="batch",
                     help="chain: the paper's frame-by-frame method; batch: the whole sequence "
                     "in one factor graph; smoother: fixed-lag smoother, frame by frame "
                     "(default: %(default)s)")
    est.add_argument("--lag", type=float, default=DEFAULT_LAG,
                     help="smoother window in seconds (default: %(default)s)")
    est.add_argument("--out", required=True, help="output folder")
    est.add_argument("--theta0-deg", default=None,
                     help="starting configuration, degrees, one per segment (default straight);"
                     " write --theta0-deg=-10,5,3 when the first angle is negative")
    est.add_argument("--theta0-sigma-deg", type=float, default=0.1,
                     help="how well the starting configuration is known: standard deviation "
                     "of its prior, degrees (default: %(default)s)")
    est.add_argument("--noise-px", type=float, default=1.0,
                     help="pixel noise of the tracks, standard deviation per coordinate "
                     "(default: %(default)s); sets the outlier threshold and the sigmas")
    est.add_argument("--vision", choices=("projection", "epipolar"), default=None,
                     help="vision model: projection (default: every observation once, each "
                     "track's point eliminated) or epipolar (frame pairs, for comparison)")
    est.add_argument("--calibrate", action="store_true",
                     help="self-calibration: estimate each segment's k and delta_max with the "
                     "angles (batch; or smoother with --vision epipolar); the batch writes "
                     "robot_calibrated.toml")
    est.set_defaults(run=_run_estimate)

    ev = sub.add_parser(
        "evaluate", help="compare an estimate with a sequence's ground truth",
        description="RMS and max error per segment, overall and per window of frames (so "
        "drift shows).",
        epilog=_EXAMPLES["evaluate"], formatter_class=fmt,
    )
    ev.add_argument("estimate", help="folder with theta.csv (the --out of estimate)")
    ev.add_argument("--truth", required=True, help="sequence folder with ground truth")
    ev.add_argument("--window", type=_at_least(1), default=100, help="frames per window")
    ev.set_defaults(run=_run_evaluate)

    plt = sub.add_parser(
        "plot", help="plot an estimate's angles against time (and the truth, with errors)",
        description="Draw every segment's estimated angle over time with a band of --sigmas "
        "marginal standard deviations, the ground truth and the error when --truth is given "
        "(the paper's Fig. 11).",
        epilog=_EXAMPLES["plot"], formatter_class=fmt,
    )
    plt.add_argument("estimate", help="folder with theta.csv (the --out of estimate)")
    plt.add_argument("--truth", help="sequence folder with ground truth")
    plt.add_argument("--output", required=True, metavar="FIG.png",
                     help="figure file (png, pdf, svg, ...)")
    plt.add_argument("--sigmas", type=_positive, default=2.0,
                     help="half-width of the uncertainty band in sigmas (default 2)")
    plt.set_defaults(run=_run_plot)

    bench = sub.add_parser(
        "bench", help="benchmarks against named peers (figures, not tests)",
        description="Speed and accuracy figures of apcc_graph and of named peers measured in "
        "the same run. Each benchmark has its own --help.",
        epilog="examples:\n" + "\n".join(
            line for key, text in _EXAMPLES.items() if key.startswith("bench ")
            for line in text.splitlines()[1:]),
        formatter_class=fmt)
    bench_sub = bench.add_subparsers(dest="bench", metavar="BENCHMARK", required=True)
    kin = bench_sub.add_parser(
        "kinematics",
        help="vectorised forward kinematics vs a matmul chain and a gtsam loop",
        description="Time Robot.forward over many frames, and its peers on the same angles.",
        epilog=_EXAMPLES["bench kinematics"],
        formatter_class=fmt,
    )
    kin.add_argument(
        "--robot",
        default="data/robots/planar_three.toml",
        help="robot.toml (default: the repository's three-segment planar robot)",
    )
    kin.add_argument("--frames", type=int, default=1_000_000, help="frames (default 10^6)")
    kin.add_argument("--repeats", type=int, default=3, help="timing repeats, best kept")
    kin.add_argument("--seed", type=int, default=0)
    kin.set_defaults(run=_run_bench_kinematics)

    seqb = bench_sub.add_parser(
        "sequences", help="simulate, save and load sequences; load vs loadtxt and csv peers",
        description="Time the simulator (3 x 1000 frames x ~200 tracks) and loading about a "
        "million track rows, with numpy.loadtxt and the csv module as peers.",
        epilog=_EXAMPLES["bench sequences"], formatter_class=fmt,
    )
    seqb.add_argument("--robot", default="data/robots/planar_three.toml")
    seqb.add_argument("--frames", type=_at_least(2), default=1000)
    seqb.add_argument("--rows", type=_at_least(1), default=1_000_000,
                      help="track rows for the load test (default 10^6)")
    seqb.add_argument("--repeats", type=_at_least(1), default=3)
    seqb.add_argument("--seed", type=int, default=0)
    seqb.set_defaults(run=_run_bench_sequences)

    solb = bench_sub.add_parser(
        "solver", help="1-point RANSAC vs OpenCV (and PoseLib) essential-matrix RANSAC",
        description="Time and accuracy of one_point_ransac against cv2.findEssentialMat "
        "(RANSAC and USAC_DEFAULT) + recoverPose and PoseLib, on the same correspondences.",
        epilog=_EXAMPLES["bench solver"], formatter_class=fmt,
    )
    solb.add_argument("--trials", type=_at_least(1), default=20, help="trials per setting")
    solb.add_argument("--seed", type=int, default=0)
    solb.set_defaults(run=_run_bench_solver)

    accb = bench_sub.add_parser(
        "accuracy", help="the paper's Fig. 10 protocol: error vs pixel noise against the CRB",
        description="Fixed and moving base, noise 0-2 px: mean and median error of "
        "one_point_ransac and their ratio to the Cramer-Rao bound.",
        epilog=_EXAMPLES["bench accuracy"], formatter_class=fmt,
    )
    accb.add_argument("--trials", type=_at_least(1), default=5000,
                      help="trials per noise level (the paper: 5000)")
    accb.add_argument("--points", type=_at_least(1), default=100,
                      help="correspondences per trial")
    accb.add_argument("--seed", type=int, default=0)
    accb.add_argument("--plot", metavar="FIG.png",
                      help="also write the error-vs-noise figure (the paper's Fig. 10)")
    accb.set_defaults(run=_run_bench_accuracy)

    calb = bench_sub.add_parser(
        "calibration",
        help="sweep fit vs one-pose calibration vs PCC on a varying-curvature rod",
        description="Fit APCC (sweep and one pose) and PCC to a noisy synthetic sweep of a rod "
        "whose curvature grows along the arc, and compare each with the true tips.",
        epilog=_EXAMPLES["bench calibration"],
        formatter_class=fmt,
    )
    calb.add_argument("--length", type=float, default=0.5, help="rod length, metres")
    calb.add_argument(
        "--growth",
        type=float,
        default=2.0,
        help="curvature growth g: tip curvature is 1+g times the base's",
    )
    calb.add_argument("--poses", type=int, default=41)
    calb.add_argument("--theta-max-deg", type=float, default=80.0)
    calb.add_argument("--noise-mm", type=float, default=0.5)
    calb.add_argument("--noise-deg", type=float, default=0.5)
    calb.add_argument("--seed", type=int, default=0)
    calb.set_defaults(run=_run_bench_calibration)

    smb = bench_sub.add_parser(
        "smoother",
        help="the back end against the Cramer-Rao bound: accuracy, drift, speed, memory",
        description="Simulate 3-segment room-scene sequences (1 px noise, 10%% and 30%% "
        "outliers, ~150 tracks per camera, 30 fps) and measure the chain, the fixed-lag "
        "smoother, the batch and the epipolar smoother beside the Cramer-Rao bound of the "
        "same sequences (and the smoothers beside the bound of a 1 s fixed lag), in one run.",
        epilog=_EXAMPLES["bench smoother"], formatter_class=fmt,
    )
    smb.add_argument("--frames", type=_at_least(30), default=600,
                     help="frames of each accuracy run")
    smb.add_argument("--seeds", default="1,2,3,4,5", help="simulation seeds, comma-separated")
    smb.add_argument("--methods", default="chain,smoother,batch,epipolar smoother",
                     help="estimators, comma-separated (default: %(default)s)")
    smb.add_argument("--outliers", default="0.1,0.3",
                     help="outlier fractions, comma-separated (default: %(default)s)")
    smb.add_argument("--long-frames", type=int, default=3000,
                     help="frames of the drift and speed run (0 to skip)")
    smb.add_argument("--memory-frames", type=int, default=10_000,
                     help="frames of the memory run (0 to skip)")
    smb.set_defaults(run=_run_bench_smoother)

    scb = bench_sub.add_parser(
        "selfcal",
        help="self-calibration of k and delta_max beside the Cramer-Rao bound",
        description="Simulate room-scene sequences of the 3-segment robot, give the batch "
        "segment models with k and delta_max off, and compare the batch with the true "
        "models, the wrong ones and the wrong ones self-calibrated, beside the bound with "
        "the models known and unknown (which also bounds k and delta_max).",
        epilog=_EXAMPLES["bench selfcal"], formatter_class=fmt,
    )
    scb.add_argument("--frames", type=_at_least(30), default=600)
    scb.add_argument("--seeds", default="1,2,3", help="simulation seeds, comma-separated")
    scb.add_argument("--outliers", type=float, default=0.1, help="outlier fraction")
    scb.add_argument("--dk", type=float, default=0.03, help="error of every segment's k")
    scb.add_argument("--dd-deg", type=float, default=3.0,
                     help="error of every segment's delta_max, degrees")
    scb.set_defaults(run=_run_bench_selfcal)

    trb = bench_sub.add_parser(
        "tracking", help="KLT tracking vs ORB matching: images per second and pixel error",
        description="Track a seeded textured image sequence whose frame-to-frame homographies "
        "are known, with the KLT tracker and with ORB + brute-force matching, and score both.",
        epilog=_EXAMPLES["bench tracking"], formatter_class=fmt,
    )
    trb.add_argument("--frames", type=_at_least(3), default=200)
    trb.add_argument("--noise", type=float, default=2.0, help="sensor noise, grey levels")
    trb.add_argument("--seed", type=int, default=0)
    trb.set_defaults(run=_run_bench_tracking)

    imb = bench_sub.add_parser(
        "images", help="images -> tracks -> smoother vs the same motion as simulated tracks",
        description="Render each tip camera's view of a textured room along a simulated "
        "motion, track the images (KLT) and run the smoother; compare with the same motion "
        "observed as simulated 1 px tracks, and time the "
        "tracker.",
        epilog=_EXAMPLES["bench images"], formatter_class=fmt,
    )
    imb.add_argument("--frames", type=_at_least(10), default=150)
    imb.add_argument("--seeds", default="1,2,3,4,5", help="comma-separated seeds")
    imb.add_argument("--noise", type=_non_negative, default=2.0,
                     help="sensor noise, grey levels (default 2)")
    imb.add_argument("--texture", choices=("skimage", "procedural"), default="skimage")
    imb.set_defaults(run=_run_bench_images)
    return parser


def _number_type(check: Callable[[float], bool], what: str,
                 cast: Callable[[str], float] = float) -> Callable[[str], float]:
    def parse(text: str) -> float:
        try:
            value = cast(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
        if not (math.isfinite(value) and check(value)):
            raise argparse.ArgumentTypeError(f"{text!r}: expected {what}")
        return value

    return parse


_positive = _number_type(lambda v: v > 0, "a number > 0")
_non_negative = _number_type(lambda v: v >= 0, "a number >= 0")
_fraction = _number_type(lambda v: 0 <= v < 1, "a fraction 0 <= p < 1")


def _at_least(minimum: int) -> Callable[[str], float]:
    return _number_type(lambda v: v >= minimum, f"an integer >= {minimum}", int)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``apcc-graph``; returns the exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        print(args.run(args))
    except (UserError, ValueError, OSError) as exc:
        if args.debug:
            raise
        message = (
            str(exc)
            if not isinstance(exc, OSError) or not exc.filename
            else (f"{exc.filename}: {exc.strerror}")
        )
        print(f"apcc-graph: error: {message}", file=sys.stderr)
        return 1
    return 0
