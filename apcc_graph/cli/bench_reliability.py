"""``apcc-graph bench`` for scale and reliability: many sequences on Dask against one process
(``many``), the smoother over a long stream (``soak``) and under faults (``reliability``)."""

from __future__ import annotations

import argparse

from apcc_graph.cli.common import FORMATTER, at_least, bench_robot_option, frames_option

EXAMPLES = {
    "many": "apcc-graph bench many --sequences 16 --frames 600 --workers 2",
    "soak": "apcc-graph bench soak --frames 100000",
    "reliability": "apcc-graph bench reliability",
}
"""Example commands per benchmark of this module."""


def add_parsers(benches: argparse._SubParsersAction) -> None:
    """Add this module's benchmarks to ``apcc-graph bench``."""
    _add_many(benches)
    soak = benches.add_parser(
        "soak", help="the smoother over a long stream generated on the fly: memory, speed",
        description="Stream simulated frames (generated one at a time, never stored) through "
        "the default smoother; resident memory, update time and RMS error per block, against "
        "the targets: memory at the end within 10%% of that after 10,000 frames, median update "
        "over the last 1,000 frames within 1.2x of frames 1,000-2,000.",
        epilog=f"example:\n  {EXAMPLES['soak']}", formatter_class=FORMATTER)
    soak.add_argument("--frames", type=at_least(2000), default=100_000,
                      help="frames to stream (default 100000; at least 2000)")
    soak.add_argument("--seed", type=int, default=1, help="stream seed (default 1)")
    soak.set_defaults(run=run_soak)
    rel = benches.add_parser(
        "reliability", help="the smoother under faults: blind cameras, a frozen robot, ...",
        description="Inject each fault (one or all cameras blind for 1 s, the last camera "
        "blind for 3 s, a camera that never sees, the robot frozen for 5 s, a 10 deg jump, "
        "swapped track ids, 50% outliers for 1 s, a start 5 deg off) into the same "
        "simulated recording and run the default smoother: what it did, RMS beside the "
        "Cramer-Rao bound of the faulted recording, recovery time in frames (target 30) and "
        "sigma honesty. Then the recording paused for 1.5 s (frames dropped while the robot "
        "moves on): the smoother and the batch over every frame after the pause (target: "
        "within 1.5x the batch).",
        epilog=f"example:\n  {EXAMPLES['reliability']}", formatter_class=FORMATTER)
    rel.add_argument("--frames", type=at_least(300), default=450,
                     help="frames per recording (default 450; the fault starts at a third)")
    rel.add_argument("--seed", type=int, default=1, help="simulation seed (default 1)")
    rel.set_defaults(run=run_reliability)


def _add_many(benches: argparse._SubParsersAction) -> None:
    many = benches.add_parser(
        "many", help="many sequences on a local Dask cluster vs one after the other",
        description="Simulate sequences of the three-segment robot and estimate them all in "
        "one process and on a local Dask cluster; wall times, their ratio and whether the "
        "results are identical.",
        epilog=f"example:\n  {EXAMPLES['many']}", formatter_class=FORMATTER,
        parents=[frames_option(600, minimum=10), bench_robot_option()])
    many.add_argument("--sequences", type=at_least(2), default=16, help="sequences (default 16)")
    many.add_argument("--workers", type=at_least(2), default=2, help="Dask workers (default 2)")
    many.add_argument("--method", choices=("chain", "batch", "smoother"), default="batch")
    many.add_argument("--seed", type=int, default=1, help="first simulation seed (default 1)")
    many.set_defaults(run=run_many)


def run_many(args: argparse.Namespace) -> str:
    """Run the many-sequences benchmark; return its table."""
    from apcc_graph.bench.many import format_many_benchmark, run_many_benchmark

    return format_many_benchmark(run_many_benchmark(
        args.sequences, args.frames, args.method, args.workers, args.seed, args.robot,
        progress=True))




def run_soak(args: argparse.Namespace) -> str:
    """Run the soak benchmark; return its table."""
    from apcc_graph.bench.soak import format_soak, run_soak

    return format_soak(run_soak(args.frames, args.seed, progress=True))


def run_reliability(args: argparse.Namespace) -> str:
    """Run the reliability benchmark; return its table."""
    from apcc_graph.bench.reliability import format_reliability, run_pause, run_reliability

    return format_reliability(run_reliability(args.frames, args.seed, progress=True),
                              args.frames, run_pause(args.frames, args.seed))
