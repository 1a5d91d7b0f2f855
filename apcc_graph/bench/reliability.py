"""``apcc-graph bench reliability``: the default smoother under faults, over several seeds.

Scenario: the three-segment robot, a simulated scene (the room by default), 1 px noise, 10%
outliers, 30 fps, ``frames`` frames; the fault starts at ``frames / 3``. Each fault is injected
into the same seed's recording (:mod:`apcc_graph.simulation.faults`), so the undisturbed run is
its peer. Every fault that hides the tracks for a while (a camera or all of them blind, the
recording paused while the robot moves on) comes twice: the tracks come back under new ids (a
tracker that lost them) and re-identified (the points tracked when the images stopped come back
under their old tracks' ids: :func:`~apcc_graph.simulation.faults.blind`'s ``keep_ids``).

The sweep (:func:`run_sweep`, :func:`format_sweep`) runs every fault on every seed and holds
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

A paused recording has fewer frames than the undisturbed one: its frames are compared with the
undisturbed frames of the same instants (:attr:`FaultCase.clean_frames`).
"""

from __future__ import annotations

import functools
import math
import warnings
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from multiprocessing import get_context

import numpy as np
from threadpoolctl import threadpool_limits

from apcc_graph.bench.smoother import FPS, N_POINTS, NOISE_PX, ROBOT_FILE, THETA0_SIGMA
from apcc_graph.estimation.methods import estimate
from apcc_graph.estimation.options import GraphOptions
from apcc_graph.evaluation.recovery import recovery_frames, sigma_honesty
from apcc_graph.evaluation.sequence_bound import lag_bound, sequence_bound
from apcc_graph.io.console import progress_bar
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


@dataclass(frozen=True)
class SeedRow:
    """One fault on one seed, against its target (angles in radians).

    Attributes:
        seed: the simulation seed.
        rms: ``(S,)`` RMS error over the frames some camera saw.
        recovery: frames until back within twice the undisturbed error (``None``: never, or
            nothing to recover from).
        after: ``(S,)`` RMS over the frames from :data:`SETTLE` after the tracks return
            (faults that hide the tracks), else ``None``.
        allowed: ``(S,)`` what ``after`` may be: the larger of twice the undisturbed run's RMS
            over the same frames and the bound of a 1 s lag there.
        back_max: the largest error on any frame and segment once the tracks are back.
        batch: ``(S,)`` the batch's RMS on the same recording (the camera that never sees).
        target: which target holds the row: ``"return"``, ``"batch"``, ``"recovery"`` or
            ``""`` (none: the undisturbed run).
    """

    seed: int
    rms: FloatArray
    recovery: int | None = None
    after: FloatArray | None = None
    allowed: FloatArray | None = None
    back_max: float | None = None
    batch: FloatArray | None = None
    target: str = ""

    @property
    def measure(self) -> float | None:
        """The row's figure against its target (``<= 1`` passes, except ``recovery``: frames,
        ``<= 30``): the worst segment's ``after / allowed``, the worst of segments 2 and 3's
        smoother over batch, or the recovery frames; ``None`` where it cannot be measured."""
        if self.target == "return":
            return None if self.after is None or self.allowed is None else float(
                np.max(self.after / self.allowed))
        if self.target == "batch":
            return None if self.batch is None else float(np.max(self.rms[1:] / self.batch[1:]))
        if self.target == "recovery":
            return None if self.recovery is None else float(self.recovery)
        return None

    @property
    def passed(self) -> bool | None:
        """Whether the seed meets the row's target (``None``: the row has none)."""
        m = self.measure
        if self.target == "return":
            return m is not None and m <= 1.0 and (self.back_max is not None
                                                   and self.back_max <= MAX_OFF)
        if self.target == "batch":
            return m is not None and m <= FACTOR
        if self.target == "recovery":
            return m is not None and m <= AFTER
        return None


def seed_row(case: FaultCase, run: CaseRun, undisturbed: FloatArray) -> SeedRow:
    """The row of ``run`` (one case of one seed) against its target, beside the undisturbed
    run's ``(F, S)`` errors."""
    seen = rms(run.errors[_seen(case.simulation)])
    if case.name == "none":
        return SeedRow(run.seed, seen)
    if case.name == NEVER:
        return SeedRow(run.seed, seen, batch=run.batch, target="batch")
    recovery = _recovery(case, run, undisturbed)
    if not case.hides:
        return SeedRow(run.seed, seen, recovery, target="recovery")
    n = case.simulation.sequence.n_frames
    back = float(np.max(np.abs(run.errors[case.stop:]))) if case.stop < n else None
    after = allowed = None
    if case.stop + SETTLE < n:
        later = slice(case.stop + SETTLE, None)
        after = rms(run.errors[later])
        allowed = FACTOR * rms(case.undisturbed(undisturbed)[later])
        if run.lag_return is not None:
            allowed = np.maximum(allowed, run.lag_return)
    return SeedRow(run.seed, seen, recovery, after, allowed, back, target="return")


@dataclass(frozen=True)
class Sweep:
    """The sweep: per row (in table order) its seeds' rows; the first seed's rows in full;
    what was run."""

    rows: dict[str, list[SeedRow]]
    detail: list[FaultRun]
    frames: int
    seeds: tuple[int, ...]
    scene: str = "room"
    model_sigma: tuple[float, float] | None = None
    pause: PauseRun | None = None


@functools.lru_cache(maxsize=2)
def _cases(frames: int, seed: int, scene: str) -> list[FaultCase]:
    return fault_cases(frames, seed, scene)


def _job(frames: int, seed: int, scene: str, index: int,
         model_sigma: tuple[float, float] | None, bounds: bool) -> CaseRun:
    """One case of one seed (in a worker process, or in this one)."""
    cases = _cases(frames, seed, scene)
    return run_one(cases[index], cases[0].simulation, seed, model_sigma, bounds)


def selected(names: Sequence[str], only: Sequence[str] | None) -> list[int]:
    """Indices of the rows whose name contains one of ``only`` (case-insensitive; every row
    when ``None``), always with the undisturbed run first."""
    if only is None:
        return list(range(len(names)))
    wanted = [w.lower() for w in only]
    return [i for i, name in enumerate(names)
            if name == "none" or any(w in name.lower() for w in wanted)]


def run_sweep(frames: int = 450, seeds: Sequence[int] = SEEDS, scene: str = "room",
              model_sigma: tuple[float, float] | None = None, only: Sequence[str] | None = None,
              workers: int = 1, progress: bool = False) -> Sweep:
    """Every fault (or those named in ``only``: see :func:`selected`) on every seed, on
    ``workers`` processes; the first seed's rows in full, with their bounds."""
    if not seeds:
        raise ValueError("seeds: expected at least one")
    cases = {seed: fault_cases(frames, seed, scene) for seed in seeds}
    names = [c.name for c in cases[seeds[0]]]
    picked = selected(names, only)
    jobs = [(frames, seed, scene, i, model_sigma, seed == seeds[0])
            for seed in seeds for i in picked]
    runs: dict[tuple[int, str], CaseRun] = {}
    for run in progress_bar(_run_jobs(jobs, workers), total=len(jobs), desc="faults x seeds",
                            progress=progress):
        runs[run.seed, run.name] = run
    rows: dict[str, list[SeedRow]] = {names[i]: [] for i in picked}
    detail = []
    for seed in seeds:
        clean = runs[seed, "none"].errors
        for i in picked:
            case = cases[seed][i]
            run = runs[seed, case.name]
            rows[case.name].append(seed_row(case, run, clean))
            if seed == seeds[0]:
                detail.append(fault_run(case, run, None if i == 0 else clean))
    pause = runs.get((seeds[0], PAUSED + KEPT))
    return Sweep(rows, detail, frames, tuple(seeds), scene, model_sigma,
                 None if pause is None else pause.pause)


def _run_jobs(jobs: list[tuple[int, int, str, int, tuple[float, float] | None, bool]],
              workers: int) -> Iterator[CaseRun]:
    """Each job's run, as they finish."""
    if workers <= 1:
        for job in jobs:
            yield _job(*job)
        return
    with ProcessPoolExecutor(workers, mp_context=get_context("spawn")) as pool:
        for done in as_completed([pool.submit(_job, *job) for job in jobs]):
            yield done.result()


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


def _measure(row: SeedRow) -> str:
    """One seed's figure against its target."""
    m = row.measure
    if row.target == "recovery":
        return "never" if m is None else f"{m:.0f}"
    if row.target == "return":
        off = "-" if row.back_max is None else f"{math.degrees(row.back_max):.1f}"
        return ("-" if m is None else f"{m:.2f}") + f" ({off})"
    return "-" if m is None else f"{m:.2f}"


TARGETS = {"return": f"+2 s / allowed <= 1 (max deg <= {math.degrees(MAX_OFF):.0f})",
           "batch": f"seg 2-3 / batch <= {FACTOR:.0f}",
           "recovery": f"recovery <= {AFTER} fr",
           "": "-"}
"""Each target as the sweep's table states it."""


def format_sweep(sweep: Sweep) -> str:
    """The sweep's tables: RMS per segment per seed; per row the median and the worst seed,
    its target's figure per seed and pass or fail; then the first seed's rows in full."""
    seeds = sweep.seeds
    model = ("the exact model" if sweep.model_sigma is None else
             f"model error as noise ({sweep.model_sigma[0] * 1e3:g} mm, "
             f"{math.degrees(sweep.model_sigma[1]):g} deg)")
    width = max([len(name) for name in sweep.rows] + [5])
    out = [f"reliability: the default smoother (lag 1 s, {model}), scene {sweep.scene}, "
           f"{sweep.frames} frames, seeds {','.join(map(str, seeds))}; faults from frame "
           f"{sweep.frames // 3}", "",
           "RMS error per segment (deg) over the frames some camera saw, per seed", "",
           f"{'fault':<{width}}  " + "  ".join(f"{f'seed {s}':>20}" for s in seeds)]
    for name, per_seed in sweep.rows.items():
        out.append(f"{name:<{width}}  " + "  ".join(f"{_deg(r.rms):>20}" for r in per_seed))
    out += ["", "across seeds: the median RMS per segment and the worst seed (the largest RMS "
            "over the median, any segment); each seed's figure against the row's target", "",
            f"{'fault':<{width}}  {'median RMS':>20}  {'worst seed':>26}  "
            f"{'target (on every seed)':<38}  {'per seed':<{13 * len(seeds)}}  pass"]
    for name, per_seed in sweep.rows.items():
        values = np.array([r.rms for r in per_seed])
        median = np.median(values, axis=0)
        worst = per_seed[int(np.argmax(np.max(values / np.maximum(median, 1e-12), axis=1)))]
        verdicts = [r.passed for r in per_seed]
        verdict = ("-" if verdicts[0] is None else
                   "pass" if all(verdicts) else
                   f"FAIL {sum(not v for v in verdicts)}/{len(verdicts)}")
        figures = "  ".join(f"{_measure(r):>11}" for r in per_seed)
        out.append(f"{name:<{width}}  {_deg(median):>20}  "
                   f"{f'{worst.seed}: {_deg(worst.rms)}':>26}  "
                   f"{TARGETS[per_seed[0].target]:<38}  {figures:<{13 * len(seeds)}}  "
                   f"{verdict}")
    out += ["", f"+2 s / allowed: the RMS over the frames from {SETTLE / FPS:.0f} s after the "
            "tracks return, over the larger of",
            f"  {FACTOR:g}x the undisturbed run's RMS there and the bound of a 1 s lag there, "
            "worst segment; in brackets",
            "  the largest error on any frame once the tracks are back (deg)",
            "seg 2-3 / batch: the smoother's RMS over the batch's on the same recording, the "
            "worse of segments 2 and 3",
            "recovery: frames after the fault ends until the 10-frame moving RMS stays within "
            "2x the undisturbed run's",
            f"'{KEPT[2:]}': a re-identifying front end (the points tracked when the images "
            "stopped come back under their old ids)", "",
            f"seed {seeds[0]} in full:", "",
            format_reliability(sweep.detail, sweep.frames, sweep.pause)]
    return "\n".join(out)


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
