"""``apcc-graph montecarlo``: one estimator over many seeded simulations, RMS error beside the
Cramer-Rao bound, on Dask (:mod:`apcc_graph.evaluation.montecarlo`)."""

from __future__ import annotations

import argparse
from pathlib import Path

from apcc_graph.cli.common import (
    FORMATTER,
    UserError,
    add_dask_options,
    at_least,
    bench_robot_option,
    force_option,
    fraction,
    frames_option,
    out_option,
    positive,
    seed_option,
)

EXAMPLE = ("example:\n  apcc-graph montecarlo --runs 16 --frames 600 --method batch "
           "--out /tmp/mc\n  apcc-graph montecarlo --runs 200 --out /tmp/mc "
           "--scheduler tcp://10.0.0.5:8786")


def add_parser(commands: argparse._SubParsersAction) -> None:
    """Add ``montecarlo`` to the subcommands."""
    mc = commands.add_parser(
        "montecarlo", help="estimate many seeded simulations; RMS error beside the bound",
        description="Simulate --runs recordings (seeds --seed, --seed + 1, ...; the room "
        "scene), estimate each from its true first frame (0.1 deg prior) and compute each "
        "one's Cramer-Rao bound; write --out/seed_<n>/ and --out/montecarlo.csv and print the "
        "RMS error per segment over the seeds beside the bound. The seeds run on a local Dask "
        "cluster (one worker per core), on --scheduler's, or in this process (--workers 1). A "
        "re-run into the same --out reads complete seeds back (--force runs them again); a "
        "seed that fails is reported and does not stop the others.",
        epilog=EXAMPLE, formatter_class=FORMATTER,
        parents=[out_option("output folder of the study"), bench_robot_option(),
                 frames_option(600, minimum=2), seed_option(1, "first seed (default 1)"),
                 force_option("run every seed again, and write into a folder that holds "
                              "something else")])
    mc.add_argument("--runs", type=at_least(1), default=16, help="seeds (default 16)")
    mc.add_argument("--method", choices=("chain", "batch", "smoother"), default="batch",
                    help="the estimator (default: %(default)s)")
    mc.add_argument("--noise-px", type=positive, default=1.0,
                    help="pixel noise, standard deviation per coordinate (default 1)")
    mc.add_argument("--outliers", type=fraction, default=0.1,
                    help="fraction of outlier observations (default 0.1)")
    add_dask_options(mc)
    mc.set_defaults(run=run)


def run(args: argparse.Namespace) -> str:
    """Run the study and return its report."""
    from apcc_graph.evaluation.montecarlo import format_montecarlo, run_montecarlo
    from apcc_graph.io.output_folder import check_writable

    out = Path(args.out)
    if out.exists() and not args.force and (not out.is_dir() or any(
            p.name != "montecarlo.csv" and not p.name.startswith("seed_")
            for p in out.iterdir())):
        raise UserError(f"{out}: holds something other than a Monte Carlo study; choose "
                        "another --out or add --force")
    if not Path(args.robot).is_file():
        raise UserError(f"{args.robot}: no such robot file")
    check_writable(out)  # before any computing
    runs = run_montecarlo(args.robot, args.runs, args.frames, out, args.method, args.seed,
                          args.noise_px, args.outliers, args.workers, args.scheduler,
                          redo=args.force, progress=True)
    return format_montecarlo(runs, out)
