"""``apcc-graph bench`` for the model and the front end: forward kinematics, sequence files, the
1-point solver against essential-matrix peers, the paper's Fig. 10 protocol, calibration (Fig.
9) and feature tracking. Each prints figures and ratios against peers measured in the same run.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Sequence

from apcc_graph.cli.common import (
    FORMATTER,
    UserError,
    at_least,
    bench_robot_option,
    deg,
    frames_option,
    seed_option,
)

EXAMPLES = {
    "kinematics": "apcc-graph bench kinematics --frames 1000000",
    "sequences": "apcc-graph bench sequences --frames 1000 --rows 1000000",
    "solver": "apcc-graph bench solver --trials 20",
    "spatial-solver": "apcc-graph bench spatial-solver --cases 2000 --trials 100",
    "accuracy": "apcc-graph bench accuracy --trials 1000 --plot /tmp/fig10.png",
    "calibration": "apcc-graph bench calibration --growth 2 --seed 0",
    "tracking": "apcc-graph bench tracking --frames 200",
}
"""One example command per benchmark of this module."""


def _bench(benches: argparse._SubParsersAction, name: str,
           parents: Sequence[argparse.ArgumentParser] = (), **kwargs: object
           ) -> argparse.ArgumentParser:
    """Add benchmark ``name`` with its example, ``--seed`` and the other ``parents``."""
    return benches.add_parser(name, epilog=f"example:\n  {EXAMPLES[name]}",
                              formatter_class=FORMATTER,
                              parents=[seed_option(0), *parents], **kwargs)


def add_parsers(benches: argparse._SubParsersAction) -> None:
    """Add this module's benchmarks to ``apcc-graph bench``."""
    kin = _bench(benches, "kinematics",
                 help="vectorised forward kinematics vs a matmul chain and a gtsam loop",
                 description="Time Robot.forward over many frames, and its peers on the same "
                 "angles.",
                 parents=[bench_robot_option(),
                          frames_option(1_000_000, minimum=None, help="frames (default 10^6)")])
    kin.add_argument("--repeats", type=int, default=3, help="timing repeats, best kept")
    kin.set_defaults(run=run_kinematics)

    seqb = _bench(benches, "sequences",
                  help="simulate, save and load sequences; load vs loadtxt and csv peers",
                  description="Time the simulator (3 x 1000 frames x ~200 tracks) and loading "
                  "about a million track rows, with numpy.loadtxt and the csv module as peers.",
                  parents=[bench_robot_option(), frames_option(1000, minimum=2)])
    seqb.add_argument("--rows", type=at_least(1), default=1_000_000,
                      help="track rows for the load test (default 10^6)")
    seqb.add_argument("--repeats", type=at_least(1), default=3)
    seqb.set_defaults(run=run_sequences)

    solb = _bench(benches, "solver",
                  help="1-point RANSAC vs OpenCV (and PoseLib) essential-matrix RANSAC",
                  description="Time and accuracy of one_point_ransac against "
                  "cv2.findEssentialMat (RANSAC and USAC_DEFAULT) + recoverPose and PoseLib, on "
                  "the same correspondences.")
    solb.add_argument("--trials", type=at_least(1), default=20, help="trials per setting")
    solb.set_defaults(run=run_solver)

    spb = _bench(benches, "spatial-solver",
                 help="2-point solver of a spatial segment; its RANSAC vs OpenCV 5-point RANSAC",
                 description="True-root rate of the 2-point solver on noise-free random cases, "
                 "and time and bending-vector error of two_point_ransac against "
                 "cv2.findEssentialMat (RANSAC) + recoverPose on the same correspondences "
                 "(200, 0.5 px, 10% outliers, f = 500 px). two_point_ransac is timed warm; the "
                 "first call (numba compiling its kernels, or loading them from numba's "
                 "cache) is reported apart, and the numpy reference engine beside it.")
    spb.add_argument("--cases", type=at_least(1), default=2000,
                     help="noise-free random cases of the minimal solver (default 2000)")
    spb.add_argument("--trials", type=at_least(1), default=100,
                     help="RANSAC trials, 200 correspondences each (default 100)")
    spb.set_defaults(run=run_spatial_solver)
    _add_accuracy_benches(benches)


def _add_accuracy_benches(benches: argparse._SubParsersAction) -> None:
    accb = _bench(benches, "accuracy",
                  help="the paper's Fig. 10 protocol: error vs pixel noise against the CRB",
                  description="Fixed and moving base, noise 0-2 px: mean and median error of "
                  "one_point_ransac and their ratio to the Cramer-Rao bound.")
    accb.add_argument("--trials", type=at_least(1), default=5000,
                      help="trials per noise level (the paper: 5000)")
    accb.add_argument("--points", type=at_least(1), default=100,
                      help="correspondences per trial")
    accb.add_argument("--plot", metavar="FIG.png",
                      help="also write the error-vs-noise figure (the paper's Fig. 10)")
    accb.set_defaults(run=run_accuracy)

    calb = _bench(benches, "calibration",
                  help="sweep fit vs one-pose calibration vs PCC on a varying-curvature rod",
                  description="Fit APCC (sweep and one pose) and PCC to a noisy synthetic sweep "
                  "of a rod whose curvature grows along the arc, and compare each with the true "
                  "tips.")
    calb.add_argument("--length", type=float, default=0.5, help="rod length, metres")
    calb.add_argument("--growth", type=float, default=2.0,
                      help="curvature growth g: tip curvature is 1+g times the base's")
    calb.add_argument("--poses", type=int, default=41)
    calb.add_argument("--theta-max-deg", type=float, default=80.0)
    calb.add_argument("--noise-mm", type=float, default=0.5)
    calb.add_argument("--noise-deg", type=float, default=0.5)
    calb.set_defaults(run=run_calibration)

    trb = _bench(benches, "tracking",
                 help="KLT tracking vs ORB matching: images per second and pixel error",
                 description="Track a seeded textured image sequence whose frame-to-frame "
                 "homographies are known, with the KLT tracker and with ORB + brute-force "
                 "matching, and score both.", parents=[frames_option(200, minimum=3)])
    trb.add_argument("--noise", type=float, default=2.0, help="sensor noise, grey levels")
    trb.set_defaults(run=run_tracking)


def run_kinematics(args: argparse.Namespace) -> str:
    """Time forward kinematics and its peers; return the table."""
    from apcc_graph.bench.kinematics import run_kinematics_benchmark
    from apcc_graph.io import load_robot

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


def run_sequences(args: argparse.Namespace) -> str:
    """Time simulating, saving and loading sequences; return the table."""
    from apcc_graph.bench.sequences import run_sequence_benchmark
    from apcc_graph.io import load_robot

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


def run_solver(args: argparse.Namespace) -> str:
    """Time the 1-point RANSAC and its peers; return the table."""
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


def run_spatial_solver(args: argparse.Namespace) -> str:
    """Run the 2-point solver's figures; return the table."""
    from apcc_graph.bench.spatial_solver import run_spatial_solver_benchmark

    r = run_spatial_solver_benchmark(cases=args.cases, trials=args.trials, seed=args.seed)
    rate = r.found / r.cases
    lines = [
        f"2-point solver, {r.cases} noise-free random cases: true bend among the roots in "
        f"{r.found} of {r.cases} ({rate:.2%}; target >= 99.5% -> "
        f"{'met' if rate >= 0.995 else 'NOT met'}), {r.mean_roots:.2f} roots per case",
        f"2-point RANSAC vs OpenCV 5-point RANSAC, {r.trials} trials: 200 correspondences, "
        "0.5 px, 10% outliers, f = 500 px (median time, median |b error|):",
        f"  {'method':<34} {'time':>10} {'|b error|':>12} {'time/ours':>9} {'fail':>4} "
        f"{'>5deg':>5}",
    ]
    rows = [("two_point_ransac", r.ransac_seconds, r.ransac_error, r.ransac_failures,
             str(r.ransac_gross)),
            ("cv2.findEssentialMat RANSAC", r.opencv_seconds, math.nan, r.opencv_failures, "-"),
            ("cv2 RANSAC + recoverPose", r.opencv_pose_seconds, r.opencv_error,
             r.opencv_failures, str(r.opencv_gross))]
    for name, seconds, error, fails, gross in rows:
        err = "-" if math.isnan(error) else f"{math.degrees(error):.4f} deg"
        lines.append(f"  {name:<34} {seconds * 1e3:>7.3f} ms {err:>12} "
                     f"{seconds / r.ransac_seconds:>8.1f}x {fails:>4} {gross:>5}")
    lines.append("  (>5deg: bending vector more than 5 deg off; OpenCV's are the twisted pair, a "
                 "rotation 180 deg off that the short baseline cannot rule out)")
    lines.append(f"  ours keeps {r.inliers_kept:.1%} of the true inliers and accepts "
                 f"{r.outliers_accepted:.1%} of the outliers (means over trials)")
    lines.append(f"  two_point_ransac's times leave out its first call in this process: "
                 f"{r.first_call_seconds:.2f} s ({r.first_call}; numba compiles the kernels "
                 "once per environment and caches them)")
    lines.append(f"  numpy reference engine (engine='numpy'): {r.numpy_seconds * 1e3:.3f} ms, "
                 f"estimates within {math.degrees(r.engine_gap):.1e} deg of the compiled one's")
    speed = r.opencv_seconds / r.ransac_seconds
    lines.append(f"speed: cv2.findEssentialMat / two_point_ransac = {speed:.1f}x (target: 10x "
                 f"-> {'met' if speed >= 10.0 else 'NOT met'})")
    lines.append(f"minimal solver: median {r.solve_seconds * 1e6:.0f} us per two_point call "
                 f"({r.cases} calls)")
    return "\n".join(lines)


def run_accuracy(args: argparse.Namespace) -> str:
    """Run the Fig. 10 protocol (and draw it with --plot); return the table."""
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


def run_calibration(args: argparse.Namespace) -> str:
    """Fit the three models to a synthetic sweep; return the table."""
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
            f"{math.degrees(row.rms_angle):>10.3f} deg {k:>7} {deg(row.delta_max):>10}"
        )
    sweep, pcc = result.rows[0], result.row("PCC (best fit)")
    lines.append(f"PCC / APCC sweep tip error ratio: {pcc.rms_position / sweep.rms_position:.1f}x")
    return "\n".join(lines)


def run_tracking(args: argparse.Namespace) -> str:
    """Score KLT and ORB on known motion; return the table."""
    from apcc_graph.bench.tracking import format_tracking_benchmark, run_tracking_benchmark

    if not (args.noise >= 0.0 and math.isfinite(args.noise)):
        raise UserError(f"--noise {args.noise!r}: expected grey levels >= 0")
    rows = run_tracking_benchmark(frames=args.frames, seed=args.seed, noise=args.noise)
    return format_tracking_benchmark(rows, args.frames, args.noise)
