"""``apcc-graph bench selfcal``: self-calibration of k and delta_max beside its Cramer-Rao bound.

The scene of ``bench smoother`` (three 0.3 m segments, room scene, 1 px noise, 30 fps, a
0.1 deg start prior). The sequences are simulated with the true segment models; the estimator
is given models whose ``k`` is off by ``dk`` and ``delta_max`` by ``dd`` on every segment. Per
seed, in one run:

- the batch with the true models, with the wrong ones, and with the wrong ones and
  ``calibrate=True`` (priors of ``(0.05, 5 deg)`` around the wrong values; the mounts
  held, ``bench mounts`` calibrates them): RMS error per segment;
- the bound of the angles with the models known, and with them unknown (the same priors):
  :func:`apcc_graph.evaluation.sequence_bound.sequence_bound` with ``calibration_sigmas``, which
  also bounds each k and delta_max;
- the calibrated k and delta_max, their errors, reported sigmas and bound.

A self-calibrating estimator cannot beat the bound with unknown models: the ratio of that bound
to the known-model one is what the sequence itself lets self-calibration cost.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence as SequenceOf
from dataclasses import dataclass

import numpy as np

from apcc_graph.bench import table_cells as _cells
from apcc_graph.bench.smoother import NOISE_PX, ROBOT_FILE, THETA0_SIGMA, room_simulation
from apcc_graph.estimation.batch import batch_estimate
from apcc_graph.evaluation.sequence_bound import sequence_bound
from apcc_graph.io.console import progress_bar
from apcc_graph.io.robot_file import load_robot
from apcc_graph.model.arrays import rms
from apcc_graph.model.robot import Robot
from apcc_graph.model.segment import Segment
from apcc_graph.model.sequence import Sequence

CALIBRATION_SIGMAS = (0.05, math.radians(5.0))


@dataclass(frozen=True)
class SelfCalibrationRun:
    """One seed (angles in radians)."""

    seed: int
    rms_true: np.ndarray  # (S,) batch with the true models
    rms_wrong: np.ndarray  # (S,) batch with the wrong models
    rms_calibrated: np.ndarray  # (S,) batch with the wrong models and calibrate=True
    bound_known: np.ndarray  # (S,) RMS bound, models known
    bound_unknown: np.ndarray  # (S,) RMS bound, models unknown
    truth: np.ndarray  # (S, 2) true k, delta_max
    found: np.ndarray  # (S, 2) calibrated k, delta_max
    sigmas: np.ndarray  # (S, 2) their reported sigmas
    bound: np.ndarray  # (S, 2) their bound
    seconds: float  # the calibrating batch


@dataclass(frozen=True)
class SelfCalibrationBenchmark:
    """Everything :func:`run_self_calibration_benchmark` measured."""

    frames: int
    outliers: float
    dk: float
    dd: float  # radians
    runs: tuple[SelfCalibrationRun, ...]


def wrong_models(robot: Robot, dk: float, dd: float) -> Robot:
    """``robot`` with every segment's k off by ``dk`` and delta_max by ``dd`` (radians)."""
    return Robot([Segment(s.length, s.k + dk, s.delta_max + dd, s.theta_max)
                  for s in robot.segments], robot.cameras)


def run_self_calibration_benchmark(frames: int = 600, seeds: SequenceOf[int] = (1, 2, 3),
                                   outliers: float = 0.1, dk: float = 0.03,
                                   dd: float = math.radians(3.0),
                                   progress: bool = False) -> SelfCalibrationBenchmark:
    """Run the benchmark (see the module docstring)."""
    robot = load_robot(ROBOT_FILE)
    wrong = wrong_models(robot, dk, dd)
    runs = []
    for seed in progress_bar(seeds, desc="selfcal", progress=progress):
        sim = room_simulation(robot, frames, outliers, seed)
        seq = sim.sequence
        assert seq.thetas is not None
        theta0 = seq.thetas[0]
        wseq = Sequence(wrong, seq.timestamps, seq.tracks, seq.world_T_base, None, seq.psis)

        true = batch_estimate(seq, theta0=theta0, marginals=False)
        off = batch_estimate(wseq, theta0=theta0, marginals=False)
        start = time.perf_counter()
        cal = batch_estimate(wseq, theta0=theta0, calibrate=True,
                             calibration_sigmas=CALIBRATION_SIGMAS, mount_sigmas=None)
        seconds = time.perf_counter() - start
        known = sequence_bound(sim, NOISE_PX, THETA0_SIGMA)
        unknown = sequence_bound(sim, NOISE_PX, THETA0_SIGMA,
                                 calibration_sigmas=CALIBRATION_SIGMAS)
        assert unknown.calibration is not None and cal.calibration_sigmas is not None
        runs.append(SelfCalibrationRun(
            seed, rms(true.thetas - seq.thetas), rms(off.thetas - seq.thetas),
            rms(cal.thetas - seq.thetas), known.rms(),
            unknown.rms(), np.array([[s.k, s.delta_max] for s in robot.segments]),
            np.array([[s.k, s.delta_max] for s in cal.robot.segments]),
            cal.calibration_sigmas, unknown.calibration, seconds))
    return SelfCalibrationBenchmark(frames, outliers, dk, dd, tuple(runs))



def format_self_calibration_benchmark(r: SelfCalibrationBenchmark) -> str:
    """The tables ``apcc-graph bench selfcal`` prints."""
    deg = np.degrees
    out = [f"bench selfcal: 3 x 0.3 m segments, room scene, {NOISE_PX:g} px, "
           f"{r.outliers:.0%} outliers, {r.frames} frames; the estimator's models have k "
           f"{r.dk:+g} and delta_max {math.degrees(r.dd):+g} deg on every segment; "
           f"calibration priors k {CALIBRATION_SIGMAS[0]:g}, delta_max "
           f"{math.degrees(CALIBRATION_SIGMAS[1]):g} deg", "",
           "RMS per segment (deg): batch with the true models, the wrong ones, the wrong ones "
           "+ calibrate=True; the bound with the models known and unknown",
           f"  {'seed':>4}  {'true models':>20}  {'wrong models':>20}  {'calibrated':>20}  "
           f"{'bound, known':>20}  {'bound, unknown':>20}  {'seconds':>7}"]
    for run in r.runs:
        out.append(f"  {run.seed:>4}  {_cells(deg(run.rms_true))}  {_cells(deg(run.rms_wrong))}"
                   f"  {_cells(deg(run.rms_calibrated))}  {_cells(deg(run.bound_known))}  "
                   f"{_cells(deg(run.bound_unknown))}  {run.seconds:7.1f}")

    def median(values: list[np.ndarray]) -> str:
        return _cells(np.median(values, axis=0), "6.2f")

    runs = r.runs
    ratios = [("calibrated / true models", [x.rms_calibrated / x.rms_true for x in runs]),
              ("wrong / true models", [x.rms_wrong / x.rms_true for x in runs]),
              ("bound unknown / known models", [x.bound_unknown / x.bound_known for x in runs]),
              ("calibrated / bound, unknown", [x.rms_calibrated / x.bound_unknown for x in runs]),
              ("true models / bound, known", [x.rms_true / x.bound_known for x in runs])]
    out += ["", "median over seeds, per segment"]
    out += [f"  {name:<32} {median(values)}" for name, values in ratios]
    out += ["", "calibration per seed and segment: found (true) +/- reported sigma [bound]"]
    for run in runs:
        for j in range(len(run.truth)):
            k, d = run.found[j]
            out.append(f"  seed {run.seed} segment {j + 1}: k {k:.4f} ({run.truth[j, 0]:.4f}) "
                       f"+/- {run.sigmas[j, 0]:.4f} [{run.bound[j, 0]:.4f}];  delta_max "
                       f"{deg(d):6.3f} ({deg(run.truth[j, 1]):.3f}) +/- "
                       f"{deg(run.sigmas[j, 1]):.3f} [{deg(run.bound[j, 1]):.3f}] deg")
    z = np.array([(x.found - x.truth) / x.bound for x in runs])  # (seeds, S, 2)
    out.append(f"  mean ((found - true) / bound)^2 over seeds, k per segment "
               f"{_cells(np.mean(z[..., 0] ** 2, axis=0), '5.2f')}; delta_max "
               f"{_cells(np.mean(z[..., 1] ** 2, axis=0), '5.2f')}")
    return "\n".join(out)
