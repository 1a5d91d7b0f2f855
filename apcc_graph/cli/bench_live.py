"""``apcc-graph bench live``: the live loop on rendered videos beside the offline smoother
(:mod:`apcc_graph.bench.live`)."""

from __future__ import annotations

import argparse

from apcc_graph.cli.common import FORMATTER, at_least

EXAMPLES = {"live": "apcc-graph bench live --frames 1800"}
"""Example commands per benchmark of this module."""


def add_parsers(benches: argparse._SubParsersAction) -> None:
    """Add ``live`` to ``apcc-graph bench``."""
    live = benches.add_parser(
        "live", help="live tracking and smoothing of rendered videos vs the offline smoother",
        description="Render the three tip cameras of the planar robot moving through a "
        "textured room into one 640x480, 30 fps video each, then estimate them offline "
        "(track --video, estimate --method smoother), live at the videos' pace, and live on "
        "every frame from the true start, the start it searches (printed beside the true one) "
        "and the robot straight: frames per second, latency, frames dropped and RMS against "
        "the truth (targets: 30 per second, median latency at most one frame, the offline "
        "accuracy). Rendering takes about 0.15 s per image; --frames 150 runs in about two "
        "minutes on 2 cores.",
        epilog=f"example:\n  {EXAMPLES['live']}", formatter_class=FORMATTER)
    live.add_argument("--frames", type=at_least(60), default=600,
                      help="frames per video (default 600: 20 s; 1800 for a minute)")
    live.add_argument("--seed", type=int, default=1, help="simulation seed (default 1)")
    live.set_defaults(run=run)


def run(args: argparse.Namespace) -> str:
    """Run the benchmark and return its table."""
    from apcc_graph.bench.live import format_live, run_live_bench

    rows, rendered, truth0 = run_live_bench(int(args.frames), args.seed)
    return format_live(rows, int(args.frames), rendered, truth0)
