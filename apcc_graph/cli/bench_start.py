"""``apcc-graph bench start``: finding an unknown start, beside the vision-only bound."""

from __future__ import annotations

import argparse

from apcc_graph.cli.common import FORMATTER, UserError, add_dask_options, bench_robot_option

EXAMPLES = {
    "start": "apcc-graph bench start --runs 100\n  apcc-graph bench start --runs 10 --workers 1"
             "\n  apcc-graph bench start --spatial --runs 50",
}
"""Example commands per benchmark of this module."""


def add_parsers(benches: argparse._SubParsersAction) -> None:
    """Add this module's benchmarks to ``apcc-graph bench``."""
    stb = benches.add_parser(
        "start", epilog=f"example:\n  {EXAMPLES['start']}", formatter_class=FORMATTER,
        parents=[bench_robot_option()],
        help="start from an unknown shape: the first second's estimate beside its bound",
        description="Simulate --runs recordings of --seconds (3-segment robot, room scene, 1 "
        "px, 10%% outliers, a start anywhere within 80%% of theta_max), find each start "
        "without any prior on it, and compare with the Cramer-Rao bound of the same recording "
        "with vision alone. Counts the seeds within 2x of the bound, those that said they "
        "could not tell, and silent failures. With --spatial the robot bends in 3-D and the "
        "search finds its bending vectors.")
    stb.add_argument("--runs", type=int, default=100, help="recordings (default: %(default)s)")
    stb.add_argument("--seed", type=int, default=1, help="first seed (default: %(default)s)")
    stb.add_argument("--seconds", type=float, default=1.0,
                     help="length of each recording, seconds (default: %(default)s)")
    stb.add_argument("--spatial", action="store_true",
                     help="the robot bends in 3-D: find every segment's bending plane too")
    add_dask_options(stb)
    stb.set_defaults(run=run_start)


def run_start(args: argparse.Namespace) -> str:
    """Run the start benchmark; return its summary."""
    from apcc_graph.bench.unknown_start import format_start_benchmark, run_start_benchmark

    if args.runs < 1:
        raise UserError(f"--runs {args.runs}: expected at least 1")
    if not 0.1 <= args.seconds <= 60.0:
        raise UserError(f"--seconds {args.seconds!r}: expected 0.1 to 60 seconds")
    seeds = list(range(args.seed, args.seed + args.runs))
    runs = run_start_benchmark(args.robot, seeds, args.seconds, workers=args.workers,
                               progress=True, spatial=args.spatial)
    return format_start_benchmark(runs, args.seconds, args.spatial)
