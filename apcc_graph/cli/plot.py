"""``apcc-graph plot``: an estimate's angles against time, with a band of marginal sigmas, the
ground truth and the errors (the paper's Fig. 11)."""

from __future__ import annotations

import argparse
from pathlib import Path

from apcc_graph.cli.common import (
    FORMATTER,
    UserError,
    check_output_file,
    estimate_option,
    force_option,
    out_option,
    positive,
)

EXAMPLE = ("example:\n  apcc-graph plot /tmp/est --truth data/sequences/planar_three "
           "--output /tmp/angles.png")


def add_parser(commands: argparse._SubParsersAction) -> None:
    """Add ``plot`` to the subcommands."""
    plt = commands.add_parser(
        "plot", help="plot an estimate's angles against time (and the truth, with errors)",
        description="Draw every segment's estimated angle over time with a band of --sigmas "
        "marginal standard deviations, the ground truth and the error when --truth is given "
        "(the paper's Fig. 11).",
        epilog=EXAMPLE, formatter_class=FORMATTER,
        parents=[out_option("figure file (png, pdf, svg, ...)", metavar="FIG.png"),
                 force_option("replace an existing figure file"),
                 estimate_option(truth_required=False)],
    )
    plt.add_argument("--sigmas", type=positive, default=2.0,
                     help="half-width of the uncertainty band in sigmas (default 2)")
    plt.set_defaults(run=run)


def run(args: argparse.Namespace) -> str:
    """Draw the figure and return where it was written."""
    from apcc_graph.cli.evaluate import matched_truth
    from apcc_graph.io.estimates import load_theta_table
    from apcc_graph.plots import angles_figure, check_figure_path, save_figure

    check_figure_path(args.out)
    check_output_file(args.out, args.force)
    table = load_theta_table(Path(args.estimate) / "theta.csv")
    truth = None
    if args.truth is not None:
        seq, match = matched_truth(args.estimate, table, args.truth)
        if seq.thetas is None:
            raise UserError(f"{args.truth}: frames.csv has no ground-truth theta columns")
        truth = seq.thetas[match.frames]
    fig = angles_figure(table.timestamps, table.thetas, table.sigmas, truth,
                        n_sigma=args.sigmas, label=Path(args.estimate).name or "estimate")
    return f"wrote {save_figure(fig, args.out)}"
