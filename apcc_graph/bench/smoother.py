"""``apcc-graph bench smoother``: the back end against the Cramer-Rao bound, in one run.

Scenario: the 3-segment robot ``data/robots/planar_three.toml`` (0.3 m segments, a camera at
every tip), the simulator's room scene (``n_points = 4000``: about 150 tracks per camera and
frame), 1 px noise, 10% and 30% outliers, 30 fps, smooth motion, several seeds. Every
estimator starts from the true first configuration with a 0.1 deg prior (the chain starts
exactly there). Every figure is measured here, in the same run:

- the Cramer-Rao bound of each sequence (:mod:`apcc_graph.evaluation.sequence_bound`), per
  segment and per 100-frame window, and the bound of a fixed-lag smoother (no observation after
  frame f + lag informs frame f: :func:`~apcc_graph.evaluation.sequence_bound.lag_bound`),
  sampled every 30 frames;
- accuracy: RMS error per segment of the chain, the smoother (lag 1 s), the smoother that solves
  at keyframes only (``smoother-keyframes``, the default
  :class:`~apcc_graph.estimation.keyframes.KeyframeRule`; beside the smoother: their RMS and
  seconds ratios) and the batch, beside the bound: median over seeds of RMS / bound, the worst
  seed, the worst 100-frame window; for the smoothers also RMS / the lag bound; the mean of
  ``(error / sigma)^2`` per segment;
- drift: the smoother's RMS over frames 100-400 and the last 300 of ``long_frames``;
- speed: the smoother's ``update`` per frame (median, 95th percentile) and the batch's seconds,
  each with the compiled kernels and their numpy reference (:mod:`apcc_graph.bench.engines`),
  and the smoother's reproducible window against gtsam's fixed-lag smoother;
- with ``--model-sigma MM,DEG``: the smoother with model error as noise (``smoother-noise``)
  beside the exact one on the same sequences (RMS, seconds, median update);
- memory: resident set size after 1,000 and ``memory_frames`` frames (``pop_final``).
"""

from __future__ import annotations

import math
import resource
import time
from collections.abc import Sequence as SequenceOf
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from apcc_graph.bench import ROBOT_FILE
from apcc_graph.bench.engines import (
    EngineTimes,
    WindowTimes,
    engine_times,
    window_times,
)
from apcc_graph.estimation.batch import batch_estimate
from apcc_graph.estimation.chain import chain_estimate
from apcc_graph.estimation.keyframes import KeyframeRule
from apcc_graph.estimation.options import GraphOptions
from apcc_graph.estimation.smoother import FixedLagSmoother
from apcc_graph.estimation.smoother_options import SmootherOptions, WindowOptions
from apcc_graph.evaluation.sequence_bound import LagBound, SequenceBound, lag_bound, sequence_bound
from apcc_graph.io.console import progress_bar
from apcc_graph.io.robot_file import load_robot
from apcc_graph.model.arrays import rms, window_rms
from apcc_graph.model.robot import Robot
from apcc_graph.model.sequence import Sequence
from apcc_graph.simulation.simulator import Simulation, simulate

QUICK = SmootherOptions(window=WindowOptions(uncertainty=False))
"""The smoother without marginal sigmas: the benches that time it or only read its angles."""

FPS = 30.0
LAG = 1.0
N_POINTS = 4000
NOISE_PX = 1.0
THETA0_SIGMA = math.radians(0.1)
WINDOW = 100
LAG_STEP = 30
KEYFRAMES = "smoother-keyframes"  # the smoother that solves at keyframes (the default rule)
METHODS = ("chain", "smoother", KEYFRAMES, "batch")
MODEL_NOISE = "smoother-noise"  # the smoother with model error as noise, beside the exact one
SMOOTHERS = ("smoother", KEYFRAMES, MODEL_NOISE)


@dataclass(frozen=True)
class Run:
    """One estimator on one sequence, beside that sequence's bound (radians)."""

    case: str
    seed: int
    method: str
    rms: np.ndarray  # (S,)
    window_rms: np.ndarray  # (W, S)
    bound: np.ndarray  # (S,)
    window_bound: np.ndarray  # (W, S)
    seconds: float
    nees: np.ndarray | None = None  # (S,) mean (error / sigma)^2, where sigmas exist
    lag_ratio: np.ndarray | None = None  # (S,) RMS / lag bound at the sampled frames
    lag_window: np.ndarray | None = None  # (S,) worst window of that
    update_median: float | None = None  # seconds, a smoother's update

    @property
    def ratio(self) -> np.ndarray:
        """``(S,)`` RMS / bound."""
        return self.rms / self.bound

    @property
    def worst_window(self) -> np.ndarray:
        """``(S,)`` the largest window RMS / window bound."""
        return np.max(self.window_rms / self.window_bound, axis=0)


@dataclass(frozen=True)
class SmootherBenchmark:
    """Everything :func:`run_smoother_benchmark` measured."""

    frames: int
    seeds: tuple[int, ...]
    tracks_per_camera: float
    runs: tuple[Run, ...]
    long_frames: int
    drift_early: float  # radians, frames 100-400, all segments
    drift_late: float  # radians, the last 300 frames
    update_median: float  # seconds
    update_p95: float  # seconds
    memory_frames: int
    rss_small: float  # bytes, after 1,000 frames
    rss_large: float  # bytes, after memory_frames frames
    engines: tuple[EngineTimes, ...] = ()  # compiled and numpy reference, on one recording
    windows: tuple[WindowTimes, ...] = ()  # reproducible and gtsam's window, the same one
    model_sigma: tuple[float, float] | None = None  # metres, radians: the smoother-noise row


def resident_set_size() -> float:
    """Current resident set size (bytes), from /proc; peak RSS where /proc is missing."""
    try:
        pages = int(Path("/proc/self/statm").read_text().split()[1])
        return float(pages * resource.getpagesize())
    except (OSError, ValueError, IndexError):
        return float(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024)


def room_simulation(robot: Robot, frames: int, outliers: float, seed: int) -> Simulation:
    """The benchmark's room-scene sequence (1 px, 30 fps, 4000 points) of ``robot``."""
    return simulate(robot, frames, noise_px=NOISE_PX, outlier_fraction=outliers, seed=seed,
                    fps=FPS, scene="room", n_points=N_POINTS)


def _stream(smoother: FixedLagSmoother, sequence: Sequence,
            progress: bool, label: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Final angles and sigmas ``(F, S)`` and update times ``(F,)`` of a smoother run."""
    times = np.empty(sequence.n_frames)
    for f in progress_bar(range(sequence.n_frames), desc=label, progress=progress, leave=False):
        start = time.perf_counter()
        smoother.update(sequence.frame(f))
        times[f] = time.perf_counter() - start
    frames = smoother.finish()
    return (np.array([fr.thetas for fr in frames]), np.array([fr.sigmas for fr in frames]),
            times)


Estimated = tuple[np.ndarray, np.ndarray | None, float, float | None]
"""A method's angles ``(F, S)``, sigmas or None, seconds and median update (smoothers)."""


def _estimators(sim: Simulation, methods: SequenceOf[str], progress: bool,
                model_sigma: tuple[float, float] | None = None) -> dict[str, Estimated]:
    """method -> :data:`Estimated`; with ``model_sigma`` (metres, radians) :data:`MODEL_NOISE`
    too, right after the exact smoother."""
    seq = sim.sequence
    assert seq.thetas is not None
    theta0 = seq.thetas[0]
    out: dict[str, Estimated] = {}
    if model_sigma is not None and MODEL_NOISE not in methods:
        at = list(methods).index("smoother") + 1 if "smoother" in methods else len(methods)
        methods = [*methods[:at], MODEL_NOISE, *methods[at:]]
    for method in methods:
        start = time.perf_counter()
        update: float | None = None
        if method == "chain":
            thetas, sigmas = chain_estimate(seq, theta0=theta0, progress=progress).thetas, None
        elif method == "batch":
            est = batch_estimate(seq, theta0=theta0, progress=progress)
            thetas, sigmas = est.thetas, est.sigmas
        elif method == "smoother":
            ps = FixedLagSmoother(seq.robot, lag=LAG, theta0=theta0)
            thetas, sigmas, times = _stream(ps, seq, progress, "smoother")
            update = float(np.median(times))
        elif method == KEYFRAMES:
            ps = FixedLagSmoother(seq.robot, lag=LAG, theta0=theta0,
                                  settings=SmootherOptions(keyframes=KeyframeRule()))
            thetas, sigmas, times = _stream(ps, seq, progress, KEYFRAMES)
            update = float(np.median(times))
        elif method == MODEL_NOISE and model_sigma is not None:
            ps = FixedLagSmoother(seq.robot, lag=LAG, theta0=theta0,
                                  options=GraphOptions(model_sigma=model_sigma))
            thetas, sigmas, times = _stream(ps, seq, progress, MODEL_NOISE)
            update = float(np.median(times))
        else:
            raise ValueError(f"method {method!r}: expected one of {METHODS}")
        out[method] = (thetas, sigmas, time.perf_counter() - start, update)
    return out


def _run(case: str, seed: int, method: str, err: np.ndarray, sigmas: np.ndarray | None,
         seconds: float, bound: SequenceBound, lagged: LagBound | None,
         update: float | None = None) -> Run:
    """One estimator's errors ``(F, S)`` on one sequence, beside its bounds (``update``: a
    smoother's median update, seconds)."""
    nees = None
    if sigmas is not None and np.all(np.isfinite(sigmas)):
        nees = np.mean((err / sigmas) ** 2, axis=0)
    lag_ratio = lag_window = None
    if lagged is not None and method in SMOOTHERS:
        sampled = err[lagged.frames]
        lag_ratio = rms(sampled) / lagged.rms()
        per = [rms(sampled[(lagged.frames >= s) & (lagged.frames < s + WINDOW)])
               for s in range(0, len(err), WINDOW)]
        lag_window = np.max(np.array(per) / lagged.window_rms(WINDOW), axis=0)
    return Run(case, seed, method, rms(err), window_rms(err, WINDOW), bound.rms(),
               bound.window_rms(WINDOW), seconds, nees, lag_ratio, lag_window, update)


def _accuracy(robot: Robot, frames: int, seeds: SequenceOf[int], outliers: SequenceOf[float],
              methods: SequenceOf[str], progress: bool,
              model_sigma: tuple[float, float] | None = None
              ) -> tuple[list[Run], list[float]]:
    """Every method on every sequence beside its bounds, and the tracks per camera and frame
    of each sequence."""
    runs: list[Run] = []
    tracks = []
    for rate in outliers:
        case = f"{rate:.0%} outliers"
        for seed in seeds:
            sim = room_simulation(robot, frames, rate, seed)
            seq = sim.sequence
            assert seq.thetas is not None
            tracks.append(np.mean([len(seq.tracks[c]) / frames for c in seq.tracks]))
            bound = sequence_bound(sim, NOISE_PX, THETA0_SIGMA)
            lagged = (lag_bound(sim, NOISE_PX, round(LAG * FPS), THETA0_SIGMA, LAG_STEP)
                      if model_sigma is not None or any(m in SMOOTHERS for m in methods)
                      else None)
            estimated = _estimators(sim, methods, progress, model_sigma)
            for method, (thetas, sigmas, seconds, update) in estimated.items():
                runs.append(_run(case, seed, method, thetas - seq.thetas, sigmas, seconds,
                                 bound, lagged, update))
    return runs, tracks


def _drift(robot: Robot, frames: int, seed: int, progress: bool
           ) -> tuple[float, float, float, float]:
    """The smoother over a long run: RMS over frames 100-400 and the last 300
    (radians), and the median and 95th percentile of its update time (seconds)."""
    seq = room_simulation(robot, frames, 0.1, seed).sequence
    assert seq.thetas is not None
    sm = FixedLagSmoother(robot, lag=LAG, theta0=seq.thetas[0], settings=QUICK)
    thetas, _, times = _stream(sm, seq, progress, "long run")
    err = thetas - seq.thetas
    return (float(rms(err[100:400], axis=None)), float(rms(err[-300:], axis=None)),
            float(np.median(times)), float(np.percentile(times, 95)))


def _memory(robot: Robot, frames: int, seed: int, progress: bool) -> tuple[float, float]:
    """Resident set size (bytes) after 1,000 and after ``frames`` frames of a stream whose
    finished frames are taken out, as a streaming user would."""
    seq = room_simulation(robot, frames, 0.1, seed).sequence
    assert seq.thetas is not None
    sm = FixedLagSmoother(robot, lag=LAG, theta0=seq.thetas[0], settings=QUICK)
    rss_small = float("nan")
    for f in progress_bar(range(frames), desc="memory", progress=progress, leave=False):
        sm.update(seq.frame(f))
        sm.pop_final()
        if f + 1 == min(1000, frames):
            rss_small = resident_set_size()
    return rss_small, resident_set_size()


def run_smoother_benchmark(
    frames: int = 600,
    seeds: SequenceOf[int] = (1, 2, 3, 4, 5),
    outliers: SequenceOf[float] = (0.1, 0.3),
    methods: SequenceOf[str] = METHODS,
    long_frames: int = 3000,
    memory_frames: int = 10_000,
    progress: bool = False,
    model_sigma: tuple[float, float] | None = None,
) -> SmootherBenchmark:
    """Run every part of the benchmark (module docstring; ``model_sigma``: metres, radians)."""
    robot = load_robot(ROBOT_FILE)
    runs, tracks = _accuracy(robot, frames, seeds, outliers, methods, progress, model_sigma)
    early = late = median = p95 = float("nan")
    engines: list[EngineTimes] = []
    windows: list[WindowTimes] = []
    if long_frames:
        early, late, median, p95 = _drift(robot, long_frames, seeds[0] + 100, progress)
        peer = room_simulation(robot, frames, 0.1, seeds[0] + 100).sequence
        engines = engine_times(peer, QUICK, progress)
        windows = window_times(peer, QUICK, progress)
    rss_small = rss_large = float("nan")
    if memory_frames:
        rss_small, rss_large = _memory(robot, memory_frames, seeds[0] + 200, progress)
    return SmootherBenchmark(frames, tuple(seeds), float(np.mean(tracks)), tuple(runs),
                             long_frames, early, late, median, p95, memory_frames, rss_small,
                             rss_large, tuple(engines), tuple(windows), model_sigma)
