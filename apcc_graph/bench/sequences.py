"""``apcc-graph bench sequences``: simulating, saving and loading sequences, against peers.

One run: simulate the three-segment robot for 1000 frames with ~200 tracks per camera (timed), then
a denser scene so the three tracks files hold about a million rows together, save it, and time
``load_sequence`` (full validation) against two peers reading the same files: ``numpy.loadtxt``
alone (the parsing floor, no checks) and Python's ``csv`` module with ``float()`` per field.
"""

from __future__ import annotations

import csv
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from apcc_graph.bench import best_time
from apcc_graph.io.sequence_folder import load_sequence, save_sequence
from apcc_graph.model.robot import Robot
from apcc_graph.simulation.simulator import simulate


@dataclass(frozen=True)
class SequenceTiming:
    """One timed step (best wall time over the repeats)."""

    step: str
    rows: int
    seconds: float


@dataclass(frozen=True)
class SequenceBenchmark:
    """Result of :func:`run_sequence_benchmark`."""

    n_frames: int
    tracks_per_camera: float
    simulate: SequenceTiming
    save: SequenceTiming
    load: SequenceTiming
    peers: tuple[SequenceTiming, ...]


def _csv_module(files: list[Path]) -> None:
    for path in files:
        with path.open(newline="") as fh:
            reader = csv.reader(fh)
            next(reader)
            np.array([[float(x) for x in row] for row in reader])


def _loadtxt(files: list[Path]) -> None:
    for path in files:
        np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)


def run_sequence_benchmark(robot: Robot, n_frames: int = 1000, target_rows: int = 1_000_000,
                           repeats: int = 3, seed: int = 0,
                           folder: Path | None = None) -> SequenceBenchmark:
    """Time simulation (default scene) and the load of ~``target_rows`` track rows.

    Args:
        robot: a robot with cameras.
        n_frames: frames to simulate.
        target_rows: track rows wanted in the load test (a denser scene is simulated for it).
        repeats: timing repeats (best kept).
        seed: random seed.
        folder: where to write the sequence (default: a temporary folder, removed after).
    """
    n_cams = len(robot.camera_segments)
    sim_seconds = best_time(lambda: simulate(robot, n_frames, seed=seed), 1)
    sim = simulate(robot, n_frames, seed=seed)
    rows = sum(len(t) for t in sim.sequence.tracks.values())
    per_camera = rows / (n_frames * n_cams)
    # Scale the scene so that the load test has about target_rows rows.
    dense_points = int(2700 * target_rows / max(rows, 1))
    dense = simulate(robot, n_frames, seed=seed, n_points=dense_points).sequence
    dense_rows = sum(len(t) for t in dense.tracks.values())
    if abs(dense_rows - target_rows) > 0.02 * target_rows:  # one correction step
        dense_points = int(dense_points * target_rows / max(dense_rows, 1))
        dense = simulate(robot, n_frames, seed=seed, n_points=dense_points).sequence
        dense_rows = sum(len(t) for t in dense.tracks.values())
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(folder) if folder is not None else Path(tmp) / "sequence"
        save_seconds = best_time(lambda: save_sequence(dense, out), 1)
        files = sorted((out / "tracks").glob("cam_*.csv"))
        load_seconds = best_time(lambda: load_sequence(out), repeats)
        peers = (
            SequenceTiming("peer: numpy.loadtxt only (no checks)", dense_rows,
                           best_time(lambda: _loadtxt(files), repeats)),
            SequenceTiming("peer: csv module + float()", dense_rows,
                           best_time(lambda: _csv_module(files), 1)),
        )
    return SequenceBenchmark(
        n_frames=n_frames,
        tracks_per_camera=per_camera,
        simulate=SequenceTiming(f"simulate ({n_cams} cameras)", rows, sim_seconds),
        save=SequenceTiming("save_sequence", dense_rows, save_seconds),
        load=SequenceTiming("load_sequence (validated)", dense_rows, load_seconds),
        peers=peers,
    )
