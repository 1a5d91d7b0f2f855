"""Many recordings at once: each sequence folder estimated into its own output folder, and one
summary table, in process or on a Dask cluster.

A sequence's outputs are complete when its folder holds ``done.txt``, written last (after
``theta.csv`` and the TUM files): a re-run skips those sequences. A sequence's folder that
holds anything else is not replaced without ``redo`` (it is that sequence's failure). Each
sequence's folder is written whole (in a staging folder, moved into place when complete), so a
run killed or interrupted half-way leaves the sequences it finished complete and nothing of the
one it was on. A sequence that fails is reported in the summary with its one-line error and
does not stop the others.

Dask (``pip install "apcc-graph[dask]"``) is imported only when more than one worker is asked
for; one worker runs everything in this process.

Every sequence is estimated with numpy's BLAS on one thread (threadpoolctl), in process and on
a worker alike: BLAS with more threads sums in another order, and a 600-frame batch would then
differ by up to 1.5e-10 rad between the two. With one thread both give the same bits, and a
sequence's small products gain nothing from more threads anyway.

The local cluster's workers are started without two of Dask's defaults that cost this workload
a quarter of its speed: ``MALLOC_TRIM_THRESHOLD_=65536`` (glibc then returns memory to the
system after every large free; the estimators allocate many short-lived arrays) and the
statistical profiler that samples each worker's stack every 10 ms. A cluster given with
``scheduler`` keeps its own settings.
"""

from __future__ import annotations

import contextlib
import math
import os
import time
import warnings
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, TypeVar

from threadpoolctl import threadpool_limits

from apcc_graph.io.atomic import atomic_write_text
from apcc_graph.io.console import progress_bar
from apcc_graph.io.csv_table import format_number

DONE = "done.txt"
"""Written last into a sequence's output folder: its outputs are complete."""

SUMMARY_COLUMNS = ("sequence", "method", "frames", "seconds", "status")

Result = TypeVar("Result")


@dataclass(frozen=True)
class SequenceRun:
    """What became of one sequence.

    Attributes:
        sequence: its folder.
        out: its output folder.
        method: the estimator.
        frames: frames estimated (0 when it failed before).
        seconds: wall time of loading, estimating and writing.
        rms: ``(S,)`` RMS error per segment against the sequence's ground truth (radians);
            empty without truth or when it failed.
        status: ``"ok"``, ``"skipped"`` (complete outputs found) or ``"failed: <message>"``.
    """

    sequence: str
    out: str
    method: str
    frames: int
    seconds: float
    rms: tuple[float, ...]
    status: str


def output_folder(out_root: str | Path, sequence: str | Path) -> Path:
    """Where a sequence's estimate goes: ``out_root/<its folder name>``."""
    return Path(out_root) / Path(sequence).resolve().name


def estimate_one(sequence: str, out: str, method: str, options: dict[str, Any],
                 redo: bool = False, names: tuple[str, str] | None = None) -> SequenceRun:
    """Load, estimate and write one sequence; never raises for a bad sequence (the error is
    its status). Skips it when ``out`` already holds complete outputs, unless ``redo``; any
    other non-empty ``out`` is replaced only with ``redo`` (and never when it is or holds the
    current folder, the home folder or ``sequence``), else it is the sequence's failure.

    ``options["theta0"] = "truth"`` starts each sequence at its ground-truth first frame: the
    protocol of the benchmarks on simulated sequences, never for real recordings.

    ``names``: the sequence and output folders as the run, its ``done.txt`` and its error
    message name them, when ``sequence`` and ``out`` are in a staging folder that will be moved
    into place (default: ``sequence`` and ``out``)."""
    done = Path(out) / DONE
    if done.is_file() and not redo:
        return _skipped(sequence, out, method, done)
    from apcc_graph.estimation.failures import gtsam_failure, is_gtsam_error
    from apcc_graph.io.interrupts import check_interrupted
    from apcc_graph.io.output_folder import replace_refusal, staged_folder

    start = time.perf_counter()
    target = Path(out)
    existing = (target.exists() or target.is_symlink()) and not (
        target.is_dir() and not any(target.iterdir()))  # anything but an empty folder
    refusal = (replace_refusal(out, [sequence]) if redo
               else "exists and is not empty; add --force to replace it")
    if existing and refusal is not None:  # the user's own folder, not a run's outputs
        return SequenceRun(sequence, out, method, 0, 0.0, (), f"failed: {out}: {refusal}")
    try:
        with threadpool_limits(limits=1, user_api="blas"), \
                staged_folder(out, replace=True) as staging:
            run = _estimate_and_write(sequence, out, method, options, start, staging)
            if names is not None:
                run = replace(run, sequence=names[0], out=names[1])
            atomic_write_text(staging / DONE, summary_csv([run]))
        return run
    except Exception as error:  # noqa: BLE001 - any failure is this sequence's status
        check_interrupted()  # unless it came of Ctrl-C (numba then raises a SystemError)
        kind = "" if isinstance(error, ValueError | OSError) else f"{type(error).__name__}: "
        message = (gtsam_failure(error) if is_gtsam_error(error)
                   else kind + " ".join(str(error).split()))
        if names is not None:
            message = message.replace(out, names[1]).replace(sequence, names[0])
            sequence, out = names
        return SequenceRun(sequence, out, method, 0, time.perf_counter() - start, (),
                           f"failed: {message}")


def _estimate_and_write(sequence: str, out: str, method: str, options: dict[str, Any],
                        start: float, staging: Path) -> SequenceRun:
    """The work of :func:`estimate_one`, which handles its errors; the files go to
    ``staging``, which becomes ``out`` when complete."""
    from apcc_graph.estimation.methods import estimate
    from apcc_graph.io import load_sequence
    from apcc_graph.io.estimates import save_estimate

    seq = load_sequence(sequence)
    if isinstance(options.get("theta0"), str) and options["theta0"] == "truth":
        options = {**options, "theta0": None if seq.thetas is None else seq.thetas[0]}
    result = estimate(seq, method=method, **options)
    save_estimate(result, staging)
    rms = (() if seq.thetas is None
           else tuple(float(v) for v in result.rms(seq.thetas, seq.psis)))
    return SequenceRun(sequence, out, method, result.n_frames, time.perf_counter() - start,
                       rms, "ok")


def _skipped(sequence: str, out: str, method: str, done: Path) -> SequenceRun:
    """The run recorded in ``done`` (the one-row summary written when it completed)."""
    lines = done.read_text().splitlines()
    header, row = lines[0].split(","), lines[1].split(",")
    fields = dict(zip(header, row, strict=True))
    rms = tuple(math.radians(float(fields[name])) for name in header if name.startswith("rms_"))
    return SequenceRun(sequence, out, method, int(fields["frames"]), 0.0, rms, "skipped")


def summary_csv(runs: Sequence[SequenceRun]) -> str:
    """The text of ``summary.csv``: one row per sequence; RMS per segment in degrees (empty
    where there is no truth)."""
    n_seg = max((len(r.rms) for r in runs), default=0)
    header = [*SUMMARY_COLUMNS[:4], *(f"rms_{i + 1}_deg" for i in range(n_seg)), "status"]
    lines = [",".join(header)]
    for r in runs:
        rms = [format_number(math.degrees(v)) for v in r.rms] + [""] * (n_seg - len(r.rms))
        status = r.status.replace(",", ";").replace("\n", " ")
        lines.append(",".join([r.sequence.replace(",", "_"), r.method, str(r.frames),
                               f"{r.seconds:.3f}", *rms, status]))
    return "\n".join(lines) + "\n"


def sequence_folders(paths: Iterable[str | Path]) -> list[Path]:
    """The sequence folders named: each path is a sequence (it holds ``frames.csv``) or a
    parent of sequences (its sub-folders that hold one), in name order.

    Raises:
        ValueError: a path that is neither; two sequences with the same folder name (their
            outputs would collide).
    """
    found: list[Path] = []
    for path in map(Path, paths):
        if (path / "frames.csv").is_file():
            found.append(path)
            continue
        children = sorted(p for p in path.iterdir() if (p / "frames.csv").is_file()) \
            if path.is_dir() else []
        if not children:
            raise ValueError(f"{path}: not a sequence folder (no frames.csv) and no sequence "
                             "folders inside")
        found += children
    names = [p.resolve().name for p in found]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise ValueError(f"two sequences named {twice[0]!r}: their outputs would collide")
    return found


def estimate_many(sequences: Sequence[str | Path], out_root: str | Path, method: str = "batch",
                  options: dict[str, Any] | None = None, workers: int | None = None,
                  scheduler: str | None = None, redo: bool = False, progress: bool = False
                  ) -> list[SequenceRun]:
    """Estimate every sequence into ``out_root/<name>/`` and write ``out_root/summary.csv``.

    Args:
        sequences: sequence folders.
        out_root: the folder of all outputs.
        method, options: as :func:`apcc_graph.estimate` (the same for every sequence).
        workers: Dask workers on a local cluster (default: one per core); 1 runs in process.
        scheduler: address of an existing ``dask.distributed`` scheduler (then ``workers`` is
            ignored).
        redo: estimate again sequences whose outputs are complete (else they are skipped).
        progress: a progress bar over the sequences.

    Returns:
        One :class:`SequenceRun` per sequence, in the order given.
    """
    options = {**(options or {}), "progress": False}  # one bar, over the sequences
    jobs = [(str(s), str(output_folder(out_root, s)), method, options, redo) for s in sequences]
    created = not Path(out_root).exists()
    Path(out_root).mkdir(parents=True, exist_ok=True)
    try:
        runs = map_tasks(estimate_one, jobs, workers, scheduler, progress, "sequences")
    except BaseException:
        clean_up_interrupted(out_root, [job[1] for job in jobs], created)
        raise
    atomic_write_text(Path(out_root) / "summary.csv", summary_csv(runs))
    return runs


def clean_up_interrupted(out_root: str | Path, outs: Sequence[str], created: bool) -> None:
    """After an interrupted run: the staging folders a killed worker left behind removed, and
    ``out_root`` too if this run created it and finished nothing."""
    import shutil

    from apcc_graph.io.output_folder import staging_folders

    for out in outs:
        for staging in staging_folders(out):
            shutil.rmtree(staging, ignore_errors=True)
    if created:
        with contextlib.suppress(OSError):
            Path(out_root).rmdir()  # only when empty


def map_tasks(function: Callable[..., Result], jobs: Sequence[tuple[Any, ...]],
              workers: int | None = None, scheduler: str | None = None,
              progress: bool = False, label: str = "tasks") -> list[Result]:
    """``function(*job)`` for every job, in the order of ``jobs``: in this process with one
    worker (or without Dask), else one Dask task per job on a local cluster of ``workers``
    (default: one per core) or on the cluster at ``scheduler``. ``function`` must be
    importable by the workers (a module-level function) and should not raise: a job's failure
    is best returned as its result."""
    if scheduler is None and (workers == 1 or not _has_dask(workers)):
        return [function(*job) for job in progress_bar(jobs, desc=label, progress=progress)]
    return _on_dask(function, list(jobs), workers, scheduler, progress, label)


def _has_dask(workers: int | None) -> bool:
    """Whether to run on a local Dask cluster of ``workers`` (``None``: one per core, and
    in this process on a one-core machine). Without ``dask.distributed`` installed: no, with
    a one-line warning, whatever ``workers`` asked."""
    import importlib.util

    if importlib.util.find_spec("distributed") is None:
        asked = "" if workers is None else f" ({workers} workers were asked for)"
        warnings.warn('Dask is not installed (pip install "apcc-graph[dask]"): the sequences '
                      f"run one after the other in this process{asked}", stacklevel=3)
        return False
    return workers is not None or (os.cpu_count() or 1) > 1


def _on_dask(function: Callable[..., Result], jobs: list[tuple[Any, ...]], workers: int | None,
             scheduler: str | None, progress: bool, label: str) -> list[Result]:
    """Every job as one Dask task; results in the order of ``jobs``."""
    try:
        from distributed import Client, as_completed
    except ImportError:
        raise ValueError('a Dask scheduler needs Dask: pip install "apcc-graph[dask]" '
                         "(or leave out --scheduler to run here)") from None
    cluster = None
    with _cluster_settings():  # this process's settings are as they were once it is over
        try:
            if scheduler is None:
                cluster = _local_cluster(workers or os.cpu_count() or 1)
            with Client(scheduler or cluster) as client:
                futures = {client.submit(function, *job, pure=False): i
                           for i, job in enumerate(jobs)}
                results: list[Result | None] = [None] * len(jobs)
                bar = progress_bar(total=len(jobs), desc=label, progress=progress)
                try:
                    for future in as_completed(futures):
                        results[futures[future]] = future.result()
                        bar.update()
                except BaseException:
                    _quiet_dask()  # the shutdown's own complaints are no news after Ctrl-C
                    raise
                finally:
                    bar.close()
        finally:
            if cluster is not None:
                cluster.close()
    return [r for r in results if r is not None]


DASK_LOGGERS = ("distributed", "tornado", "asyncio")
"""The loggers :func:`_quiet_dask` silences for the rest of a cluster's life."""


@contextlib.contextmanager
def _cluster_settings() -> Iterator[None]:
    """What a cluster's run changes in this process, restored when it ends: the environment
    variable ``PYTHONWARNINGS`` (for the cluster's processes, see :func:`_local_cluster`) and
    the levels of :data:`DASK_LOGGERS`."""
    import logging

    warnings_filters = os.environ.get("PYTHONWARNINGS")
    levels = {name: logging.getLogger(name).level for name in DASK_LOGGERS}
    try:
        yield
    finally:
        if warnings_filters is None:
            os.environ.pop("PYTHONWARNINGS", None)
        else:
            os.environ["PYTHONWARNINGS"] = warnings_filters
        for name, level in levels.items():
            logging.getLogger(name).setLevel(level)


def _quiet_dask() -> None:
    """Dask's loggers silenced (until :func:`_cluster_settings` ends): an interrupted
    cluster's shutdown reports every lost task and worker, which says nothing the one line of
    the interruption does not."""
    import logging

    for name in DASK_LOGGERS:
        logging.getLogger(name).setLevel(logging.CRITICAL)


def _local_cluster(workers: int) -> Any:
    """A local cluster of ``workers`` one-thread worker processes, without the allocator
    trimming and the sampling profiler of Dask's defaults (see the module docstring)."""
    import dask.config
    from distributed import LocalCluster

    environ = {name: value for name, value in
               dask.config.get("distributed.nanny.pre-spawn-environ", {}).items()
               if name != "MALLOC_TRIM_THRESHOLD_"}
    # the workers' own log is silent: shutting a cluster down after Ctrl-C (or an error) has
    # each one warn of every task it cancelled and log its lost scheduler with a traceback (a
    # task's failure reaches this process as the sequence's status anyway)
    environ["DASK_LOGGING__DISTRIBUTED"] = "critical"
    # Ctrl-C at a terminal reaches every process of the group: the workers ignore it
    # (dask_worker, a preload), this process shuts the cluster down; multiprocessing's resource
    # tracker would then list the semaphores the workers left, no news after the one line (the
    # processes started now inherit the filter; _cluster_settings restores this process's)
    quiet = "ignore::UserWarning:multiprocessing.resource_tracker"
    filters = [f for f in os.environ.get("PYTHONWARNINGS", "").split(",") if f]
    os.environ["PYTHONWARNINGS"] = ",".join(filters + [quiet] * (quiet not in filters))
    preload = [*dask.config.get("distributed.worker.preload", []),
               "apcc_graph.estimation.dask_worker"]
    with dask.config.set({"distributed.nanny.pre-spawn-environ": environ,
                          "distributed.worker.profile.enabled": False,
                          "distributed.worker.preload": preload}):
        return LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                            dashboard_address=None)


def format_runs(runs: Sequence[SequenceRun], out_root: str | Path) -> str:
    """The command line's report of a many-sequence run."""
    counts = {s: sum(r.status.split(":")[0] == s for r in runs) for s in ("ok", "skipped",
                                                                          "failed")}
    lines = [f"{len(runs)} sequences -> {out_root} (summary.csv): {counts['ok']} estimated, "
             f"{counts['skipped']} already complete, {counts['failed']} failed"]
    for r in runs:
        if r.status.startswith("failed"):
            lines.append(f"  {r.sequence}: {r.status}")
    return "\n".join(lines)

