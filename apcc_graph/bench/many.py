"""``apcc-graph bench many``: many sequences on Dask against the same sequences one after the
other in one process, in one run.

Simulates ``sequences`` recordings (the three-segment robot, 1 px noise, 10% outliers, seeds
``seed, seed + 1, ...``) into a temporary folder, estimates them with
:func:`~apcc_graph.estimation.many.estimate_many` once in process (``workers=1``, the peer) and
once on a local Dask cluster, each started at its true first frame (0.1 deg prior), and
reports both wall times, their ratio and whether every ``theta.csv`` is identical.
"""

from __future__ import annotations

import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from apcc_graph.bench import ROBOT_FILE
from apcc_graph.estimation.many import estimate_many
from apcc_graph.io import load_robot, save_sequence
from apcc_graph.simulation.simulator import simulate


@dataclass(frozen=True)
class ManyBenchmark:
    """Result of :func:`run_many_benchmark`."""

    sequences: int
    frames: int
    method: str
    workers: int
    serial_seconds: float
    dask_seconds: float
    identical: bool
    failed: int

    @property
    def speedup(self) -> float:
        """Serial wall time over Dask wall time."""
        return self.serial_seconds / self.dask_seconds


def run_many_benchmark(sequences: int = 16, frames: int = 600, method: str = "batch",
                       workers: int = 2, seed: int = 1, robot: str | Path = ROBOT_FILE,
                       progress: bool = False) -> ManyBenchmark:
    """Time ``sequences`` recordings of ``frames`` frames serially and on ``workers`` Dask
    workers (see the module docstring)."""
    model = load_robot(robot)
    options = {"theta0": "truth", "noise_px": 1.0}
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        folders = []
        for i in range(sequences):
            sim = simulate(model, frames, noise_px=1.0, outlier_fraction=0.1, seed=seed + i)
            folders.append(root / "in" / f"seq_{i + 1:03d}")
            save_sequence(sim.sequence, folders[-1])
        start = time.perf_counter()
        serial = estimate_many(folders, root / "serial", method, options, workers=1,
                               progress=progress)
        serial_seconds = time.perf_counter() - start
        start = time.perf_counter()
        dask = estimate_many(folders, root / "dask", method, options, workers=workers,
                             progress=progress)
        dask_seconds = time.perf_counter() - start
        identical = all((root / "serial" / f.name / "theta.csv").read_bytes()
                        == (root / "dask" / f.name / "theta.csv").read_bytes()
                        for f, run in zip(folders, serial, strict=True) if run.status == "ok")
    failed = sum(r.status.startswith("failed") for r in [*serial, *dask])
    return ManyBenchmark(sequences, frames, method, workers, serial_seconds, dask_seconds,
                         identical and [r.status for r in serial] == [r.status for r in dask],
                         failed)


def format_many_benchmark(r: ManyBenchmark) -> str:
    """The benchmark's table."""
    return "\n".join([
        f"{r.sequences} sequences x {r.frames} frames, method {r.method}:",
        f"  {'in process, one after the other (peer)':<44} {r.serial_seconds:>8.1f} s   1.00x",
        f"  {f'local Dask cluster, {r.workers} workers':<44} {r.dask_seconds:>8.1f} s "
        f"{r.speedup:>6.2f}x",
        f"identical theta.csv files: {'yes' if r.identical else 'NO'}; failed sequences: "
        f"{r.failed}",
        f"target: at least 1.7x on 2 workers -> {r.speedup:.2f}x "
        f"({'met' if r.speedup >= 1.7 else 'NOT met'})",
    ])
