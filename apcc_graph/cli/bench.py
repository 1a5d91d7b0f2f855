"""``apcc-graph bench``: benchmarks against named peers measured in the same run (figures, never
tests). The benchmarks themselves are in :mod:`~apcc_graph.cli.bench_front_end`,
:mod:`~apcc_graph.cli.bench_back_end`, :mod:`~apcc_graph.cli.bench_reliability` and
:mod:`~apcc_graph.cli.bench_start`, :mod:`~apcc_graph.cli.bench_real` and
:mod:`~apcc_graph.cli.bench_live`; their work
in :mod:`apcc_graph.bench`."""

from __future__ import annotations

import argparse

from apcc_graph.cli import (
    bench_back_end,
    bench_front_end,
    bench_live,
    bench_real,
    bench_reliability,
    bench_start,
)
from apcc_graph.cli.common import FORMATTER


def add_parser(commands: argparse._SubParsersAction) -> None:
    """Add ``bench`` and its benchmarks to the subcommands."""
    examples = [*bench_front_end.EXAMPLES.values(), *bench_back_end.EXAMPLES.values(),
                *bench_reliability.EXAMPLES.values(), *bench_start.EXAMPLES.values(),
                *bench_real.EXAMPLES.values(), *bench_live.EXAMPLES.values()]
    bench = commands.add_parser(
        "bench", help="benchmarks against named peers (figures, not tests)",
        description="Speed and accuracy figures of apcc_graph and of named peers measured in "
        "the same run. Each benchmark has its own --help.",
        epilog="examples:\n" + "\n".join(f"  {line.strip()}" for text in examples
                                         for line in text.splitlines()),
        formatter_class=FORMATTER)
    benches = bench.add_subparsers(dest="bench", metavar="BENCHMARK", required=True)
    bench_front_end.add_parsers(benches)
    bench_back_end.add_parsers(benches)
    bench_reliability.add_parsers(benches)
    bench_start.add_parsers(benches)
    bench_real.add_parsers(benches)
    bench_live.add_parsers(benches)
