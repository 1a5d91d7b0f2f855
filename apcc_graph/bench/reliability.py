"""``apcc-graph bench reliability``: the default smoother under faults, over several seeds.

Scenario: the three-segment robot, a simulated scene (the room by default), 1 px noise, 10%
outliers, 30 fps, ``frames`` frames; the fault starts at ``frames / 3``. Each fault is injected
into the same seed's recording (:mod:`apcc_graph.simulation.faults`), so the undisturbed run is
its peer. Every fault that hides the tracks for a while (a camera or all of them blind, the
recording paused while the robot moves on) comes twice: the tracks come back under new ids (a
tracker that lost them) and re-identified (the points tracked when the images stopped come back
under their old tracks' ids: :func:`~apcc_graph.simulation.faults.blind`'s ``keep_ids``).

The sweep (:mod:`apcc_graph.bench.reliability_sweep`) runs every fault on every seed and holds
each row to its target on every seed:

- a fault that hides the tracks: over the frames from 2 s after the tracks return, the RMS error
  per segment within twice the undisturbed run's over the same frames, or at most the
  Cramer-Rao bound of a 1 s lag there (where the fault left less in the images than that); and
  never more than 5 deg off on any frame once the tracks are back;
- a camera that never sees: RMS within twice the batch's on the same recording, segments 2 and
  3 (the segments that camera's absence weakens);
- every other fault: recovery within 30 frames (below).

One seed's rows are kept in full (:class:`FaultRun`, :func:`format_reliability`):

- what the estimator did: its warnings and the statuses of the faulty frames;
- the RMS error per segment beside the Cramer-Rao bound of the faulted recording itself (every
  observation once, each track's point a nuisance; the bound counts the images only, so the
  smoother's motion prior can beat it), both over the frames some camera saw (frames no camera
  saw have no bound: the robot's motion in the dark is anyone's guess);
- recovery: frames after the fault ends until the 10-frame moving RMS is back within 2x the
  undisturbed run's error over the same frames, for good (target: 30;
  :func:`~apcc_graph.evaluation.recovery.recovery_frames`). A fault that changes the motion
  (the robot frozen, the jump) is simulated anew: it is compared with the undisturbed error
  level, the larger of the undisturbed RMS and the bound;
- the yardstick of that target: the Cramer-Rao bound of a 1 s lag, 30 frames after the fault
  ends (:func:`~apcc_graph.evaluation.sequence_bound.lag_bound`), beside the same bound of the
  undisturbed recording: where the fault raised it more than twice, the row says so;
- sigma honesty: the mean of ``(error / sigma)^2`` and the share within 3 sigma.

A paused recording's frames are compared with the undisturbed frames of the same instants.
"""

from __future__ import annotations

import functools
import math
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from threadpoolctl import threadpool_limits

from apcc_graph.bench.smoother import FPS, N_POINTS, NOISE_PX, ROBOT_FILE, THETA0_SIGMA
from apcc_graph.estimation.methods import estimate
from apcc_graph.estimation.options import GraphOptions
from apcc_graph.evaluation.recovery import recovery_frames, sigma_honesty
from apcc_graph.evaluation.sequence_bound import lag_bound, sequence_bound
from apcc_graph.io.robot_file import load_robot
from apcc_graph.model.arrays import FloatArray, IntArray, rms
from apcc_graph.model.robot import Robot
from apcc_graph.simulation import faults
from apcc_graph.simulation.simulator import SCENES, Simulation, simulate

OUTLIERS = 0.1
SECOND = int(FPS)
AFTER = 30
"""Frames after a fault ends by which the smoother should be back (the recovery target)."""
SETTLE = 2 * SECOND
"""Frames after the tracks return from which a fault that hid them is held to its target."""
FACTOR = 2.0
"""The targets' factor: over the undisturbed error (faults that hide the tracks) and over the
batch (a camera that never sees)."""
MAX_OFF = math.radians(5.0)
"""The largest error allowed on any frame once the tracks are back (radians)."""
PAUSE = 45
"""Frames the pause drops (1.5 s at 30 fps), from the frame where the faults start."""
PAUSE_STEP = 10
"""Lag bounds over many frames are sampled every this many frames."""
SCENE_POINTS = {"room": N_POINTS, "points": 2700}
"""Scene points per scene (:func:`~apcc_graph.simulation.simulator.simulate`'s ``scene``)."""
NEVER = "camera 2 never sees anything"
"""The row held to the batch."""
PAUSED = f"paused for {PAUSE / FPS:.1f} s"
"""The pause's row (frames never received while the robot moved on)."""
KEPT = ", ids kept"
"""Suffix of the rows whose returning tracks keep their ids."""
SEEDS = (1, 2, 3, 4, 5)
"""The default seeds of the sweep."""


@dataclass(frozen=True)
class FaultCase:
    """A recording with a fault: the simulation, the start given to the estimator, and the
    faulty frames ``start .. stop - 1`` (recovery is counted from ``stop``); ``resimulated``:
    the fault changed the motion, so the recording was simulated anew with noise of its own
    (recovery then compares with the undisturbed error level, not with its frames); ``hides``:
    the fault hid the tracks, which return at ``stop`` (the return targets apply);
    ``clean_frames``: each frame's index in the undisturbed recording (``None``: the same
    frames; a pause drops some)."""

    name: str
    simulation: Simulation
    theta0: FloatArray
    start: int
    stop: int
    resimulated: bool = False
    hides: bool = False
    clean_frames: IntArray | None = None

    def undisturbed(self, errors: FloatArray) -> FloatArray:
        """The undisturbed run's ``errors`` at this recording's frames."""
        return errors if self.clean_frames is None else errors[self.clean_frames]


def _simulate(robot: Robot, frames: int, seed: int, scene: str,
              bends: FloatArray | None = None) -> Simulation:
    return simulate(robot, frames, noise_px=NOISE_PX, outlier_fraction=OUTLIERS, seed=seed,
                    fps=FPS, scene=scene, n_points=SCENE_POINTS[scene], bends=bends)


def fault_cases(frames: int = 450, seed: int = 1, scene: str = "room") -> list[FaultCase]:
    """The undisturbed recording and every fault of the benchmark, in table order."""
    if scene not in SCENE_POINTS:
        raise ValueError(f"scene = {scene!r}: expected one of {SCENES}")
    robot = load_robot(ROBOT_FILE)
    clean = _simulate(robot, frames, seed, scene)
    truth = clean.sequence.thetas
    assert truth is not None
    at = frames // 3
    hold = min(5 * SECOND, frames - at - SECOND)
    theta_max = robot.segments[1].theta_max
    every = list(clean.sequence.tracks)
    made: list[tuple[str, Callable[[], Simulation], int, int]] = [
        ("none", lambda: clean, at, at)]
    for name, cams, seconds in (("camera 2 blind for 1 s", [1], 1),
                                ("camera 3 blind for 3 s", [2], 3),
                                ("all cameras blind for 1 s", every, 1)):
        stop = at + seconds * SECOND
        made += [(name, functools.partial(faults.blind, clean, cams, at, stop), at, stop),
                 (name + KEPT, functools.partial(faults.blind, clean, cams, at, stop, True),
                  at, stop)]
    made += [
        (NEVER, lambda: faults.without_camera(clean, 1), 0, frames),
        (f"robot frozen for {hold / FPS:.0f} s", lambda: _simulate(
            robot, frames, seed, scene, faults.frozen_bends(truth, at, hold)), at, at + hold),
        ("segment 2 jumps 10 deg in one frame", lambda: _simulate(
            robot, frames, seed, scene, faults.jumped_bends(truth, at, 1, 10.0, theta_max)),
         at, at),
        ("camera 2: ids swapped for 10 frames", lambda: faults.swapped_ids(
            clean, 1, at, at + 10, 0.2, seed), at, at + 10),
        ("camera 2: 50% outliers for 1 s", lambda: faults.outlier_burst(
            clean, 1, at, at + SECOND, 0.5, seed), at, at + SECOND),
    ]
    hides = {name for name, _, _, _ in made if "blind" in name}
    cases = [FaultCase(name, make(), truth[0], a, b, name.startswith(("robot", "segment")),
                       name in hides) for name, make, a, b in made]
    # the pause: frames at .. at + PAUSE - 1 never received while the robot moved on; the
    # tracks return at frame ``at`` of the paused recording, under new ids or re-identified
    dropped = np.r_[0:at, at + PAUSE:frames]
    cases += [FaultCase(name, faults.paused(faults.blind(clean, every, at, at + PAUSE, kept),
                                            at, at + PAUSE),
                        truth[0], at, at, hides=True, clean_frames=dropped)
              for name, kept in ((PAUSED, False), (PAUSED + KEPT, True))]
    return [*cases, FaultCase("start 5 deg off", clean, truth[0] + math.radians(5.0), 0, 0)]


def _seen(sim: Simulation) -> np.ndarray:
    """``(F,)`` whether some camera saw the frame."""
    seen = np.zeros(sim.sequence.n_frames, dtype=bool)
    for t in sim.sequence.tracks.values():
        seen[t.frames] = True
    return seen


@dataclass(frozen=True)
class PauseRun:
    """The pause's smoother beside the batch: RMS per segment over every frame after the pause
    (radians), and the yardsticks over the same frames."""

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


@dataclass(frozen=True)
class CaseRun:
    """What the smoother did on one case of one seed (angles in radians): its errors, sigmas
    and the statuses of the faulty frames, its warnings (``"Category: message"``) and their
    summary; the batch's RMS per segment on the same recording (the row held to the batch
    only); the bound of a 1 s lag over the frames from :data:`SETTLE` after the tracks return,
    every :data:`PAUSE_STEP`-th (faults that hide the tracks only); the whole recording's bound
    (when asked for, and for recordings simulated anew); the bound of a 1 s lag :data:`AFTER`
    frames after the fault ends and the undisturbed recording's at the same instant (when asked
    for); and, when asked for, on the pause whose tracks keep their ids, the smoother beside the
    batch after the pause."""

    seed: int
    name: str
    errors: FloatArray
    sigmas: FloatArray
    did: str
    warnings: tuple[str, ...] = ()
    batch: FloatArray | None = None
    lag_return: FloatArray | None = None
    bound: FloatArray | None = None
    lag_after: FloatArray | None = None
    lag_clean: FloatArray | None = None
    pause: PauseRun | None = None


def _estimate(case: FaultCase, graph: GraphOptions | None, method: str = "smoother"
              ) -> tuple[FloatArray, FloatArray, np.ndarray, list[warnings.WarningMessage]]:
    """``method`` on the case: its errors, sigmas, statuses and the warnings it gave."""
    seq = case.simulation.sequence
    assert seq.thetas is not None
    with warnings.catch_warnings(record=True) as caught, \
            threadpool_limits(limits=1, user_api="blas"):
        warnings.simplefilter("always")
        result = estimate(seq, method=method, theta0=case.theta0, theta0_sigma=THETA0_SIGMA,
                          noise_px=NOISE_PX, graph=graph, progress=False)
    return result.errors(seq.thetas), result.sigmas, result.status, caught


def _lag(sim: Simulation, frames: Sequence[int]) -> FloatArray:
    """``(S,)`` RMS over ``frames`` of the bound of a 1 s lag."""
    with threadpool_limits(limits=1, user_api="blas"):
        return rms(lag_bound(sim, NOISE_PX, SECOND, THETA0_SIGMA, frames=frames).sigmas)


def run_one(case: FaultCase, clean: Simulation, seed: int = 1,
            model_sigma: tuple[float, float] | None = None, bounds: bool = False) -> CaseRun:
    """The smoother on one case (with ``model_sigma``, model error as noise:
    ``GraphOptions(model_sigma=...)``), and whatever its row's target needs besides; with
    ``bounds``, the yardsticks of the one-seed table too. ``clean``: the undisturbed
    recording."""
    graph = None if model_sigma is None else GraphOptions(model_sigma=model_sigma)
    errors, sigmas, status, caught = _estimate(case, graph)
    sim = case.simulation
    n = sim.sequence.n_frames
    batch = lag_return = bound = lag_after = lag_clean = pause = None
    if case.name == NEVER:
        batch = rms(_estimate(case, graph, "batch")[0][_seen(sim)])
    if case.hides and case.stop + SETTLE < n:
        lag_return = _lag(sim, range(case.stop + SETTLE, n, PAUSE_STEP))
    if bounds or case.resimulated:
        with threadpool_limits(limits=1, user_api="blas"):
            sigmas_bound = sequence_bound(sim, NOISE_PX, THETA0_SIGMA).sigmas
        bound = rms(sigmas_bound[np.all(np.isfinite(sigmas_bound), axis=1)])
        if bounds and case.name == PAUSED + KEPT:
            at = case.stop
            warned = any("paused for" in str(w.message) for w in caught)
            pause = PauseRun(PAUSE, at, rms(errors[at:]),
                             rms(_estimate(case, graph, "batch")[0][at:]), warned,
                             rms(sigmas_bound[at:]), _lag(sim, range(at, n, PAUSE_STEP)))
    if bounds and case.name != "none" and case.stop + AFTER < n:
        at = case.stop + AFTER
        lag_after = _lag(sim, [at])
        lag_clean = _lag(clean, [at if case.clean_frames is None
                                 else int(case.clean_frames[at])])
    said = tuple(f"{w.category.__name__}: {w.message}" for w in caught)
    return CaseRun(seed, case.name, errors, sigmas,
                   _what_it_did(caught, status[case.start:case.stop]), said, batch,
                   lag_return, bound, lag_after, lag_clean, pause)


@dataclass(frozen=True)
class FaultRun:
    """One row of the one-seed table (angles in radians)."""

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


def _recovery(case: FaultCase, run: CaseRun, undisturbed: FloatArray | None) -> int | None:
    """Frames after the fault until the error is back within twice the undisturbed one for
    good (``None``: never, or nothing to recover from)."""
    if undisturbed is None or case.stop >= case.simulation.sequence.n_frames:
        return None
    # a recording simulated anew has noise of its own: its windows are compared with the
    # undisturbed error level, the larger of that run's RMS and the bound (one run's RMS
    # can fall far below the error to expect, by chance)
    level = None
    if case.resimulated:
        level = rms(undisturbed) if run.bound is None else np.maximum(rms(undisturbed),
                                                                       run.bound)
    return recovery_frames(run.errors, case.undisturbed(undisturbed), case.stop, level=level)


def fault_run(case: FaultCase, run: CaseRun, undisturbed: FloatArray | None = None) -> FaultRun:
    """The one-seed row of ``run`` (``undisturbed``: the undisturbed run's errors, for the
    recovery; ``None`` for the undisturbed run itself)."""
    z2, inside = sigma_honesty(run.errors, run.sigmas)
    ends = undisturbed is not None and case.stop < case.simulation.sequence.n_frames
    nan = np.full(run.errors.shape[1], np.nan)
    return FaultRun(case.name, run.did, rms(run.errors[_seen(case.simulation)]),
                    nan if run.bound is None else run.bound, _recovery(case, run, undisturbed),
                    float(np.nanmax(z2)), float(np.nanmin(inside)), run.warnings, ends,
                    run.lag_after, run.lag_clean)


def run_case(case: FaultCase, undisturbed: FloatArray | None = None,
             clean: Simulation | None = None) -> tuple[FaultRun, FloatArray]:
    """Run the default smoother on one case; the one-seed row (with its bounds) and the
    ``(F, S)`` errors.

    ``undisturbed``: the errors of the undisturbed run, for the recovery time; ``clean``: the
    undisturbed recording, for the lag bound beside the faulted one's."""
    run = run_one(case, case.simulation if clean is None else clean, bounds=True)
    row = fault_run(case, run, undisturbed)
    if clean is None:  # no undisturbed peer: no lag bound beside it
        row = FaultRun(row.name, row.did, row.rms, row.bound, row.recovery, row.z2,
                       row.within_3_sigma, row.warnings, row.ends)
    return row, run.errors


def _what_it_did(caught: list[warnings.WarningMessage], status: np.ndarray) -> str:
    """The warnings (first words) and the statuses of the faulty frames (how many frames
    have each on some segment)."""
    said = [" ".join(str(w.message).split()[:8]) + " ..." for w in caught]
    kinds = [k for k in np.unique(status).tolist() if k != "ok"]  # frames with each
    shown = ", ".join(f"{k} x{int(np.any(status == k, axis=1).sum())}" for k in kinds)
    return "; ".join([*(f"warned: {s}" for s in said), *([shown] if shown else [])]) or "-"


def _deg(values: FloatArray | None, width: int = 6) -> str:
    """Angles (radians) in degrees, three decimals below 10 deg, one above."""
    if values is None:
        return "-"
    return " ".join(f"{v:{width}.3f}" if abs(v) < 10.0 else f"{v:{width}.1f}"
                    for v in np.degrees(values))


def format_reliability(rows: list[FaultRun], frames: int, pause: PauseRun | None = None
                       ) -> str:
    """One seed's table (and the pause's line beside the batch, if given)."""
    deg = np.degrees
    width = max([len(r.name) for r in rows] + [38])
    out = [f"reliability: the default smoother (lag 1 s), {frames} frames, fault from frame "
           f"{frames // 3}; RMS and its Cramer-Rao bound per segment over the frames some "
           "camera saw (deg)", "",
           f"{'fault':<{width}} {'RMS':>20} {'bound':>20} {'recovery':>9} "
           f"{f'lag bound +{AFTER}':>16} {'(e/s)^2':>8} {'<3 sigma':>8}  what the estimator did"]
    for r in rows:
        rec = "-" if r.name == "none" or not r.ends else (
            "never" if r.recovery is None else f"{r.recovery} fr")
        lagged = "-" if r.lag_after is None or r.lag_clean is None else (
            " ".join(f"{v:4.1f}" for v in r.lag_after / r.lag_clean)
            + ("*" if r.beyond_bound else " "))
        out.append(f"{r.name:<{width}} {' '.join(f'{v:6.3f}' for v in deg(r.rms)):>20} "
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
