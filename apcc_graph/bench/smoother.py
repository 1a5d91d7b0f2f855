"""``apcc-graph bench smoother``: the back end against the paper's chain, in one run.

Scenario (issue 5): the 3-segment robot ``data/robots/planar_three.toml`` (0.3 m segments, a
camera at every tip), the simulator's room scene (``n_points = 4000``: about 150 tracks per
camera and frame on average), 1 px noise, 10% and 30% outliers, 30 fps, smooth motion. The
estimators start from the true first configuration (the chain needs it; the graph gets it as a
1 deg prior). Every figure is measured here, in the same run:

- accuracy over ``frames`` frames: RMS per segment of the chain, the fixed-lag smoother (lag
  1 s) and the batch; ratios smoother / chain and batch / smoother;
- drift over ``long_frames`` frames: RMS over frames 100-400 and over the last 300, smoother and
  chain;
- speed: ``FixedLagSmoother.update`` wall time per frame (median, 95th percentile) with 3
  cameras and a 1 s lag, for gtsam's IncrementalFixedLagSmoother and BatchFixedLagSmoother, and
  the real-time factor at 30 fps;
- memory: resident set size after 1,000 and after ``memory_frames`` frames of a stream whose
  finished frames are taken out (:meth:`FixedLagSmoother.pop_final`);
- self-calibration: data simulated with k and delta_max off the robot file's by +0.03 and
  +3 deg; RMS with the true model, with the wrong model, and with the wrong model plus
  ``calibrate=True``, and the calibration recovered.
"""

from __future__ import annotations

import math
import resource
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from apcc_graph.estimation.batch import batch_estimate
from apcc_graph.estimation.chain import chain_estimate
from apcc_graph.estimation.smoother import FixedLagSmoother
from apcc_graph.robot import Robot, load_robot
from apcc_graph.segment import Segment
from apcc_graph.sequence import Sequence
from apcc_graph.simulate import simulate

ROBOT_FILE = Path(__file__).resolve().parents[2] / "data" / "robots" / "planar_three.toml"
FPS = 30.0
LAG = 1.0
N_POINTS = 4000
K_OFFSET = 0.03
DELTA_OFFSET = math.radians(3.0)


@dataclass(frozen=True)
class AccuracyRow:
    """RMS error per segment (radians) of one estimator on one sequence."""

    case: str
    method: str
    rms: np.ndarray
    seconds: float
    recoveries: int = 0  # gtsam failures the smoother caught


@dataclass(frozen=True)
class DriftRow:
    """RMS (radians, all segments) over an early and a late window of a long run."""

    method: str
    early: float  # frames 100-400
    late: float  # the last 300 frames
    recoveries: int = 0


@dataclass(frozen=True)
class SpeedRow:
    """Per-frame update time of a smoother backend."""

    backend: str
    frames: int
    median: float  # seconds
    p95: float  # seconds


@dataclass(frozen=True)
class CalibrationRow:
    """One self-calibration run."""

    case: str
    rms: np.ndarray  # radians, per segment
    k: np.ndarray | None  # recovered k per segment
    delta_max: np.ndarray | None  # recovered delta_max per segment (radians)
    recoveries: int = 0


@dataclass(frozen=True)
class SmootherBenchmark:
    """Everything :func:`run_smoother_benchmark` measured."""

    frames: int
    tracks_per_camera: float
    accuracy: tuple[AccuracyRow, ...]
    long_frames: int
    drift: tuple[DriftRow, ...]
    speed: tuple[SpeedRow, ...]
    memory_frames: int
    rss_small: float  # bytes, after 1,000 frames
    rss_large: float  # bytes, after memory_frames frames
    calibration: tuple[CalibrationRow, ...]
    true_segments: tuple[Segment, ...]


def _rss() -> float:
    """Current resident set size (bytes), from /proc; peak RSS where /proc is missing."""
    try:
        pages = int(Path("/proc/self/statm").read_text().split()[1])
        return float(pages * resource.getpagesize())
    except (OSError, ValueError, IndexError):
        return float(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024)


def _sequence(robot: Robot, frames: int, outliers: float, seed: int,
              truth_segments: tuple[Segment, ...] | None = None) -> Sequence:
    return simulate(robot, frames, noise_px=1.0, outlier_fraction=outliers, seed=seed,
                    fps=FPS, scene="room", n_points=N_POINTS,
                    truth_segments=truth_segments).sequence


def _run_smoother(sequence: Sequence, robot: Robot | None = None, progress: bool = False,
                  **options: object) -> tuple[np.ndarray, np.ndarray, FixedLagSmoother]:
    """Angles ``(F, S)`` and update times ``(F,)`` of a smoother run."""
    assert sequence.thetas is not None
    smoother = FixedLagSmoother(robot or sequence.robot, lag=LAG, theta0=sequence.thetas[0],
                                uncertainty=False, **options)  # type: ignore[arg-type]
    times = np.empty(sequence.n_frames)
    for f in tqdm(range(sequence.n_frames), desc="smoother", disable=not progress,
                  leave=False):
        start = time.perf_counter()
        smoother.update(sequence.frame(f))
        times[f] = time.perf_counter() - start
    thetas = np.array([fr.thetas for fr in smoother.finish()])
    return thetas, times, smoother


def _rms(est: np.ndarray, truth: np.ndarray) -> np.ndarray:
    return np.sqrt(np.mean((est - truth) ** 2, axis=0))


def run_smoother_benchmark(
    frames: int = 600,
    long_frames: int = 3000,
    memory_frames: int = 10_000,
    seed: int = 1,
    batch: bool = True,
    progress: bool = False,
) -> SmootherBenchmark:
    """Run every part of the benchmark (see the module docstring)."""
    robot = load_robot(ROBOT_FILE)
    accuracy: list[AccuracyRow] = []
    tracks = []
    for outliers in (0.1, 0.3):
        case = f"{outliers:.0%} outliers"
        seq = _sequence(robot, frames, outliers, seed)
        assert seq.thetas is not None
        tracks.append(np.mean([len(seq.tracks[c]) / frames for c in seq.tracks]))
        start = time.perf_counter()
        chain = chain_estimate(seq, theta0=seq.thetas[0], progress=progress)
        accuracy.append(AccuracyRow(case, "chain", _rms(chain.thetas, seq.thetas),
                                    time.perf_counter() - start))
        start = time.perf_counter()
        thetas, _, sm = _run_smoother(seq, progress=progress)
        accuracy.append(AccuracyRow(case, "smoother", _rms(thetas, seq.thetas),
                                    time.perf_counter() - start, sm.recoveries))
        if batch:
            start = time.perf_counter()
            est = batch_estimate(seq, theta0=seq.thetas[0], initial=thetas,
                                 marginals=False, progress=progress)
            accuracy.append(AccuracyRow(case, "batch", _rms(est.thetas, seq.thetas),
                                        time.perf_counter() - start))

    # Drift and speed over a long run.
    seq = _sequence(robot, long_frames, 0.1, seed + 1)
    assert seq.thetas is not None
    thetas, times, long_run = _run_smoother(seq, progress=progress)
    chain = chain_estimate(seq, theta0=seq.thetas[0], progress=progress)
    early, late = slice(100, 400), slice(long_frames - 300, long_frames)

    def window_rms(est: np.ndarray, rows: slice) -> float:
        return float(np.sqrt(np.mean((est[rows] - seq.thetas[rows]) ** 2)))

    drift = (DriftRow("smoother", window_rms(thetas, early), window_rms(thetas, late),
                      long_run.recoveries),
             DriftRow("chain", window_rms(chain.thetas, early), window_rms(chain.thetas, late)))
    speed = [SpeedRow("incremental (iSAM2)", long_frames, float(np.median(times)),
                      float(np.percentile(times, 95)))]
    short = _sequence(robot, 150, 0.1, seed + 2)
    _, times_b, _ = _run_smoother(short, progress=progress, backend="batch")
    speed.append(SpeedRow("batch (LM over the window)", 150, float(np.median(times_b)),
                          float(np.percentile(times_b, 95))))

    # Memory of a long stream; finished frames are taken out as a streaming user would.
    seq = _sequence(robot, memory_frames, 0.1, seed + 3)
    assert seq.thetas is not None
    smoother = FixedLagSmoother(robot, lag=LAG, theta0=seq.thetas[0], uncertainty=False)
    rss_small = rss_large = 0.0
    for f in tqdm(range(memory_frames), desc="memory", disable=not progress, leave=False):
        smoother.update(seq.frame(f))
        smoother.pop_final()
        if f + 1 == min(1000, memory_frames):
            rss_small = _rss()
    rss_large = _rss()
    del smoother, seq

    # Self-calibration: the data come from segments off the robot file's.
    true_segments = tuple(
        Segment(s.length, s.k + K_OFFSET, s.delta_max + DELTA_OFFSET, s.theta_max)
        for s in robot.segments)
    seq = _sequence(robot, frames, 0.1, seed + 4, truth_segments=true_segments)
    assert seq.thetas is not None
    true_robot = Robot(list(true_segments), list(robot.cameras))
    calibration = []
    thetas, _, sm = _run_smoother(seq, robot=true_robot, progress=progress)
    calibration.append(CalibrationRow("true model", _rms(thetas, seq.thetas), None, None,
                                      sm.recoveries))
    thetas, _, sm = _run_smoother(seq, progress=progress)
    calibration.append(CalibrationRow("robot file (k -0.03, delta_max -3 deg)",
                                      _rms(thetas, seq.thetas), None, None, sm.recoveries))
    thetas, _, sm = _run_smoother(seq, progress=progress, calibrate=True)
    cal = sm.calibration()
    assert cal is not None
    calibration.append(CalibrationRow(
        "robot file + self-calibration", _rms(thetas, seq.thetas),
        np.array([cal[i][0] for i in range(robot.n_segments)]),
        np.array([cal[i][1] for i in range(robot.n_segments)]), sm.recoveries))
    return SmootherBenchmark(
        frames=frames, tracks_per_camera=float(np.mean(tracks)), accuracy=tuple(accuracy),
        long_frames=long_frames, drift=drift, speed=tuple(speed), memory_frames=memory_frames,
        rss_small=rss_small, rss_large=rss_large, calibration=tuple(calibration),
        true_segments=true_segments)


def format_smoother_benchmark(r: SmootherBenchmark) -> str:
    """The benchmark as the table ``apcc-graph bench smoother`` prints."""
    deg = math.degrees
    out = [f"bench smoother: 3 x 0.3 m segments, room scene, ~{r.tracks_per_camera:.0f} tracks "
           f"per camera and frame, 1 px noise, {FPS:.0f} fps, lag {LAG:g} s", ""]
    out.append(f"accuracy over {r.frames} frames, RMS per segment (deg)")
    out.append(f"  {'case':<14} {'method':<9} {'seg 1':>7} {'seg 2':>7} {'seg 3':>7} "
               f"{'time':>8}   ratio to chain    recoveries")
    by_case: dict[str, dict[str, AccuracyRow]] = {}
    for row in r.accuracy:
        by_case.setdefault(row.case, {})[row.method] = row
    for case, rows in by_case.items():
        for method, row in rows.items():
            ratio = row.rms / rows["chain"].rms
            out.append(f"  {case:<14} {method:<9} "
                       + " ".join(f"{deg(v):7.3f}" for v in row.rms)
                       + f" {row.seconds:7.1f}s   "
                       + " ".join(f"{v:5.2f}" for v in ratio)
                       + (f"  {row.recoveries:>6}" if method == "smoother" else ""))
        if "batch" in rows:
            ratio = rows["batch"].rms / rows["smoother"].rms
            out.append(f"  {case:<14} batch / smoother: "
                       + " ".join(f"{v:5.2f}" for v in ratio))
    out += ["", f"drift over {r.long_frames} frames, RMS over all segments (deg)",
            f"  {'method':<9} {'frames 100-400':>15} {'last 300':>10} {'late / early':>13}"]
    for row in r.drift:
        out.append(f"  {row.method:<9} {deg(row.early):15.3f} {deg(row.late):10.3f} "
                   f"{row.late / row.early:13.2f}")
    out.append(f"  (smoother recoveries from gtsam failures: {r.drift[0].recoveries})")
    out += ["", "speed: FixedLagSmoother.update per frame, 3 cameras, lag 1 s",
            f"  {'backend':<28} {'frames':>7} {'median':>10} {'p95':>10} {'x real time':>12}"]
    for row in r.speed:
        out.append(f"  {row.backend:<28} {row.frames:>7} {row.median * 1e3:8.2f}ms "
                   f"{row.p95 * 1e3:8.2f}ms {1.0 / FPS / row.median:12.1f}")
    mb = 1024.0 ** 2
    out += ["", "memory: resident set size of a stream (finished frames taken out)",
            f"  after 1,000 frames {r.rss_small / mb:8.1f} MB; after {r.memory_frames:,} "
            f"frames {r.rss_large / mb:8.1f} MB; ratio {r.rss_large / r.rss_small:.3f}"]
    out += ["", f"self-calibration over {r.frames} frames, data from k + {K_OFFSET}, delta_max "
            f"+ {deg(DELTA_OFFSET):.0f} deg",
            f"  {'model':<40} {'seg 1':>7} {'seg 2':>7} {'seg 3':>7}  ratio to true model"]
    base = r.calibration[0].rms
    for row in r.calibration:
        out.append(f"  {row.case:<40} " + " ".join(f"{deg(v):7.3f}" for v in row.rms)
                   + "  " + " ".join(f"{v:5.2f}" for v in row.rms / base)
                   + f"   recoveries {row.recoveries}")
    last = r.calibration[-1]
    if last.k is not None and last.delta_max is not None:
        for i, seg in enumerate(r.true_segments):
            out.append(f"  segment {i + 1}: k {last.k[i]:.4f} (true {seg.k:.4f}), delta_max "
                       f"{deg(last.delta_max[i]):.2f} deg (true {deg(seg.delta_max):.2f})")
    return "\n".join(out)

