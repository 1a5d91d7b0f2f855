"""Monte Carlo: one estimator over many seeded simulations, each error beside its own
Cramer-Rao bound, on Dask or in process (``apcc-graph montecarlo``).

Each seed is one task (:func:`run_seed`): simulate the recording (the robot, ``frames`` frames,
pixel noise, outliers, the room scene), save it, compute the bound of its angles (every
observation once, each track's point a nuisance, the same 0.1 degree start prior the estimator
gets; :func:`~apcc_graph.evaluation.sequence_bound.sequence_bound`), and estimate it
(:func:`~apcc_graph.estimation.many.estimate_one`), started at the true first configuration
plus a draw of that prior (seeded): the bound counts the prior as information of that spread,
so an estimator started at the truth itself would beat it on short recordings. The tasks
run like the sequences of ``apcc-graph estimate A B C``
(:func:`~apcc_graph.estimation.many.map_tasks`): a local Dask cluster by default, an existing
one with ``scheduler``, this process with one worker; the same seed gives the same bits
anywhere. Outputs, under ``out``::

    seed_0001/sequence/   the simulated recording
    seed_0001/estimate/   its estimate (theta.csv, TUM files, done.txt)
    seed_0001/bound.csv   its bound per segment (degrees), written before the estimate
    montecarlo.csv        one row per seed: RMS error and bound per segment, status

Each seed's folder is written whole (in a staging folder beside it, moved into place when
complete). A seed whose estimate is complete (``done.txt``) is read back instead of being run
again, so an interrupted study resumes; a seed that fails is a row with its one-line error.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from threadpoolctl import threadpool_limits

from apcc_graph.estimation.many import (
    DONE,
    SequenceRun,
    clean_up_interrupted,
    estimate_one,
    map_tasks,
)
from apcc_graph.io.atomic import atomic_write_text
from apcc_graph.io.interrupts import check_interrupted
from apcc_graph.io.output_folder import staged_folder
from apcc_graph.model.arrays import FloatArray, rms

THETA0_SIGMA = math.radians(0.1)
"""The start prior of every seed's estimate and bound (radians)."""


@dataclass(frozen=True)
class SeedRun:
    """One seed: its estimate's run (RMS error per segment in radians, status) and the RMS over
    its frames of the per-frame bound (radians; empty if it failed before)."""

    seed: int
    run: SequenceRun
    bound: tuple[float, ...]


def run_seed(robot_file: str, frames: int, seed: int, noise_px: float, outliers: float,
             method: str, folder: str, redo: bool = False) -> SeedRun:
    """Simulate, bound and estimate one seed into ``folder`` (see the module docstring); never
    raises for a failure of its own (the error is the run's status)."""
    root = Path(folder)
    sequence, estimate, bound_file = root / "sequence", root / "estimate", root / "bound.csv"
    options: dict[str, Any] = {"theta0_sigma": THETA0_SIGMA, "noise_px": noise_px}
    if not redo and (estimate / DONE).is_file() and bound_file.is_file():
        bound = tuple(math.radians(float(v)) for v in bound_file.read_text().split()[1:])
        return SeedRun(seed, estimate_one(str(sequence), str(estimate), method, options), bound)
    staged = ""
    try:
        # the seed's folder is written whole: in a staging folder, moved into place at the end
        # (done.txt and the messages name the files where they will be, not where they are)
        with staged_folder(root, replace=True) as staging:
            staged = str(staging)
            bound, options["theta0"] = _simulate_and_bound(robot_file, frames, seed, noise_px,
                                                           outliers, staging / "sequence")
            atomic_write_text(staging / "bound.csv", "bound_deg " + " ".join(
                f"{math.degrees(b):.6f}" for b in bound) + "\n")
            run = estimate_one(str(staging / "sequence"), str(staging / "estimate"), method,
                               options, True, names=(str(sequence), str(estimate)))
    except Exception as error:  # noqa: BLE001 - the seed's status, not the study's end
        check_interrupted()  # unless it came of Ctrl-C
        message = " ".join(str(error).split())
        if staged:
            message = message.replace(staged, str(root))
        failed = SequenceRun(str(sequence), str(estimate), method, 0, 0.0, (),
                             f"failed: {message}")
        return SeedRun(seed, failed, ())
    return SeedRun(seed, replace(run, sequence=str(sequence), out=str(estimate)), bound)


def _simulate_and_bound(robot_file: str, frames: int, seed: int, noise_px: float,
                        outliers: float, folder: Path) -> tuple[tuple[float, ...], FloatArray]:
    """Simulate and save the recording; its bound and the estimator's start (radians)."""
    from apcc_graph.evaluation.sequence_bound import sequence_bound
    from apcc_graph.io import load_robot, save_sequence
    from apcc_graph.simulation.simulator import simulate

    sim = simulate(load_robot(robot_file), frames, noise_px=noise_px, outlier_fraction=outliers,
                   seed=seed, scene="room")
    save_sequence(sim.sequence, folder)
    with threadpool_limits(limits=1, user_api="blas"):  # the same bits on every worker
        sigmas = sequence_bound(sim, noise_px, THETA0_SIGMA).sigmas
    seen = np.all(np.isfinite(sigmas), axis=1)
    truth = sim.sequence.thetas
    assert truth is not None
    start = truth[0] + np.random.default_rng([seed, 1]).normal(0.0, THETA0_SIGMA, len(truth[0]))
    return tuple(float(v) for v in rms(sigmas[seen])), start


def run_montecarlo(robot_file: str | Path, seeds: int, frames: int, out: str | Path,
                   method: str = "batch", first_seed: int = 1, noise_px: float = 1.0,
                   outliers: float = 0.1, workers: int | None = None,
                   scheduler: str | None = None, redo: bool = False,
                   progress: bool = False) -> list[SeedRun]:
    """Run seeds ``first_seed .. first_seed + seeds - 1`` (see the module docstring) and write
    ``out/montecarlo.csv``; one :class:`SeedRun` per seed, in seed order."""
    if seeds < 1 or frames < 2:
        raise ValueError(f"seeds = {seeds}, frames = {frames}: expected at least 1 seed and "
                         "2 frames")
    if not noise_px > 0.0 or not 0.0 <= outliers < 1.0:
        raise ValueError(f"noise_px = {noise_px}, outliers = {outliers}: expected noise_px > 0 "
                         "and 0 <= outliers < 1")
    root = Path(out)
    created = not root.exists()
    root.mkdir(parents=True, exist_ok=True)
    jobs = [(str(robot_file), frames, s, noise_px, outliers, method,
             str(root / f"seed_{s:04d}"), redo) for s in range(first_seed, first_seed + seeds)]
    try:
        runs = map_tasks(run_seed, jobs, workers, scheduler, progress, "seeds")
    except BaseException:  # Ctrl-C: the finished seeds stay, nothing of the others
        clean_up_interrupted(root, [job[6] for job in jobs], created)
        raise
    atomic_write_text(root / "montecarlo.csv", montecarlo_csv(runs))
    return runs


def montecarlo_csv(runs: list[SeedRun]) -> str:
    """The study's table: seed, method, frames, seconds, RMS and bound per segment (degrees),
    status."""
    S = max((len(r.bound) for r in runs), default=0)
    head = ["seed", "method", "frames", "seconds",
            *(f"rms_deg_{i + 1}" for i in range(S)), *(f"bound_deg_{i + 1}" for i in range(S)),
            "status"]
    lines = [",".join(head)]
    for r in runs:
        rms_deg = [f"{math.degrees(v):.6f}" for v in r.run.rms] or [""] * S
        bound_deg = [f"{math.degrees(v):.6f}" for v in r.bound] or [""] * S
        status = r.run.status.replace(",", ";")
        lines.append(",".join([str(r.seed), r.run.method, str(r.run.frames),
                               f"{r.run.seconds:.3f}", *rms_deg, *bound_deg, status]))
    return "\n".join(lines) + "\n"


def summarise(runs: list[SeedRun]) -> tuple[FloatArray, FloatArray, int]:
    """Over the seeds that did not fail: the RMS error per segment (root of the mean of the
    seeds' squared RMS) and the same of their bounds (radians), and how many seeds count."""
    ok = [r for r in runs if r.run.rms and r.bound]
    if not ok:
        return np.zeros(0), np.zeros(0), 0
    return (rms(np.array([r.run.rms for r in ok])), rms(np.array([r.bound for r in ok])),
            len(ok))


def format_montecarlo(runs: list[SeedRun], out: str | Path) -> str:
    """The command line's report."""
    error, bound, n = summarise(runs)
    method = runs[0].run.method if runs else "-"
    lines = [f"{len(runs)} seeds, {method} -> {out} (montecarlo.csv): {n} estimated or read "
             f"back, {len(runs) - n} failed"]
    if n:
        lines += [f"{'segment':>8} {'RMS (deg)':>10} {'bound (deg)':>12} {'ratio':>6}"]
        lines += [f"{i + 1:>8} {math.degrees(e):10.4f} {math.degrees(b):12.4f} {e / b:6.2f}"
                  for i, (e, b) in enumerate(zip(error, bound, strict=True))]
    lines += [f"  seed {r.seed}: {r.run.status}" for r in runs
              if r.run.status.startswith("failed")]
    return "\n".join(lines)
