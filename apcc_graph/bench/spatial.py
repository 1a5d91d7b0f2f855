"""``apcc-graph bench spatial``: robots that bend in 3-D, against the Cramer-Rao bound.

Scenario: the 3-segment robot of the other back-end benchmarks with bending planes that turn
(the simulator's ``spatial=True``: psi sweeps within +/- pi while theta swings through
straight), the room scene (``n_points = 4000``), 1 px noise, 10% outliers, 30 fps, several
seeds. Every estimator starts from the true first bends with a 0.1 deg prior on each
bending-vector component (the chain starts exactly there). Measured in the same run:

- the Cramer-Rao bound of each sequence in bending vectors
  (:func:`apcc_graph.evaluation.sequence_bound.sequence_bound` with ``spatial=True``: every
  observation once, each track's point a nuisance), per segment the RMS over frames of
  ``sqrt(sigma_u^2 + sigma_v^2)``, and per 100-frame window;
- accuracy: the RMS over frames of the bending-vector error ``|b - b_true|`` per segment of the
  chained 2-point estimate, the spatial batch and the fixed-lag smoother (1 s window), beside
  the bound: median over seeds of
  RMS / bound, the worst seed and the worst 100-frame window; where sigmas exist, the mean of
  ``|b - b_true|^2 / (sigma_theta^2 + theta^2 sigma_psi^2)`` (1 for honest sigmas);
- how close to straight each segment came (smallest true ``|theta|``), so passages through
  straight are part of every figure;
- the seconds of each estimator.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence as SequenceOf
from dataclasses import dataclass

import numpy as np

from apcc_graph.bench import ROBOT_FILE
from apcc_graph.estimation.batch import batch_estimate
from apcc_graph.estimation.chain import chain_estimate
from apcc_graph.estimation.options import GraphOptions
from apcc_graph.estimation.result import Estimate
from apcc_graph.estimation.smoother_runs import smoother_estimate
from apcc_graph.evaluation.sequence_bound import sequence_bound
from apcc_graph.io.console import progress_bar
from apcc_graph.io.robot_file import load_robot
from apcc_graph.model.arrays import rms, window_rms
from apcc_graph.simulation.simulator import simulate

FPS = 30.0
N_POINTS = 4000
NOISE_PX = 1.0
THETA0_SIGMA = math.radians(0.1)
WINDOW = 100
METHODS = ("chain", "batch", "smoother")
TARGETS = {"batch": 2.0, "smoother": 3.0}
"""RMS / bound each method is held to, per segment."""


@dataclass(frozen=True)
class SpatialRun:
    """One estimator on one spatial sequence, beside that sequence's bound (radians)."""

    seed: int
    method: str
    rms: np.ndarray  # (S,) of |b - b_true|
    bound: np.ndarray  # (S,)
    worst_window: np.ndarray  # (S,) max over 100-frame windows of RMS / bound
    nees: np.ndarray | None  # (S,) mean |b - b_true|^2 / sigma_b^2
    closest_to_straight: np.ndarray  # (S,) min over frames of the true |theta|
    seconds: float

    @property
    def ratio(self) -> np.ndarray:
        """``(S,)`` RMS / bound."""
        return self.rms / self.bound


@dataclass(frozen=True)
class SpatialBenchmark:
    """Everything :func:`run_spatial_benchmark` measured."""

    frames: int
    outliers: float
    seeds: tuple[int, ...]
    runs: tuple[SpatialRun, ...]


def _estimate(method: str, seq, progress: bool) -> Estimate:
    theta0, psi0 = seq.thetas[0], seq.psis[0]
    if method == "chain":
        return chain_estimate(seq, theta0, threshold_px=NOISE_PX, progress=progress,
                              psi0=psi0, spatial=True)
    options = GraphOptions(theta0_sigma=THETA0_SIGMA, threshold_px=NOISE_PX)
    if method == "batch":
        return batch_estimate(seq, theta0, options=options, progress=progress, psi0=psi0,
                              spatial=True)
    if method == "smoother":
        return smoother_estimate(seq, theta0, options=options, progress=progress,
                                 spatial=True, psi0=psi0)
    raise ValueError(f"method {method!r}: expected one of {', '.join(METHODS)}")


def run_spatial_benchmark(frames: int = 600, seeds: SequenceOf[int] = (1, 2, 3),
                          outliers: float = 0.1, methods: SequenceOf[str] = METHODS,
                          progress: bool = False) -> SpatialBenchmark:
    """Run the benchmark (see the module docstring)."""
    robot = load_robot(ROBOT_FILE)
    runs = []
    for seed in progress_bar(seeds, desc="spatial", progress=progress):
        sim = simulate(robot, frames, noise_px=NOISE_PX, outlier_fraction=outliers, seed=seed,
                       fps=FPS, scene="room", n_points=N_POINTS, spatial=True)
        seq = sim.sequence
        bound = sequence_bound(sim, NOISE_PX, THETA0_SIGMA, spatial=True)
        closest = np.min(np.abs(seq.thetas), axis=0)
        for method in methods:
            start = time.perf_counter()
            est = _estimate(method, seq, progress)
            seconds = time.perf_counter() - start
            err = est.errors(seq.thetas, seq.psis)
            sig = est.bend_sigmas()
            nees = (np.mean((err / sig) ** 2, axis=0) if np.all(np.isfinite(sig)) else None)
            worst = np.max(window_rms(err, WINDOW) / window_rms(bound.sigmas, WINDOW), axis=0)
            runs.append(SpatialRun(seed, method, rms(err), rms(bound.sigmas), worst, nees,
                                   closest, seconds))
    return SpatialBenchmark(frames, outliers, tuple(seeds), tuple(runs))


def _row(label: str, values: np.ndarray, fmt: str = "{:>10.3f}") -> str:
    return f"  {label:<34}" + "".join(fmt.format(v) for v in values)


def format_spatial_benchmark(result: SpatialBenchmark) -> str:
    """The benchmark's tables, one per method, and the verdict against the targets."""
    n_seg = len(result.runs[0].rms)
    head = f"  {'':<34}" + "".join(f"{f'seg {i + 1}':>10}" for i in range(n_seg))
    lines = [f"spatial robot, {result.frames} frames at {FPS:g} fps, room scene, "
             f"{NOISE_PX:g} px, {result.outliers:.0%} outliers, seeds "
             f"{','.join(str(s) for s in result.seeds)}; errors of the bending vector "
             "b = theta (cos psi, sin psi)", head]
    first = [r for r in result.runs if r.method == result.runs[0].method]
    lines.append(_row("bound, RMS over frames (deg)",
                      np.degrees(np.median([r.bound for r in first], axis=0)), "{:>10.4f}"))
    lines.append(_row("closest to straight, min (deg)",
                      np.degrees(np.min([r.closest_to_straight for r in first], axis=0))))
    verdicts = []
    for method in dict.fromkeys(r.method for r in result.runs):
        runs = [r for r in result.runs if r.method == method]
        ratios = np.array([r.ratio for r in runs])
        lines.append(f"{method} ({np.median([r.seconds for r in runs]):.1f} s per sequence)")
        lines.append(_row("RMS, median over seeds (deg)",
                          np.degrees(np.median([r.rms for r in runs], axis=0)), "{:>10.4f}"))
        lines.append(_row("RMS / bound, median over seeds", np.median(ratios, axis=0)))
        lines.append(_row("RMS / bound, worst seed", np.max(ratios, axis=0)))
        lines.append(_row("worst 100-frame window / bound",
                          np.max([r.worst_window for r in runs], axis=0)))
        if all(r.nees is not None for r in runs):
            lines.append(_row("mean (error / sigma)^2 (1 = honest)",
                              np.median([r.nees for r in runs], axis=0)))
        if method in TARGETS:
            target = TARGETS[method]
            met = bool(np.all(ratios <= target))
            verdicts.append(f"{method}: every seed and segment within {target:g}x of the "
                            f"bound: {'yes' if met else 'NO'} (worst "
                            f"{float(np.max(ratios)):.2f}x)")
    return "\n".join(lines + verdicts)
