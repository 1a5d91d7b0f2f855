"""``apcc-graph bench`` for scale and reliability: many sequences on Dask against one process
(``many``), the smoother over a long stream (``soak``) and under faults (``reliability``)."""

from __future__ import annotations

import argparse

from apcc_graph.cli.common import (
    FORMATTER,
    at_least,
    bench_robot_option,
    frames_option,
    int_list,
    model_sigma,
    seeds_option,
)
from apcc_graph.simulation.simulator import SCENES

EXAMPLES = {
    "many": "apcc-graph bench many --sequences 16 --frames 600 --workers 2",
    "soak": "apcc-graph bench soak --frames 100000",
    "reliability": "apcc-graph bench reliability",
}
"""Example commands per benchmark of this module."""
RELIABILITY_EXAMPLES = (
    EXAMPLES["reliability"],
    "apcc-graph bench reliability --seeds 11,12,13 --scene points --workers 2",
    "apcc-graph bench reliability --seeds 1 --frames 240 --model-sigma 1,0.5 --only 'camera 2'",
)
"""More examples of ``bench reliability``: seeds never tuned on, another scene, model noise."""
MIN_FRAMES = 240
"""The shortest recording of ``bench reliability``: the last camera's 3 s blackout ends at
frame 170 and is held to its target from frame 230."""
SEEDS = (1, 2, 3, 4, 5)
"""The default seeds of ``bench reliability`` (as :data:`apcc_graph.bench.reliability.SEEDS`;
not imported here, to keep the command line's start light)."""


def add_parsers(benches: argparse._SubParsersAction) -> None:
    """Add this module's benchmarks to ``apcc-graph bench``."""
    _add_many(benches)
    soak = benches.add_parser(
        "soak", help="the smoother over a long stream generated on the fly: memory, speed",
        description="Stream simulated frames (generated one at a time, never stored) through "
        "the default smoother; resident memory, update time and RMS error per block, against "
        "the targets: memory at the end within 10% of that after 10,000 frames, median update "
        "over the last 1,000 frames within 1.2x of frames 1,000-2,000.",
        epilog=f"example:\n  {EXAMPLES['soak']}", formatter_class=FORMATTER)
    soak.add_argument("--frames", type=at_least(2000), default=100_000,
                      help="frames to stream (default 100000; at least 2000)")
    soak.add_argument("--seed", type=int, default=1, help="stream seed (default 1)")
    soak.set_defaults(run=run_soak)
    rel = benches.add_parser(
        "reliability", help="the smoother under faults over several seeds: blind cameras, a "
        "pause, a frozen robot, ...",
        description="Inject each fault (one or all cameras blind for 1 s, the last camera "
        "blind for 3 s, the recording paused for 1.5 s while the robot moves on, each with the "
        "returning tracks under new ids and re-identified under their old ones; a camera that "
        "never sees, the robot frozen for 5 s, a 10 deg jump, swapped track ids, 50% outliers "
        "for 1 s, a "
        "start 5 deg off) into each seed's simulated recording and run the default smoother. "
        "Per seed the RMS error per segment; across seeds the median and the worst seed, and "
        "each row against its target on every seed: after a fault that hid the tracks, from "
        "2 s after they return within 2x the undisturbed error or at the bound of a 1 s lag, "
        "and never more than 5 deg off once they are back; a camera that never sees: segments "
        "2 and 3 within 2x the batch on the same recording; every other fault: back within 2x "
        "the undisturbed error in 30 frames. Then the first seed in full: what the estimator "
        "did, RMS beside the Cramer-Rao bound, recovery, sigma honesty, and the pause beside "
        "the batch.",
        epilog="examples:\n  " + "\n  ".join(RELIABILITY_EXAMPLES), formatter_class=FORMATTER,
        parents=[seeds_option(",".join(map(str, SEEDS)))])
    rel.add_argument("--frames", type=at_least(MIN_FRAMES), default=450,
                     help="frames per recording (default 450; the fault starts at a third; "
                     f"at least {MIN_FRAMES})")
    rel.add_argument("--scene", choices=SCENES, default="room",
                     help="the simulated scene the cameras see (default room)")
    rel.add_argument("--model-sigma", type=model_sigma, default=None, metavar="MM,DEG",
                     help="run the smoother with model error as noise of these standard "
                     "deviations (tip position mm, rotation deg; much slower); default the "
                     "exact model")
    rel.add_argument("--only", default=None, metavar="TEXT,...",
                     help="only the faults whose name contains one of these (case-insensitive, "
                     "comma-separated, e.g. 'blind,paused'); the undisturbed run always runs")
    rel.add_argument("--workers", type=at_least(1), default=1,
                     help="processes running the faults and seeds side by side (default 1)")
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
    """Run the reliability sweep; return its tables."""
    from apcc_graph.bench.reliability_sweep import format_sweep, run_sweep

    only = None if args.only is None else [w.strip() for w in args.only.split(",") if w.strip()]
    return format_sweep(run_sweep(args.frames, int_list(args.seeds, "--seeds"), args.scene,
                                  args.model_sigma, only, args.workers, progress=True))
