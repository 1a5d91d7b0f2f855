"""``apcc-graph evaluate``: an estimate against a sequence's ground truth, RMS and max error per
segment, overall and per window of frames (so drift shows)."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from apcc_graph.cli.common import FORMATTER, at_least, estimate_option, truth_for

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
    """Compare and return the table."""
    from apcc_graph.evaluation.accuracy import compare
    from apcc_graph.io.estimates import load_theta_table

    table = load_theta_table(Path(args.estimate) / "theta.csv")
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
