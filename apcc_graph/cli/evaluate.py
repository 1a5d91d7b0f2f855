"""``apcc-graph evaluate``: an estimate against a sequence's ground truth: RMS and max angle error
per segment, overall and per window of frames (so drift shows), and where the sequence has measured
tips (a real-motion replay's ``truth_tips.csv``) the tip position and tangent errors beside the
floor."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from apcc_graph.cli.common import FORMATTER, UserError, at_least, estimate_option, truth_for

if TYPE_CHECKING:
    from apcc_graph.io.estimates import ThetaTable
    from apcc_graph.model.sequence import Sequence

EXAMPLE = "example:\n  apcc-graph evaluate /tmp/est --truth data/sequences/planar_three"


def add_parser(commands: argparse._SubParsersAction) -> None:
    """Add ``evaluate`` to the subcommands."""
    ev = commands.add_parser(
        "evaluate", help="compare an estimate with a sequence's ground truth",
        description="RMS and max error per segment, overall and per window of frames (so "
        "drift shows).",
        epilog=EXAMPLE, formatter_class=FORMATTER, parents=[estimate_option(truth_required=True)],
    )
    ev.add_argument("--window", type=at_least(1), default=100, help="frames per window")
    ev.set_defaults(run=run)


def run(args: argparse.Namespace) -> str:
    """Compare and return the table(s): angles where the truth has them, tips where it has
    measured tips (``truth_tips.csv``)."""
    from apcc_graph.io import load_sequence
    from apcc_graph.io.estimates import load_theta_table

    table = load_theta_table(Path(args.estimate) / "theta.csv")
    seq = load_sequence(args.truth)
    if seq.thetas is None and seq.truth_tips is None:
        raise UserError(f"{args.truth}: no ground truth (no theta columns in frames.csv, no "
                        "truth_tips.csv)")
    parts = []
    if seq.truth_tips is not None:
        if table.thetas.shape != (seq.n_frames, seq.n_segments):
            raise UserError(f"{args.estimate}: {table.thetas.shape[0]} frames x "
                            f"{table.thetas.shape[1]} segments, but {args.truth} has "
                            f"{seq.n_frames} x {seq.n_segments}")
        parts.append(tip_table(seq, table.thetas, table.psis))
    if seq.thetas is not None:
        parts.append(_angle_table(args, table))
    return "\n".join(parts)


def tip_table(seq: Sequence, thetas: np.ndarray, psis: np.ndarray | None) -> str:
    """Tip errors of estimated angles (the sequence's robot and base) against its measured
    tips, beside the floor: the model's tips at the bends that best fit the measured tips."""
    from apcc_graph.evaluation.tip_floor import tip_errors, tip_floor

    assert seq.truth_tips is not None
    est = tip_errors(seq.robot.forward(thetas, psis, seq.world_T_base), seq.truth_tips)
    floor = tip_floor(seq.robot, seq.truth_tips, seq.world_T_base).errors
    lines = ["tip errors against the measured segment ends, RMS over "
             f"{seq.n_frames} frames (floor: the model's best fit to the measured tips)",
             f"  {'segment end':<12}{'position (mm)':>15}{'floor (mm)':>12}{'ratio':>8}"
             f"{'tangent (deg)':>15}{'floor (deg)':>13}"]
    for i in range(seq.n_segments):
        p, fp = est.rms_position[i] * 1e3, floor.rms_position[i] * 1e3
        lines.append(f"  {i + 1:<12}{p:>15.2f}{fp:>12.2f}{p / max(fp, 1e-12):>8.2f}"
                     f"{np.degrees(est.rms_tangent[i]):>15.3f}"
                     f"{np.degrees(floor.rms_tangent[i]):>13.3f}")
    return "\n".join(lines)


def _angle_table(args: argparse.Namespace, table: ThetaTable) -> str:
    from apcc_graph.evaluation.accuracy import compare

    thetas = table.thetas
    truth, truth_psis = truth_for(args.estimate, thetas, args.truth, psis=True)
    report = compare(thetas, truth, window=args.window, psis=table.psis, truth_psis=truth_psis)
    n_seg = thetas.shape[1]
    lines = [f"{'':<16}" + "".join(f"{f'segment {i + 1}':>12}" for i in range(n_seg)),
             f"{'RMS (deg)':<16}" + "".join(f"{v:>12.4f}" for v in np.degrees(report.rms)),
             f"{'max |err| (deg)':<16}" + "".join(f"{v:>12.4f}"
                                                  for v in np.degrees(report.max_abs)),
             f"RMS per window of {report.window} frames (deg):"]
    if table.psis is not None:
        lines.insert(0, "errors of the bending vector theta (cos psi, sin psi)")
    for start, row in zip(report.window_starts, report.window_rms, strict=True):
        lines.append(f"  frames {start:>6}-{min(start + report.window, thetas.shape[0]) - 1:<6}"
                     + "".join(f"{v:>12.4f}" for v in np.degrees(row)))
    return "\n".join(lines)
