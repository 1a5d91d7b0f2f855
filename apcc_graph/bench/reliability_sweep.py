"""``apcc-graph bench reliability``'s sweep: every fault of :mod:`apcc_graph.bench.reliability`
on every seed (and scene), each seed's row against its target, side by side in worker processes,
and the tables (per seed the RMS per segment; per row the median, the worst seed and pass/fail).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from multiprocessing import get_context

import numpy as np

from apcc_graph.bench.reliability import (
    AFTER,
    FACTOR,
    KEPT,
    MAX_OFF,
    NEVER,
    PAUSED,
    SEEDS,
    SETTLE,
    CaseRun,
    FaultCase,
    FaultRun,
    PauseRun,
    _deg,
    _recovery,
    _seen,
    fault_cases,
    fault_run,
    format_reliability,
    run_one,
)
from apcc_graph.bench.smoother import FPS
from apcc_graph.io.console import progress_bar
from apcc_graph.model.arrays import FloatArray, rms


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


