"""``apcc-graph bench reliability``: the default smoother under faults, one row per fault.

Scenario: the three-segment robot, the room scene, 1 px noise, 10% outliers, 30 fps,
``frames`` frames; the fault starts at ``frames / 3``. Each fault is injected into the same
seed's recording (:mod:`apcc_graph.simulation.faults`), so the undisturbed run is its peer.
Every row gives:

- what the estimator did: its warnings and the statuses of the faulty frames;
- the RMS error per segment beside the Cramer-Rao bound of the faulted recording itself (every
  observation once, each track's point a nuisance; the bound counts the images only, so the
  smoother's motion prior can beat it), both over the frames some camera saw (frames no camera
  saw have no bound: the robot's motion in the dark is anyone's guess);
- recovery: frames after the fault ends until the 10-frame moving RMS is back within 2x the
  undisturbed run's error over the same frames, for good (target: 30;
  :func:`~apcc_graph.evaluation.recovery.recovery_frames`). A fault that changes the motion
  (the robot frozen, the jump) is a recording simulated anew, with noise of its own: its
  windows are compared with the undisturbed error level, the larger of the undisturbed RMS and
  the bound;
- the yardstick of that target: the Cramer-Rao bound of a 1 s lag, 30 frames after the fault
  ends (:func:`~apcc_graph.evaluation.sequence_bound.lag_bound`), beside the same bound of the
  undisturbed recording at that frame. Where the fault raised it more than twice, being back
  within twice the undisturbed error by then asks more than the images allow, and the row says
  so (the bound counts the images only: the undisturbed smoother, with its motion and start
  priors, can be below it);
- sigma honesty: the mean of ``(error / sigma)^2`` (1 when honest) and the share of errors
  within 3 sigma, worst segment.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from threadpoolctl import threadpool_limits

from apcc_graph.bench.smoother import FPS, N_POINTS, NOISE_PX, ROBOT_FILE, THETA0_SIGMA
from apcc_graph.estimation.methods import estimate
from apcc_graph.evaluation.recovery import recovery_frames, sigma_honesty
from apcc_graph.evaluation.sequence_bound import lag_bound, sequence_bound
from apcc_graph.io.console import progress_bar
from apcc_graph.io.robot_file import load_robot
from apcc_graph.model.arrays import FloatArray, rms
from apcc_graph.model.robot import Robot
from apcc_graph.simulation import faults
from apcc_graph.simulation.simulator import Simulation, simulate

OUTLIERS = 0.1
SECOND = int(FPS)
AFTER = 30
"""Frames after a fault ends by which the smoother should be back (the recovery target)."""


@dataclass(frozen=True)
class FaultCase:
    """A recording with a fault: the simulation, the start given to the estimator, and the
    faulty frames ``start .. stop - 1`` (recovery is counted from ``stop``); ``resimulated``:
    the fault changed the motion, so the recording was simulated anew with noise of its own
    (recovery then compares with the undisturbed error level, not with its frames)."""

    name: str
    simulation: Simulation
    theta0: FloatArray
    start: int
    stop: int
    resimulated: bool = False


def _simulate(robot: Robot, frames: int, seed: int, bends: FloatArray | None = None
              ) -> Simulation:
    return simulate(robot, frames, noise_px=NOISE_PX, outlier_fraction=OUTLIERS, seed=seed,
                    fps=FPS, scene="room", n_points=N_POINTS, bends=bends)


def fault_cases(frames: int = 450, seed: int = 1) -> list[FaultCase]:
    """The undisturbed recording and every fault of the benchmark, in table order."""
    robot = load_robot(ROBOT_FILE)
    clean = _simulate(robot, frames, seed)
    truth = clean.sequence.thetas
    assert truth is not None
    at = frames // 3
    hold = min(5 * SECOND, frames - at - SECOND)
    theta_max = robot.segments[1].theta_max
    made: list[tuple[str, Callable[[], Simulation], int, int]] = [
        ("none", lambda: clean, at, at),
        ("camera 2 blind for 1 s", lambda: faults.blind(clean, [1], at, at + SECOND),
         at, at + SECOND),
        ("camera 3 blind for 3 s", lambda: faults.blind(clean, [2], at, at + 3 * SECOND),
         at, at + 3 * SECOND),
        ("all cameras blind for 1 s", lambda: faults.blind(clean, [0, 1, 2], at, at + SECOND),
         at, at + SECOND),
        ("camera 2 never sees anything", lambda: faults.without_camera(clean, 1), 0, frames),
        (f"robot frozen for {hold / FPS:.0f} s", lambda: _simulate(
            robot, frames, seed, faults.frozen_bends(truth, at, hold)), at, at + hold),
        ("segment 2 jumps 10 deg in one frame", lambda: _simulate(
            robot, frames, seed, faults.jumped_bends(truth, at, 1, 10.0, theta_max)), at, at),
        ("camera 2: ids swapped for 10 frames", lambda: faults.swapped_ids(
            clean, 1, at, at + 10, 0.2, seed), at, at + 10),
        ("camera 2: 50% outliers for 1 s", lambda: faults.outlier_burst(
            clean, 1, at, at + SECOND, 0.5, seed), at, at + SECOND),
    ]
    cases = [FaultCase(name, make(), truth[0], a, b, name.startswith(("robot", "segment")))
             for name, make, a, b in made]
    return [*cases, FaultCase("start 5 deg off", clean, truth[0] + math.radians(5.0), 0, 0)]


@dataclass(frozen=True)
class FaultRun:
    """One row of the benchmark (angles in radians)."""

    name: str
    did: str
    rms: FloatArray  # (S,) over the frames some camera saw
    bound: FloatArray  # (S,) RMS of the per-frame bound over the frames a camera saw
    recovery: int | None
    z2: float  # worst segment's mean (error / sigma)^2
    within_3_sigma: float  # worst segment's share of errors within 3 sigma
    warnings: tuple[str, ...] = ()  # "Category: message" of each warning the run gave
    ends: bool = True  # the fault ends before the recording does (else no recovery to count)
    lag_after: FloatArray | None = None  # (S,) bound of a 1 s lag AFTER frames after the end
    lag_clean: FloatArray | None = None  # (S,) the same of the undisturbed recording

    @property
    def beyond_bound(self) -> bool:
        """Whether the fault raised the 1 s lag bound, :data:`AFTER` frames after its end,
        more than twice on some segment: back within twice the undisturbed error by then asks
        more than the images allow."""
        return (self.lag_after is not None and self.lag_clean is not None
                and bool(np.any(self.lag_after > 2.0 * self.lag_clean)))


def run_case(case: FaultCase, undisturbed: FloatArray | None = None,
             clean: Simulation | None = None) -> tuple[FaultRun, FloatArray]:
    """Run the default smoother on one case; the row and the ``(F, S)`` errors.

    ``undisturbed``: the errors of the undisturbed run, for the recovery time; ``clean``: the
    undisturbed recording, for the lag bound beside the faulted one's."""
    seq = case.simulation.sequence
    assert seq.thetas is not None
    with warnings.catch_warnings(record=True) as caught, \
            threadpool_limits(limits=1, user_api="blas"):
        warnings.simplefilter("always")
        result = estimate(seq, method="smoother", theta0=case.theta0,
                          theta0_sigma=THETA0_SIGMA, noise_px=NOISE_PX, progress=False)
    errors = result.errors(seq.thetas)
    sigmas = sequence_bound(case.simulation, NOISE_PX, THETA0_SIGMA).sigmas
    seen = np.all(np.isfinite(sigmas), axis=1)
    z2, inside = sigma_honesty(errors, result.sigmas)
    ends = undisturbed is not None and case.stop < seq.n_frames
    recovery, bound = None, rms(sigmas[seen])
    if ends and undisturbed is not None:
        # a recording simulated anew has noise of its own: its windows are compared with the
        # undisturbed error level, the larger of that run's RMS and the bound (one run's RMS
        # can fall far below the error to expect, by chance)
        level = np.maximum(rms(undisturbed), bound) if case.resimulated else None
        recovery = recovery_frames(errors, undisturbed, case.stop, level=level)
    said = tuple(f"{w.category.__name__}: {w.message}" for w in caught)
    lag_after = lag_clean = None
    if ends and clean is not None and case.stop + AFTER < seq.n_frames:
        lag_after, lag_clean = (lag_bound(sim, NOISE_PX, SECOND, THETA0_SIGMA,
                                          frames=[case.stop + AFTER]).sigmas[0]
                                for sim in (case.simulation, clean))
    return FaultRun(case.name, _what_it_did(caught, result.status[case.start:case.stop]),
                    rms(errors[seen]), bound, recovery, float(np.nanmax(z2)),
                    float(np.nanmin(inside)), said, ends, lag_after, lag_clean), errors


PAUSE = 45
"""Frames the pause drops (1.5 s at 30 fps), from the frame where the faults start."""


@dataclass(frozen=True)
class PauseRun:
    """The pause's row: RMS per segment over every frame after the pause (radians), and the
    yardsticks over the same frames."""

    frames: int  # frames dropped
    at: int  # the first frame after the pause (in the paused recording)
    smoother: FloatArray
    batch: FloatArray
    warned: bool  # the smoother said it re-acquires
    bound: FloatArray | None = None  # the whole recording's bound: the batch's yardstick
    lag: FloatArray | None = None  # a 1 s lag's bound (every PAUSE_STEP-th frame)

    @property
    def ratio(self) -> FloatArray:
        """The smoother over the batch on the same frames (the target is 1.5)."""
        return self.smoother / self.batch


PAUSE_STEP = 10
"""The pause's lag bound is sampled every this many frames after it."""


def run_pause(frames: int = 450, seed: int = 1) -> PauseRun:
    """The undisturbed recording paused for :data:`PAUSE` frames from frame ``frames // 3``
    while the robot moved on; the default smoother and the batch on it, and the bounds of the
    whole recording and of a 1 s lag over the frames after the pause."""
    at = frames // 3
    sim = faults.paused(_simulate(load_robot(ROBOT_FILE), frames, seed), at, at + PAUSE)
    sequence = sim.sequence
    assert sequence.thetas is not None
    out = []
    with warnings.catch_warnings(record=True) as caught, \
            threadpool_limits(limits=1, user_api="blas"):
        warnings.simplefilter("always")
        for method in ("smoother", "batch"):
            result = estimate(sequence, method=method, theta0=sequence.thetas[0],
                              theta0_sigma=THETA0_SIGMA, noise_px=NOISE_PX, progress=False)
            out.append(rms(result.errors(sequence.thetas)[at:]))
        bound = rms(sequence_bound(sim, NOISE_PX, THETA0_SIGMA).sigmas[at:])
        lag = rms(lag_bound(sim, NOISE_PX, SECOND, THETA0_SIGMA,
                            frames=range(at, sequence.n_frames, PAUSE_STEP)).sigmas)
    warned = any("paused for" in str(w.message) for w in caught)
    return PauseRun(PAUSE, at, out[0], out[1], warned, bound, lag)


def _what_it_did(caught: list[warnings.WarningMessage], status: np.ndarray) -> str:
    """The warnings (first words) and the statuses of the faulty frames (how many frames
    have each on some segment)."""
    said = [" ".join(str(w.message).split()[:8]) + " ..." for w in caught]
    kinds = [k for k in np.unique(status).tolist() if k != "ok"]  # frames with each
    shown = ", ".join(f"{k} x{int(np.any(status == k, axis=1).sum())}" for k in kinds)
    return "; ".join([*(f"warned: {s}" for s in said), *([shown] if shown else [])]) or "-"


def run_reliability(frames: int = 450, seed: int = 1, progress: bool = False
                    ) -> list[FaultRun]:
    """Every row of the benchmark; the first is the undisturbed run."""
    cases = fault_cases(frames, seed)
    first, clean_errors = run_case(cases[0])
    rows = [first]
    for case in progress_bar(cases[1:], desc="faults", progress=progress):
        rows.append(run_case(case, clean_errors, cases[0].simulation)[0])
    return rows


def format_reliability(rows: list[FaultRun], frames: int, pause: PauseRun | None = None
                       ) -> str:
    """The benchmark's table (and the pause's line, if given)."""
    deg = np.degrees
    out = [f"reliability: the default smoother (lag 1 s), {frames} frames, fault from frame "
           f"{frames // 3}; RMS and its Cramer-Rao bound per segment over the frames some "
           "camera saw (deg)", "",
           f"{'fault':<38} {'RMS':>20} {'bound':>20} {'recovery':>9} "
           f"{f'lag bound +{AFTER}':>16} {'(e/s)^2':>8} {'<3 sigma':>8}  what the estimator did"]
    for r in rows:
        rec = "-" if r.name == "none" or not r.ends else (
            "never" if r.recovery is None else f"{r.recovery} fr")
        lagged = "-" if r.lag_after is None or r.lag_clean is None else (
            " ".join(f"{v:4.1f}" for v in r.lag_after / r.lag_clean)
            + ("*" if r.beyond_bound else " "))
        out.append(f"{r.name:<38} {' '.join(f'{v:6.3f}' for v in deg(r.rms)):>20} "
                   f"{' '.join(f'{v:6.3f}' for v in deg(r.bound)):>20} {rec:>9} "
                   f"{lagged:>16} {r.z2:8.2f} {r.within_3_sigma:8.1%}  {r.did}")
    out += ["", "recovery: frames after the fault ends until the 10-frame moving RMS stays "
            "within 2x the undisturbed run's (target 30; for a recording simulated anew, the",
            "robot frozen and the jump: 2x the larger of the undisturbed RMS and the bound); "
            "(e/s)^2 and <3 sigma: worst segment",
            f"lag bound +{AFTER}: the Cramer-Rao bound of a 1 s lag {AFTER} frames after the "
            "fault ends, over the undisturbed recording's at that frame; * where the fault "
            "more than",
            f"doubled it on some segment (back within twice the undisturbed error {AFTER} "
            "frames after asks more than the images allow)"]
    if pause is not None:
        show = lambda v: " / ".join(f"{x:.3f}" for x in np.degrees(v))  # noqa: E731
        out += ["", f"pause: {pause.frames / FPS:.1f} s of frames dropped before frame "
                f"{pause.at} while the robot moved on "
                f"({'re-acquisition said' if pause.warned else 'nothing said'}); RMS over "
                f"every frame after it: smoother {show(pause.smoother)} deg, the batch on the "
                f"same frames {show(pause.batch)}, ratio "
                + " / ".join(f"{x:.1f}" for x in pause.ratio) + " (target 1.5)"]
        if pause.bound is not None and pause.lag is not None:
            out += [f"  yardsticks over those frames: the whole recording's bound "
                    f"{show(pause.bound)} (the batch's), a 1 s lag's {show(pause.lag)} (the "
                    f"smoother's; every {PAUSE_STEP}th frame); smoother / lag bound "
                    + " / ".join(f"{x:.2f}" for x in pause.smoother / pause.lag)]
    return "\n".join(out)
