"""``apcc-graph calibrate``: k and delta_max of one segment from measured tip poses or from photos
of ArUco markers (docs/estimation.md, "Calibrating a segment"; formats in docs/formats.md)."""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable
from pathlib import Path

from apcc_graph.cli.common import (
    FORMATTER,
    UserError,
    check_output_file,
    deg,
    degree_list,
    force_option,
    non_negative,
    out_option,
    positive,
    seed_option,
)

EXAMPLE = (
    "examples:\n  apcc-graph calibrate data/calibration/paper_example.toml\n"
    "  apcc-graph calibrate data/calibration/images_sweep --output /tmp/robot.toml\n"
    "  apcc-graph calibrate data/real_tdcr/impulse_2/backbone_poses.csv --robot "
    "data/robots/real_tdcr.toml --output /tmp/robot_calibrated.toml\n"
    "  apcc-graph calibrate /tmp/sweep --render --length 0.4 --k 0.21 --delta-max-deg 7 "
    "--theta-max-deg 80 --bends-deg=-80,-40,0,40,80 --seed 0")


def add_parser(commands: argparse._SubParsersAction) -> None:
    """Add ``calibrate`` to the subcommands."""
    cal = commands.add_parser(
        "calibrate",
        help="calibrate k and delta_max of a segment from measured tip poses or marker images",
        description="Calibrate every segment of a robot from motion-capture backbone poses "
        "(backbone_poses.csv with --robot: k, delta_max and the marker offsets, with the APCC "
        "and PCC residuals and held-out markers), or one segment from a TOML file of measured "
        "tip poses "
        "(format apcc-graph/calibration@1) or from a folder of side-camera images with ArUco "
        "markers on the base and the tip (calibration.toml, format "
        "apcc-graph/calibration-images@1, and *.png): one pose by the paper's closed form, "
        "several by least squares. Prints the tip measured in each image, the model and the "
        "APCC-vs-PCC residuals.",
        epilog=EXAMPLE, formatter_class=FORMATTER,
        parents=[out_option("also write a one-segment robot.toml with the calibrated segment",
                            required=False, metavar="ROBOT.toml"),
                 seed_option(None, "random seed of --render (default 0)"),
                 force_option("--render into a non-empty PATH (replaced whole once the new "
                              "images are written), or replace an existing --output")],
    )
    cal.add_argument("file", metavar="PATH",
                     help="calibration TOML file, folder of calibration images, or "
                     "backbone_poses.csv (motion capture; then --robot)")
    cal.add_argument("--robot", help="with a backbone_poses.csv: the robot.toml whose segments "
                     "are calibrated (its lengths say which markers are segment ends); --output "
                     "then writes it calibrated, with the marker offsets")
    syn = cal.add_argument_group(
        "synthetic images", "--render first writes a seeded synthetic image folder to PATH (the\n"
        "segment below bent to each of --bends-deg, seen by a 640x480 side camera), then\n"
        "calibrates it")
    syn.add_argument("--render", action="store_true", help="render synthetic images into PATH")
    syn.add_argument("--length", type=positive, help="segment length, metres")
    syn.add_argument("--k", type=float, help="true k, 0 < k < 0.5")
    syn.add_argument("--delta-max-deg", type=float, help="true delta_max, degrees (default 0)")
    syn.add_argument("--theta-max-deg", type=float,
                     help="true theta_max, degrees (default: the largest |bend|)")
    syn.add_argument("--bends-deg", help="comma-separated bends, degrees, one image each "
                     "(e.g. --bends-deg -80,-40,0)")
    syn.add_argument("--noise", type=non_negative,
                     help="sensor noise, grey levels (default 1)")
    syn.add_argument("--tilt-deg", type=float,
                     help="camera tilt away from parallel, degrees, about the image diagonal "
                     "(default 0)")
    cal.set_defaults(run=run)


_RENDER_OPTIONS = ("length", "k", "delta_max_deg", "theta_max_deg", "bends_deg", "seed", "noise",
                   "tilt_deg", "force")


def run(args: argparse.Namespace) -> str:
    """Calibrate (after rendering, with --render) and return the report."""
    from apcc_graph.calibration.files import calibrate_measurements, load_tip_measurements

    path = Path(args.file)
    if args.out is not None:
        check_output_file(args.out, args.force)
    lines = []
    if args.render:
        lines.append(_render_calibration_images(args, path))
    elif given := [name for name in _RENDER_OPTIONS
                   if getattr(args, name) is not None and getattr(args, name) is not False
                   and not (name == "force" and args.out is not None)]:
        option = "--" + given[0].replace("_", "-")
        raise UserError(f"{option} applies to --render only")
    if path.suffix.lower() == ".csv":
        from apcc_graph.cli.calibrate_backbone import calibrate_backbone_file

        if args.robot is None:
            raise UserError(f"{path}: calibrating from backbone poses needs --robot robot.toml "
                            "(its segment lengths say which markers are segment ends)")
        lines.append(calibrate_backbone_file(path, args.robot, args.out))
        return "\n".join(lines)
    if args.robot is not None:
        raise UserError("--robot applies to a backbone_poses.csv file only")
    if path.is_dir():
        from apcc_graph.calibration.photos import calibrate_images

        result = calibrate_images(path)
        report = result.report
        lines.append(_format_image_measurements(result))
    else:
        report = calibrate_measurements(load_tip_measurements(path))
    if args.out is not None:
        from apcc_graph.io.robot_file import save_robot
        from apcc_graph.model.robot import Robot

        save_robot(Robot([report.segment]), args.out)
    lines.append(_format_calibration(report, args.file, args.out))
    return "\n".join(lines)


def _render_calibration_images(args: argparse.Namespace, path: Path) -> str:
    """``calibrate --render``: write a seeded synthetic image folder to ``path``."""
    from apcc_graph.io.output_folder import check_writable, replace_refusal, staged_folder
    from apcc_graph.model.segment import Segment
    from apcc_graph.simulation.calibration_photos import write_calibration_images

    missing = [f"--{name.replace('_', '-')}" for name in ("length", "k", "bends_deg")
               if getattr(args, name) is None]
    if missing:
        raise UserError(f"--render needs {', '.join(missing)}")
    if path.exists() and (not path.is_dir() or any(path.iterdir())) and not args.force:
        raise UserError(f"{path}: exists and is not empty; choose another PATH or add --force "
                        "(replaces it whole)")
    refusal = replace_refusal(path) if path.is_dir() and args.force else None
    if refusal is not None:
        raise UserError(f"{path}: {refusal}: choose another PATH")
    check_writable(path)  # before rendering
    bends = [math.radians(v) for v in degree_list(
        args.bends_deg, "--bends-deg", ", e.g. -80,-40,0")]
    theta_max = max(abs(b) for b in bends) if args.theta_max_deg is None else math.radians(
        args.theta_max_deg)
    segment = Segment(args.length, k=args.k, delta_max=math.radians(args.delta_max_deg or 0.0),
                      theta_max=theta_max)
    tilt = math.radians(args.tilt_deg or 0.0) / math.sqrt(2.0)
    seed = 0 if args.seed is None else args.seed
    noise = 1.0 if args.noise is None else args.noise
    with staged_folder(path, replace=args.force) as staging:  # whole, or not at all
        written = write_calibration_images(staging, segment, bends, seed=seed, noise=noise,
                                           tilt=(tilt, tilt), force=True)
    return (f"wrote {path}: {len(written) - 1} synthetic image(s) and {written[-1].name} "
            f"(seed {seed}, noise {noise:g} grey levels)")


def _format_image_measurements(result: object) -> str:
    """One line per image: chord angle, tip angle, |OP|, fitted theta and corner RMS."""
    from apcc_graph.calibration.closed_form import MIN_BEND
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
            f"  {Path(measured.name).name:<20} {deg(tip.chord_angle):>12} {deg(tip.angle):>12} "
            f"{op_text:>10} {deg(float(theta)):>13} {measured.rms_px:>8.3f} px"
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
        f"  delta_max  = {pm(deg(seg.delta_max), report.delta_max_std, deg)}",
        f"  theta_max  = {deg(seg.theta_max)}",
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
