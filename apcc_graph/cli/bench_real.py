"""``apcc-graph bench real``: the estimators on a real robot's measured motion, beside the floor."""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from apcc_graph.cli.common import FORMATTER, UserError, model_sigma, non_negative, positive

EXAMPLES = {
    "real": "apcc-graph bench real\n"
            "  apcc-graph bench real --methods chain --recordings impulse_2\n"
            "  apcc-graph bench real --fps 30",
}
"""Example commands per benchmark of this module."""


def add_parsers(benches: argparse._SubParsersAction) -> None:
    """Add this module's benchmarks to ``apcc-graph bench``."""
    rb = benches.add_parser(
        "real", epilog=f"examples:\n  {EXAMPLES['real']}", formatter_class=FORMATTER,
        help="the estimators on a real robot's motion: tip errors beside the floor",
        description="For each recording of a real two-segment robot (data/real_tdcr): "
        "calibrate the robot from its backbone poses (with each segment's model error), replay "
        "the measured motion with tip cameras seeing a simulated room (1 px, 10%% outliers), "
        "estimate with the chain, the batch and the smoother as a user gets them (the "
        "calibrated robot file's model error as noise), the same with the exact model forced "
        "(batch-exact, smoother-exact) from the floor's first configuration (2 deg prior), and "
        "the yardstick noise@floor (the batch with model noise started at the floor's bends of "
        "every frame), and print "
        "the RMS tip errors beside the floor (the model's best fit to the measured tips); then "
        "the same on the model-exact version of the motion.")
    rb.add_argument("--data", default="data/real_tdcr",
                    help="folder of the recordings, each <name>/backbone_poses.csv "
                    "(default: %(default)s)")
    rb.add_argument("--robot", default="data/robots/real_tdcr.toml",
                    help="the robot to calibrate (default: %(default)s)")
    rb.add_argument("--recordings", default="slow_free_space,impulse_2",
                    help="recordings, comma-separated (default: %(default)s)")
    rb.add_argument("--methods",
                    default="chain,batch,smoother,batch-exact,smoother-exact,noise@floor",
                    help="estimators, comma-separated (default: %(default)s): batch and "
                    "smoother as a user gets them (the calibrated robot file's model error as "
                    "noise, drifting along the bends), *-exact with the exact model "
                    "forced; peers to add: batch-independent and smoother-independent (the file's "
                    "model error independent per frame, not drifting along the bends), "
                    "batch-chain (batch "
                    "started from the chain instead of the cameras' rotations), noise and "
                    "smoother-noise (with --model-sigma), smoother-qr (the smoother factoring "
                    "its window by QR), smoother-gate (the smoother with the model-free "
                    "outlier gate), smoother-keyframes (the smoother solving at keyframes)")
    rb.add_argument("--noise-px", type=non_negative, default=1.0, help="pixel noise (default 1)")
    rb.add_argument("--outliers", type=float, default=0.1, help="outlier fraction (default 0.1)")
    rb.add_argument("--start-sigma-deg", type=positive, default=2.0,
                    help="the start prior's sigma, degrees (default 2)")
    rb.add_argument("--seed", type=int, default=0, help="replay seed (default 0)")
    rb.add_argument("--fps", type=positive, default=None,
                    help="replay at this frame rate, the motion interpolated between the "
                    "motion capture's samples (30: a real tip camera's rate; default: the "
                    "recording's own sample times, about 16 a second)")
    rb.add_argument("--model-sigma", type=model_sigma, default="1,0.5", metavar="MM,DEG",
                    help="model noise of noise, smoother-noise and noise@floor: tip position mm, "
                    "rotation deg "
                    "(default: %(default)s)")
    rb.set_defaults(run=run_real)


def run_real(args: argparse.Namespace) -> str:
    """Run the real-robot benchmark; return its table."""
    from apcc_graph.bench.real_robot import METHODS, format_real_bench, run_real_bench
    from apcc_graph.io import load_robot

    methods = tuple(m.strip() for m in args.methods.split(",") if m.strip())
    if not methods or any(m not in METHODS for m in methods):
        raise UserError(f"--methods {args.methods!r}: expected a comma-separated subset of "
                        f"{', '.join(METHODS)}")
    if not 0.0 <= args.outliers < 1.0:
        raise UserError(f"--outliers {args.outliers!r}: expected a fraction in [0, 1)")
    recordings = tuple(r.strip() for r in args.recordings.split(",") if r.strip())
    if not Path(args.robot).is_file():
        raise UserError(f"{args.robot}: no such robot file (--robot)")
    rows = run_real_bench(Path(args.data), load_robot(args.robot), noise_px=args.noise_px,
                          outliers=args.outliers, seed=args.seed,
                          start_sigma=math.radians(args.start_sigma_deg), methods=methods,
                          recordings=recordings, model_sigma=args.model_sigma, fps=args.fps)
    rate = ("at the recordings' own sample times" if args.fps is None
            else f"at {args.fps:g} frames a second (interpolated)")
    return f"replayed {rate}\n" + format_real_bench(rows)
