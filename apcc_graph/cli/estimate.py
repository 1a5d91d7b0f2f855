"""``apcc-graph estimate``: every frame's segment angles of a sequence folder, written as
``theta.csv`` and one TUM trajectory per segment tip (docs/formats.md, "Estimates")."""

from __future__ import annotations

import argparse
import math
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from apcc_graph.cli.common import (
    FORMATTER,
    UserError,
    add_dask_options,
    add_model_options,
    check_output_folder,
    chosen_model_sigma,
    degree_list,
    force_option,
    out_option,
)
from apcc_graph.model.robot import Robot

if TYPE_CHECKING:
    from apcc_graph.estimation.result import Estimate
    from apcc_graph.estimation.smoother_options import SmootherOptions

EXAMPLE = ("example:\n  apcc-graph estimate data/sequences/planar_three --method batch "
           "--out /tmp/est --theta0-deg 20.5,-15.2,21.3")


CALIBRATE_CHOICES = ("all", "models", "mounts")
"""What ``--calibrate`` estimates: everything, the segment models, or the camera mounts."""


def _add_smoother_arguments(est: argparse.ArgumentParser) -> None:
    """The smoother's own options."""
    est.add_argument("--lag", type=float, default=DEFAULT_LAG,
                     help="smoother window in seconds (default: %(default)s)")
    est.add_argument("--rotation-gate", type=float, default=None, metavar="RAD",
                     help="smoother only: also reject an observation that disagrees by more "
                     "than RAD radians with its camera's rotation to both neighbouring frames "
                     "(0.02 suits 1 px; off by default; docs/estimation.md, the fixed-lag "
                     "smoother)")
    est.add_argument("--factorization", choices=("CHOLESKY", "QR"), default=None,
                     help="smoother only: how iSAM2 factors the window (default CHOLESKY; QR "
                     "is slower but does not square the window's condition number, and gtsam "
                     "then never failed on the real robot's motion; docs/estimation.md, the "
                     "fixed-lag smoother)")
    est.add_argument("--keyframes", action="store_true",
                     help="smoother only: run iSAM2 at keyframes only (a frame that turns, "
                     "shows parallax or comes 0.1 s after the last keyframe); every frame still "
                     "enters the window with all its observations, the others wait for the "
                     "next keyframe (docs/estimation.md, keyframes)")


def add_parser(commands: argparse._SubParsersAction) -> None:
    """Add ``estimate`` to the subcommands."""
    est = commands.add_parser(
        "estimate", help="estimate every frame's segment angles of a sequence folder",
        description="Estimate the bending angles of a sequence and write theta.csv and one "
        "TUM trajectory per segment tip (tips_seg_<i>.tum) into --out.",
        epilog=EXAMPLE, formatter_class=FORMATTER,
        parents=[out_option("output folder"),
                 force_option("replace a non-empty --out (whole, once the new estimate is "
                              "written)")],
    )
    est.add_argument("sequence", nargs="+",
                     help="sequence folder; several, or a folder of sequence folders, are "
                     "estimated each into --out/<name>/ with a summary.csv")
    est.add_argument("--method", choices=("chain", "batch", "smoother"), default="batch",
                     help="chain: the paper's frame-by-frame method; batch: the whole sequence "
                     "in one factor graph; smoother: fixed-lag smoother, frame by frame "
                     "(default: %(default)s)")
    _add_smoother_arguments(est)
    est.add_argument("--theta0-deg", default=None,
                     help="starting configuration, degrees, one per segment (e.g. "
                     "--theta0-deg -10,5,3). Without it the "
                     "start is unknown: found from the first second of images (longer if the "
                     "robot barely moved), or refused if the recording never tells it")
    est.add_argument("--theta0-sigma-deg", type=float, default=None,
                     help="how well --theta0-deg is known: standard deviation of its prior, "
                     "degrees (default: 0.1)")
    est.add_argument("--spatial", action="store_true",
                     help="the robot bends in 3-D: estimate each segment's bending plane psi "
                     "too (theta.csv gains psi_<i> and psi_sigma_<i>); any --method, "
                     "with --theta0-deg (and --psi0-deg)")
    est.add_argument("--psi0-deg", default=None,
                     help="with --spatial: the bending planes at the start, degrees, one per "
                     "segment (default: 0; e.g. --psi0-deg -90,0,45)")
    est.add_argument("--noise-px", type=float, default=1.0,
                     help="pixel noise of the tracks, standard deviation per coordinate "
                     "(default: %(default)s); sets the outlier threshold and the sigmas")
    add_model_options(est)
    est.add_argument("--calibrate", nargs="?", const="all", default=None,
                     choices=CALIBRATE_CHOICES,
                     help="self-calibration (--method batch): estimate with the angles each "
                     "segment's k and delta_max (models), each camera's mounting tip_T_cam "
                     "(mounts), or both (all, the default), with their sigmas; it writes "
                     "robot_calibrated.toml. Both at once can cost the angles far more "
                     "than either alone where the motion does not tell a mount from the "
                     "model (docs/estimation.md, 'Self-calibration')")
    many = est.add_argument_group(
        "many sequences", "with several sequences, each goes to --out/<name>/ and --out gets\n"
        "summary.csv; a re-run skips sequences whose outputs are complete (--force redoes\n"
        "them); an --out/<name>/ that holds anything else is that sequence's failure\n"
        "(--force replaces it whole); a sequence that fails is reported and does not stop\n"
        "the others")
    add_dask_options(many)
    est.set_defaults(run=run)


def _theta0_list(text: str) -> np.ndarray:
    """``--theta0-deg`` as radians, unchecked against a robot (each sequence's estimate checks
    it against its own)."""
    return np.radians(degree_list(text, "--theta0-deg"))


def _theta0(text: str | None, robot: Robot) -> np.ndarray | None:
    """``--theta0-deg``: one angle per segment within its theta_max, radians; ``None`` when
    not given."""
    n_segments = robot.n_segments
    if text is None:
        return None
    values = degree_list(text, "--theta0-deg")
    if len(values) != n_segments or not all(math.isfinite(v) for v in values):
        raise UserError(f"--theta0-deg {text!r}: expected {n_segments} finite angles in degrees "
                        "(one per segment)")
    for i, (value, seg) in enumerate(zip(values, robot.segments, strict=True)):
        if abs(math.radians(value)) > seg.theta_max:
            raise UserError(f"--theta0-deg {text!r}: {value:g} deg is beyond segment {i + 1}'s "
                            f"theta_max of {math.degrees(seg.theta_max):g} deg")
    return np.radians(values)


DEFAULT_LAG = 1.0


def _psi0(text: str | None, n_segments: int | None) -> np.ndarray | None:
    """``--psi0-deg`` in radians: finite angles, one per segment when ``n_segments`` is
    known; ``None`` when not given."""
    if text is None:
        return None
    values = degree_list(text, "--psi0-deg")
    if not all(math.isfinite(v) for v in values) or (n_segments is not None
                                                     and len(values) != n_segments):
        count = "one per segment" if n_segments is None else f"{n_segments}, one per segment"
        raise UserError(f"--psi0-deg {text!r}: expected finite angles in degrees ({count})")
    return np.radians(values)


def _spatial_options(args: argparse.Namespace) -> dict:
    """``--spatial`` and ``--psi0-deg``, checked against the other options."""
    if args.psi0_deg is not None and not args.spatial:
        raise UserError("--psi0-deg applies to --spatial only")
    if not args.spatial:
        return {}
    if args.psi0_deg is not None and args.theta0_deg is None:
        raise UserError("--psi0-deg applies to a given start (--theta0-deg); without either, "
                        "the search finds the bending planes at the start too")
    return {"spatial": True}


def _smoother_settings(args: argparse.Namespace) -> SmootherOptions | None:
    """The smoother's settings from the command line, checked (``None`` for another method,
    which must not have been given any)."""
    from apcc_graph.estimation.keyframes import KeyframeRule
    from apcc_graph.estimation.smoother_options import (
        FaultOptions,
        SmootherOptions,
        WindowOptions,
    )

    if args.method == "smoother":
        if not (args.lag > 0.0 and math.isfinite(args.lag)):
            raise UserError(f"--lag {args.lag!r}: expected a positive number of seconds")
        gate = args.rotation_gate
        if gate is not None and not (gate > 0.0 and math.isfinite(gate)):
            raise UserError(f"--rotation-gate {gate!r}: expected a positive angle in radians")
        return SmootherOptions(
            window=WindowOptions(lag=args.lag, factorization=args.factorization or "CHOLESKY"),
            faults=FaultOptions(rotation_gate=gate),
            keyframes=KeyframeRule() if args.keyframes else None)
    if args.lag is not None and args.lag != DEFAULT_LAG:
        raise UserError("--lag applies to --method smoother only")
    if args.rotation_gate is not None:
        raise UserError("--rotation-gate applies to --method smoother only")
    if args.factorization is not None:
        raise UserError("--factorization applies to --method smoother only")
    if args.keyframes:
        raise UserError("--keyframes applies to --method smoother only")
    return None


def _options(args: argparse.Namespace) -> dict:
    """The estimator's keyword arguments from the command line, checked."""
    from apcc_graph.estimation.options import BatchOptions, GraphOptions

    options: dict = {"progress": True, **_spatial_options(args)}
    settings = _smoother_settings(args)
    if settings is not None:
        options["settings"] = settings
    if args.theta0_sigma_deg is not None and args.theta0_deg is None:
        raise UserError("--theta0-sigma-deg applies to a given start (--theta0-deg); without "
                        "one the start is found from the images, with its own sigma")
    if args.method != "chain" and args.theta0_deg is not None:
        sigma = 0.1 if args.theta0_sigma_deg is None else args.theta0_sigma_deg
        if not (math.isfinite(sigma) and sigma > 0.0):
            raise UserError(f"--theta0-sigma-deg {sigma!r}: expected a positive number "
                            "of degrees")
        options["theta0_sigma"] = math.radians(sigma)
    if not (math.isfinite(args.noise_px) and args.noise_px > 0.0):
        raise UserError(f"--noise-px {args.noise_px!r}: expected a positive number of pixels")
    options["noise_px"] = args.noise_px
    if args.model_sigma is not None and args.method == "chain":
        raise UserError("--model-sigma applies to --method batch or smoother (the chain "
                        "has no model noise)")
    if args.method != "chain":
        options["graph"] = GraphOptions(model_sigma=chosen_model_sigma(args))
    if args.calibrate:
        if args.method != "batch":
            raise UserError("--calibrate: self-calibration runs in --method batch")
        settings = BatchOptions(calibrate=True)
        if args.calibrate == "mounts":
            settings = replace(settings, calibration_sigmas=None)
        elif args.calibrate == "models":
            settings = replace(settings, mount_sigmas=None)
        options["settings"] = settings
    return options


def run(args: argparse.Namespace) -> str:
    """Estimate one sequence or many; return the summary."""
    single = len(args.sequence) == 1 and (Path(args.sequence[0]) / "frames.csv").is_file()
    if not single:
        return _run_many(args)
    if args.workers is not None or args.scheduler is not None:
        raise UserError("--workers and --scheduler apply to several sequences only")
    return _run_one(args, args.sequence[0])


def _run_many(args: argparse.Namespace) -> str:
    """Several sequences: each into --out/<name>/, then summary.csv."""
    from apcc_graph.estimation.many import estimate_many, format_runs, sequence_folders

    if args.calibrate:
        raise UserError("--calibrate applies to one sequence at a time")
    folders = sequence_folders(args.sequence)
    options = {**_options(args), "progress": False}
    _check_many_out(args.out, folders, args.force)
    if args.theta0_deg is not None:
        options["theta0"] = _theta0_list(args.theta0_deg)
    if args.psi0_deg is not None:
        options["psi0"] = _psi0(args.psi0_deg, None)
    runs = estimate_many(folders, args.out, args.method, options, workers=args.workers,
                         scheduler=args.scheduler, redo=args.force, progress=True)
    return format_runs(runs, args.out)


def _check_many_out(out: str, folders: list[Path], force: bool) -> None:
    """``--out`` of several sequences: writable, and no sequence's output folder (replaced
    whole when it is estimated again) is or holds an input sequence, nor, with ``--force``,
    the current folder or the home folder."""
    from apcc_graph.estimation.many import output_folder
    from apcc_graph.io.output_folder import check_writable, replace_refusal

    check_writable(out)
    for folder in folders:
        target = output_folder(out, folder).resolve()
        refusal = replace_refusal(target, folders) if force and target.exists() else None
        if refusal is not None:
            raise UserError(f"{target}: {refusal}: choose another --out")
        for given in folders:
            if target == given.resolve() or target in given.resolve().parents:
                raise UserError(f"{out}: the estimate of {folder} would go to {target}, "
                                f"which holds the input {given}; choose another --out")


def calibration_lines(given: Robot, result: Estimate,
                      mount_prior: tuple[float, float] | None = None) -> list[str]:
    """What self-calibration found: each segment's k and delta_max, and each calibrated
    camera's mount as a change from ``given``'s (rotations about the camera's axes in degrees,
    translations along them in mm), each with its standard deviation; the mount components
    whose sigma is within 10% of ``mount_prior``'s (default the library's) are named as not
    told by the images."""
    from apcc_graph.estimation.model_calibration import MOUNT_SIGMAS, mount_change

    prior = np.repeat(MOUNT_SIGMAS if mount_prior is None else mount_prior, 3)
    names = ("rotation x", "rotation y", "rotation z", "translation x", "translation y",
             "translation z")

    lines = []
    if result.calibration_sigmas is not None:
        for i, (seg, sig) in enumerate(zip(result.robot.segments, result.calibration_sigmas,
                                           strict=True)):
            lines.append(f"segment {i + 1}: k = {seg.k:.4f} +/- {sig[0]:.4f}, delta_max = "
                         f"{math.degrees(seg.delta_max):.3f} +/- {math.degrees(sig[1]):.3f} deg")
    for i, sig in enumerate([] if result.mount_sigmas is None else result.mount_sigmas):
        before, after = given.cameras[i], result.robot.cameras[i]
        if before is None or after is None or np.isnan(sig).all():
            continue
        xi = mount_change(after.tip_T_cam, before.tip_T_cam)
        rot = ", ".join(f"{math.degrees(v):+.3f} +/- {math.degrees(s):.3f}"
                        for v, s in zip(xi[:3], sig[:3], strict=True))
        pos = ", ".join(f"{v * 1e3:+.2f} +/- {s * 1e3:.2f}"
                        for v, s in zip(xi[3:], sig[3:], strict=True))
        lines.append(f"camera on segment {i + 1}: mount moved from the robot file's by "
                     f"rotations about x, y, z {rot} deg; translations {pos} mm")
        blind = [name for name, s, p in zip(names, sig, prior, strict=True) if s > 0.9 * p]
        if blind:
            lines.append(f"  the images do not tell its {', '.join(blind)} (sigma near the "
                         "prior's): the robot file's value stays")
    return lines


def model_line(model_sigma: object, robot: Robot, calibrating: bool) -> str:
    """Which measurement model ran, and where its noise came from."""
    from apcc_graph.estimation.model_noise import ROBOT, describe, segment_sigmas

    if calibrating and model_sigma == ROBOT:
        return "the exact model (self-calibration fits the model itself)"
    text = describe(segment_sigmas(model_sigma, robot))  # type: ignore[arg-type]
    if model_sigma is None:
        return text + " (--exact-model)"
    if model_sigma != ROBOT:
        return text + " (--model-sigma)"
    if text.startswith("model"):
        return text + " per segment, the robot file's model_error"
    return text + " (the robot file gives no model error)"


def _run_one(args: argparse.Namespace, folder: str) -> str:
    """One sequence: estimate, write the estimate (and the calibrated robot), summarise."""
    from apcc_graph.estimation.methods import estimate
    from apcc_graph.io import load_sequence
    from apcc_graph.io.estimates import save_estimate
    from apcc_graph.io.output_folder import staged_folder

    sequence = load_sequence(folder)
    theta0 = _theta0(args.theta0_deg, sequence.robot)
    options = _options(args)
    if args.psi0_deg is not None:
        options["psi0"] = _psi0(args.psi0_deg, sequence.robot.n_segments)
    # after the inputs (their errors come first), before any computing
    check_output_folder(args.out, args.force, inputs=[folder])
    try:
        result = estimate(sequence, method=args.method, theta0=theta0, **options)
    except ValueError as error:
        raise UserError(str(error)) from None
    with staged_folder(args.out, replace=args.force) as staging:  # whole, or not at all
        written = save_estimate(result, staging)
        if args.calibrate and args.method == "batch":
            from apcc_graph.io.robot_file import save_robot

            save_robot(result.robot, staging / "robot_calibrated.toml")
            written = [*written, staging / "robot_calibrated.toml"]
    lines = [f"{args.method}: {result.n_frames} frames, {sequence.n_segments} segments -> "
             f"{args.out} ({', '.join(p.name for p in written)})"]
    if args.method != "chain":
        lines.append("measurement model: " + model_line(options["graph"].model_sigma,
                                                         sequence.robot, bool(args.calibrate)))
    if result.start is not None:
        found = result.start
        lines.append(f"start found from the first {found.seconds:.2f} s ({found.n_frames} "
                     "frames): " + ", ".join(
                         f"{math.degrees(t):.2f} +/- {math.degrees(s):.2f}"
                         for t, s in zip(found.theta0, found.sigma0, strict=True)) + " deg")
        if found.psi0 is not None:
            lines.append("  in the bending planes " + ", ".join(
                f"{math.degrees(p):.1f}" for p in found.psi0) + " deg (sigmas: along each "
                "bending vector's worst-determined direction)")
    if args.calibrate:
        lines += calibration_lines(sequence.robot, result)
        sigma = np.degrees(np.sqrt(np.nanmean(result.bend_sigmas() ** 2, axis=0)))
        lines.append("RMS angle sigma with the calibration: " + ", ".join(
            f"segment {i + 1} {v:.3f} deg" for i, v in enumerate(sigma)) + " (models and "
            "mounts at once can cost the angles far more than either alone: compare "
            "--calibrate models and --calibrate mounts)")
    if result.model_fit is not None:
        lines.append("residual test (does the model explain the images?):")
        lines += ["  " + line for line in result.model_fit.summary().splitlines()]
    if sequence.thetas is not None:  # evaluation only: the estimator never read these
        rms = np.degrees(result.rms(sequence.thetas, sequence.psis))
        what = " (bending vector)" if result.spatial else ""
        lines.append(f"RMS error{what} vs the sequence's ground truth: "
                     + ", ".join(f"segment {i + 1} {v:.3f} deg" for i, v in enumerate(rms)))
    return "\n".join(lines)
