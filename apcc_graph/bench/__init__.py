"""Benchmarks behind ``apcc-graph bench ...``: each returns a result object with its figures and
the ratios against the peers measured in the same run. They are commands, never timed tests.

May import: every library layer (model to evaluation) and the ``apcc_graph`` facade; the plots
and the command line import the benchmarks, never the reverse.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable
from pathlib import Path

ROBOT_FILE = Path(__file__).resolve().parent / "planar_three.toml"
"""The benches' three-segment robot, shipped with the package (the same file as
``data/robots/planar_three.toml`` of the repository), so that the benches run from any folder."""


def best_time(fn: Callable[[], object], repeats: int) -> float:
    """Best wall time of ``repeats`` calls of ``fn`` (seconds)."""
    best = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - start)
    return best


def table_cells(values: Iterable[float], fmt: str = "6.3f") -> str:
    """One row's numbers for a benchmark table, each formatted with ``fmt``."""
    return " ".join(f"{v:{fmt}}" for v in values)
