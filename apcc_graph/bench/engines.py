"""The compiled kernels against their numpy reference, and the reproducible window against
gtsam's fixed-lag smoother, timed in the same run.

``apcc-graph bench smoother`` reports the smoother's update time and the batch's seconds; this
module gives both their peer: the same estimator on the same recording with the numpy
reference of the projection model's hot loops (:mod:`apcc_graph.factors.engine`), so the
speed-up is measured, not remembered. The kernels are the same steps to rounding, so the
batches agree to rounding; the smoothers can differ by a little more (about 1e-3 degree), as
rounding tips some of iSAM2's re-linearisation decisions. The largest difference is reported.

The window's peer: the same smoother with gtsam's ``IncrementalFixedLagSmoother`` holding its
window (``WindowOptions(reproducible=False)``), which marginalises at every update and is
not reproducible (:mod:`apcc_graph.estimation.smoother.fixed_lag`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np

from apcc_graph.estimation.batch import batch_estimate
from apcc_graph.estimation.smoother import FixedLagSmoother
from apcc_graph.estimation.smoother_options import SmootherOptions
from apcc_graph.factors.engine import ENGINES, use_engine
from apcc_graph.io.console import progress_bar
from apcc_graph.model.sequence import Sequence


@dataclass(frozen=True)
class EngineTimes:
    """One engine's times on the peer recording."""

    engine: str
    update_median: float  # seconds per smoother update
    update_p95: float
    batch_seconds: float
    smoother_thetas: np.ndarray  # (F, S) final smoother angles (radians)
    batch_thetas: np.ndarray  # (F, S)


def _smoother_times(sequence: Sequence, settings: SmootherOptions, progress: bool,
                    label: str) -> tuple[np.ndarray, np.ndarray]:
    assert sequence.thetas is not None
    smoother = FixedLagSmoother(sequence.robot, lag=1.0, theta0=sequence.thetas[0],
                                settings=settings)
    times = np.empty(sequence.n_frames)
    for f in progress_bar(range(sequence.n_frames), desc=label, progress=progress, leave=False):
        start = time.perf_counter()
        smoother.update(sequence.frame(f))
        times[f] = time.perf_counter() - start
    return times, np.array([fr.thetas for fr in smoother.finish()])


def engine_times(sequence: Sequence, settings: SmootherOptions, progress: bool = False
                 ) -> list[EngineTimes]:
    """The smoother's update times and the batch's seconds on ``sequence`` with each engine
    (compiled first), each started at the true first frame."""
    assert sequence.thetas is not None
    out = []
    for engine in ENGINES:
        with use_engine(engine):
            times, smoothed = _smoother_times(sequence, settings, progress,
                                              f"smoother ({engine})")
            start = time.perf_counter()
            batch = batch_estimate(sequence, theta0=sequence.thetas[0], progress=progress)
            seconds = time.perf_counter() - start
        out.append(EngineTimes(engine, float(np.median(times)),
                               float(np.percentile(times, 95)), seconds, smoothed,
                               batch.thetas))
    return out


def format_engine_times(rows: list[EngineTimes], frames: int) -> list[str]:
    """The comparison's lines for the benchmark's table."""
    compiled, reference = rows[0], rows[-1]
    deg = np.degrees
    lines = [f"  compiled kernels against the numpy reference, {frames} frames, one recording:",
             f"  {'engine':<8} {'update median':>14} {'update p95':>11} {'batch':>8}"]
    for r in rows:
        lines.append(f"  {r.engine:<8} {r.update_median * 1e3:11.2f} ms {r.update_p95 * 1e3:8.2f}"
                     f" ms {r.batch_seconds:6.1f} s")
    lines.append(
        f"  speed-up: update {reference.update_median / compiled.update_median:.2f}x, batch "
        f"{reference.batch_seconds / compiled.batch_seconds:.2f}x; largest angle difference "
        f"smoother {deg(np.max(np.abs(compiled.smoother_thetas - reference.smoother_thetas))):.1e}"
        f" deg, batch {deg(np.max(np.abs(compiled.batch_thetas - reference.batch_thetas))):.1e}"
        " deg")
    return lines


@dataclass(frozen=True)
class WindowTimes:
    """The smoother's update times with one window solver, on the peer recording."""

    window: str
    update_median: float  # seconds
    update_p95: float
    thetas: np.ndarray  # (F, S) final angles (radians)


WINDOWS = {"reproducible": True, "gtsam": False}
"""The window solvers compared: label -> ``SmootherOptions.window.reproducible``."""


def window_times(sequence: Sequence, settings: SmootherOptions, progress: bool = False
                 ) -> list[WindowTimes]:
    """The compiled smoother's update times on ``sequence`` with each window solver."""
    out = []
    for label, reproducible in WINDOWS.items():
        solver = replace(settings, window=replace(settings.window, reproducible=reproducible))
        times, thetas = _smoother_times(sequence, solver, progress, f"smoother ({label} window)")
        out.append(WindowTimes(label, float(np.median(times)),
                               float(np.percentile(times, 95)), thetas))
    return out


def format_window_times(rows: list[WindowTimes]) -> list[str]:
    """The comparison's lines for the benchmark's table."""
    ours, peer = rows[0], rows[-1]
    lines = ["  the window: reproducible (ours) against gtsam's IncrementalFixedLagSmoother:",
             f"  {'window':<13} {'update median':>14} {'update p95':>11}"]
    for r in rows:
        lines.append(f"  {r.window:<13} {r.update_median * 1e3:11.2f} ms "
                     f"{r.update_p95 * 1e3:8.2f} ms")
    diff = np.degrees(np.max(np.abs(ours.thetas - peer.thetas)))
    lines.append(f"  ours / gtsam's: update median {ours.update_median / peer.update_median:.2f}"
                 f"x, p95 {ours.update_p95 / peer.update_p95:.2f}x; largest angle difference "
                 f"{diff:.1e} deg")
    return lines
