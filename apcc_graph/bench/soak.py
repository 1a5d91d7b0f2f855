"""``apcc-graph bench soak``: the default smoother over a long simulated stream.

The stream (:class:`~apcc_graph.simulation.stream.SimulatedStream`: the three-segment robot, the
room scene, 1 px noise, 10% outliers, 30 fps) is generated frame by frame and never stored. The
smoother (projection model, lag 1 s, no marginal sigmas) starts at the true first frame; a
streaming user's loop takes finished frames out with ``pop_final`` after every update.

Measured in the same run:

- resident set size at every checkpoint (every ``frames / 20`` frames; printed as the run
  goes), against the target: within 10% of the size after 10,000 frames at the end;
- the update time per frame, wall clock and CPU time of the calling thread (the CPU time is not
  inflated by other processes on the machine), median per block, against the target: the median
  over the last 1,000 frames within 1.2x of frames 1,000-2,000;
- the RMS error per segment per block, beside the Cramer-Rao bound of a fixed-lag smoother on
  a 600-frame simulated sequence of the same scenario (the bound of a 100,000-frame stream
  itself would need a 300,000-unknown information matrix per sample). The bound counts the
  images only; the smoother's motion prior adds information of its own, so an RMS under the
  bound is possible.

numpy's BLAS runs on one thread, as in every estimate of many sequences: its idle threads would
otherwise spin on the second core.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
from threadpoolctl import threadpool_limits
from tqdm import tqdm

from apcc_graph.bench.smoother import FPS, LAG, N_POINTS, NOISE_PX, ROBOT_FILE, resident_set_size
from apcc_graph.estimation.smoother import FixedLagSmoother
from apcc_graph.estimation.smoother_options import SmootherOptions, WindowOptions
from apcc_graph.evaluation.sequence_bound import lag_bound
from apcc_graph.io.console import progress_bar
from apcc_graph.io.robot_file import load_robot
from apcc_graph.simulation.simulator import simulate
from apcc_graph.simulation.stream import SimulatedStream

OUTLIERS = 0.1
MEMORY_REFERENCE = 10_000
"""The memory target compares the end of the stream with this many frames."""


@dataclass(frozen=True)
class SoakBenchmark:
    """Result of :func:`run_soak`.

    Attributes:
        frames: frames streamed.
        checkpoints: ``(C,)`` frame counts at which the rest was read.
        rss: ``(C,)`` resident set size (bytes) at each checkpoint.
        wall, cpu: ``(F,)`` seconds per update, wall clock and the thread's CPU time.
        block_rms: ``(C, S)`` RMS error (radians) of the frames finished in each block up to
            its checkpoint.
        bound: ``(S,)`` median fixed-lag bound of the reference sequence (radians).
        rss_reference: resident set size after ``MEMORY_REFERENCE`` frames (NaN if fewer).
        recoveries: gtsam failures the smoother caught and recovered from.
    """

    frames: int
    checkpoints: np.ndarray
    rss: np.ndarray
    wall: np.ndarray
    cpu: np.ndarray
    block_rms: np.ndarray
    bound: np.ndarray
    rss_reference: float
    recoveries: int

    def median_ratio(self, times: np.ndarray) -> float:
        """Median update over the last 1,000 frames over frames 1,000-2,000."""
        return float(np.median(times[-1000:]) / np.median(times[1000:2000]))

    @property
    def memory_ratio(self) -> float:
        """Resident set size at the end over that after ``MEMORY_REFERENCE`` frames."""
        return float(self.rss[-1] / self.rss_reference)


def reference_bound(seed: int, frames: int = 600) -> np.ndarray:
    """``(S,)`` median over sampled frames of the fixed-lag bound (radians) of a simulated
    sequence of the soak's scenario."""
    robot = load_robot(ROBOT_FILE)
    sim = simulate(robot, frames, noise_px=NOISE_PX, outlier_fraction=OUTLIERS, seed=seed,
                   fps=FPS, scene="room", n_points=N_POINTS)
    bound = lag_bound(sim, NOISE_PX, int(round(LAG * FPS)), math.radians(0.1), step=60)
    return np.median(bound.sigmas, axis=0)


def run_soak(frames: int = 100_000, seed: int = 1, bound: bool = True,
             progress: bool = False) -> SoakBenchmark:
    """Stream ``frames`` frames through the default smoother (see the module docstring)."""
    if frames < 2000:
        raise ValueError(f"frames = {frames}: the soak needs at least 2,000 frames (its speed "
                         "target reads frames 1,000-2,000)")
    robot = load_robot(ROBOT_FILE)
    stream = SimulatedStream(robot, NOISE_PX, OUTLIERS, seed, fps=FPS, n_points=N_POINTS)
    smoother = FixedLagSmoother(robot, lag=LAG, theta0=stream.thetas(0),
                                settings=SmootherOptions(window=WindowOptions(uncertainty=False)))
    step = max(frames // 20, 1)
    checkpoints = np.unique([*range(step, frames + 1, step), frames])
    wall, cpu = np.empty(frames), np.empty(frames)
    rss, block_rms = np.empty(len(checkpoints)), np.empty((len(checkpoints), robot.n_segments))
    sq, n, truth, rss_reference, c = np.zeros(robot.n_segments), 0, {}, float("nan"), 0
    limit = threadpool_limits(limits=1, user_api="blas")
    try:
        for f in progress_bar(range(frames), desc="soak", progress=progress, mininterval=1.0):
            observations, truth[f] = stream.next_frame()
            start, start_cpu = time.perf_counter(), time.thread_time()
            smoother.update(observations)
            cpu[f], wall[f] = time.thread_time() - start_cpu, time.perf_counter() - start
            for done in smoother.pop_final():
                sq += (done.thetas - truth.pop(done.frame)) ** 2
                n += 1
            if f + 1 == MEMORY_REFERENCE:
                rss_reference = resident_set_size()
            if f + 1 == checkpoints[c]:
                rss[c], block_rms[c] = resident_set_size(), np.sqrt(sq / max(n, 1))
                if progress:  # a long run shows its figures as it goes
                    block = slice(0 if c == 0 else checkpoints[c - 1], f + 1)
                    tqdm.write(f"  {f + 1:>7,} frames: RSS {rss[c] / 1024**2:.1f} MB, median "
                               f"update {1e3 * np.median(wall[block]):.1f} ms (CPU "
                               f"{1e3 * np.median(cpu[block]):.1f} ms), RMS "
                               + " ".join(f"{v:.3f}" for v in np.degrees(block_rms[c])) + " deg")
                sq, n, c = np.zeros(robot.n_segments), 0, c + 1
    finally:
        limit.restore_original_limits()
    sigma = reference_bound(seed) if bound else np.full(robot.n_segments, np.nan)
    return SoakBenchmark(frames, checkpoints, rss, wall, cpu, block_rms, sigma,
                         rss_reference, smoother.recoveries)


def format_soak(r: SoakBenchmark) -> str:
    """The benchmark's table and targets."""
    mb = 1024.0**2
    edges = [0, *r.checkpoints.tolist()]
    deg = np.degrees
    out = [f"soak: the default smoother over {r.frames:,} frames generated on the fly "
           "(3 segments, 1 px, 10% outliers, lag 1 s)", "",
           f"{'frames':>15} {'RSS MB':>8} {'update ms':>10} {'CPU ms':>8}   RMS per segment "
           "(deg)"]
    for c, end in enumerate(r.checkpoints.tolist()):
        block = slice(edges[c], end)
        rms = " ".join(f"{v:6.3f}" for v in deg(r.block_rms[c]))
        out.append(f"{edges[c]:>7,}-{end:<7,} {r.rss[c] / mb:8.1f} "
                   f"{1e3 * np.median(r.wall[block]):10.1f} {1e3 * np.median(r.cpu[block]):8.1f}"
                   f"   {rms}")
    out.append(f"{'bound':>15} {'':8} {'':10} {'':8}   "
               + " ".join(f"{v:6.3f}" for v in deg(r.bound))
               + "   (fixed-lag Cramer-Rao bound of the images, 600 frames of the same scenario)")
    out += ["", f"gtsam failures recovered from: {r.recoveries}"]
    if math.isfinite(r.rss_reference):
        ratio = r.memory_ratio
        out.append(f"memory: {r.rss[-1] / mb:.1f} MB after {r.frames:,} frames, "
                   f"{r.rss_reference / mb:.1f} MB after {MEMORY_REFERENCE:,}: ratio {ratio:.3f} "
                   f"(target <= 1.10: {'met' if ratio <= 1.10 else 'NOT met'})")
    for label, times in (("CPU time", r.cpu), ("wall clock", r.wall)):
        ratio = r.median_ratio(times)
        out.append(f"speed ({label}): median update {1e3 * np.median(times[-1000:]):.1f} ms "
                   f"over the last 1,000 frames, {1e3 * np.median(times[1000:2000]):.1f} ms over "
                   f"frames 1,000-2,000: ratio {ratio:.3f} "
                   f"(target <= 1.2: {'met' if ratio <= 1.2 else 'NOT met'})")
    return "\n".join(out)
