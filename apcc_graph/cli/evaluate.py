"""``apcc-graph evaluate``: an estimate against a sequence's ground truth: RMS and max angle error
per segment, overall and per window of frames (so drift shows), and where the sequence has measured
tips (a real-motion replay's ``truth_tips.csv``) the tip position and tangent errors beside the
floor."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from apcc_graph.cli.common import FORMATTER, UserError, at_least, estimate_option

if TYPE_CHECKING:
    from apcc_graph.evaluation.frame_match import FrameMatch
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
    measured tips (``truth_tips.csv``); rows matched to the truth's frames by frame number and
    timestamp (:mod:`~apcc_graph.evaluation.frame_match`)."""
    from apcc_graph.io.estimates import load_theta_table

    table = load_theta_table(Path(args.estimate) / "theta.csv")
    seq, match = matched_truth(args.estimate, table, args.truth)
    if seq.thetas is None and seq.truth_tips is None:
        raise UserError(f"{args.truth}: no ground truth (no theta columns in frames.csv, no "
                        "truth_tips.csv)")
    parts = [] if match.complete else [match.coverage()]
    if seq.truth_tips is not None:
        parts.append(tip_table(seq, table.thetas, table.psis, match.frames))
    if seq.thetas is not None:
        parts.append(_angle_table(args, table, seq, match.frames))
    return "\n".join(parts)


def matched_truth(estimate: str, table: ThetaTable, truth: str
                  ) -> tuple[Sequence, FrameMatch]:
    """The truth sequence and the truth frame of each of the estimate's rows.

    Raises:
        UserError: the segments differ, or a row's frame or time is not the truth's (named).
    """
    from apcc_graph.evaluation.frame_match import match_frames
    from apcc_graph.io import load_sequence

    seq = load_sequence(truth)
    if table.thetas.shape[1] != seq.n_segments:
        raise UserError(f"{estimate}: {table.thetas.shape[1]} segments, but {truth} has "
                        f"{seq.n_segments}")
    try:
        match = match_frames(table.frame_numbers(), table.timestamps, seq.timestamps,
                             str(Path(estimate) / "theta.csv"), str(Path(truth) / "frames.csv"))
    except ValueError as exc:
        raise UserError(str(exc)) from None
    return seq, match


def tip_table(seq: Sequence, thetas: np.ndarray, psis: np.ndarray | None,
              frames: np.ndarray | None = None) -> str:
    """Tip errors of estimated angles (the sequence's robot and base) against its measured
    tips, beside the floor: the model's tips at the bends that best fit the measured tips;
    ``frames``: the truth frame of each row of ``thetas`` (default all, in order)."""
    from apcc_graph.evaluation.tip_floor import tip_errors, tip_floor

    assert seq.truth_tips is not None
    rows = np.arange(seq.n_frames) if frames is None else np.asarray(frames)
    base = None if seq.world_T_base is None else seq.world_T_base[rows]
    measured = seq.truth_tips[rows]
    est = tip_errors(seq.robot.forward(thetas, psis, base), measured)
    floor = tip_floor(seq.robot, measured, base).errors
    lines = ["tip errors against the measured segment ends, RMS over "
             f"{len(rows)} frames (floor: the model's best fit to the measured tips)",
             f"  {'segment end':<12}{'position (mm)':>15}{'floor (mm)':>12}{'ratio':>8}"
             f"{'tangent (deg)':>15}{'floor (deg)':>13}"]
    for i in range(seq.n_segments):
        p, fp = est.rms_position[i] * 1e3, floor.rms_position[i] * 1e3
        lines.append(f"  {i + 1:<12}{p:>15.2f}{fp:>12.2f}{p / max(fp, 1e-12):>8.2f}"
                     f"{np.degrees(est.rms_tangent[i]):>15.3f}"
                     f"{np.degrees(floor.rms_tangent[i]):>13.3f}")
    return "\n".join(lines)


def _angle_table(args: argparse.Namespace, table: ThetaTable, seq: Sequence,
                 frames: np.ndarray) -> str:
    from apcc_graph.evaluation.accuracy import compare

    assert seq.thetas is not None
    thetas = table.thetas
    truth = seq.thetas[frames]
    truth_psis = None if seq.psis is None else seq.psis[frames]
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
        last = frames[min(start + report.window, thetas.shape[0]) - 1]
        lines.append(f"  frames {frames[start]:>6}-{last:<6}"
                     + "".join(f"{v:>12.4f}" for v in np.degrees(row)))
    return "\n".join(lines)
