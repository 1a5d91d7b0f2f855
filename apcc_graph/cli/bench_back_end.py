"""``apcc-graph bench`` for the back end: the estimators against the Cramér-Rao bound
(``smoother``), self-calibration against its bound (``selfcal``, and of the camera mounts
``mounts``), the whole pipeline on
rendered images (``images``) and robots that bend in 3-D (``spatial``)."""

from __future__ import annotations

import argparse
import math
from collections.abc import Sequence

from apcc_graph.cli.common import (
    FORMATTER,
    UserError,
    frames_option,
    int_list,
    model_sigma,
    non_negative,
    seeds_option,
)

EXAMPLES = {
    "smoother": "apcc-graph bench smoother\n  apcc-graph bench smoother --frames 120 --seeds 1,2 "
    "--long-frames 0 --memory-frames 0 --methods chain,smoother",
    "selfcal": "apcc-graph bench selfcal --frames 600 --seeds 1,2,3",
    "mounts": "apcc-graph bench mounts --frames 600 --seeds 1,2,3 --deg 2 --mm 5",
    "images": "apcc-graph bench images --frames 150 --seeds 1,2,3,4,5",
    "spatial": "apcc-graph bench spatial\n  apcc-graph bench spatial --frames 150 --seeds 1",
    "young-tracks": "apcc-graph bench young-tracks --frames 300 --seeds 0,1,2",
}
"""Example commands per benchmark of this module."""


def _bench(benches: argparse._SubParsersAction, name: str, seeds: str,
           parents: Sequence[argparse.ArgumentParser] = (), **kwargs: object
           ) -> argparse.ArgumentParser:
    """Add benchmark ``name`` with its example, ``--seeds`` and the other ``parents``."""
    return benches.add_parser(name, epilog=f"example:\n  {EXAMPLES[name]}",
                              formatter_class=FORMATTER,
                              parents=[seeds_option(seeds), *parents], **kwargs)


def add_parsers(benches: argparse._SubParsersAction) -> None:
    """Add this module's benchmarks to ``apcc-graph bench``."""
    smb = _bench(
        benches, "smoother", "1,2,3,4,5",
        help="the back end against the Cramer-Rao bound: accuracy, drift, speed, memory",
        description="Simulate 3-segment room-scene sequences (1 px noise, 10%% and 30%% "
        "outliers, ~150 tracks per camera, 30 fps) and measure the chain, the fixed-lag "
        "smoother (solving at every frame, and at keyframes only: smoother-keyframes) and the "
        "batch beside the Cramer-Rao bound of the same sequences (and the smoothers beside "
        "the bound of a 1 s fixed lag), in one run.",
        parents=[frames_option(600, minimum=30, help="frames of each accuracy run")])
    smb.add_argument("--methods", default="chain,smoother,smoother-keyframes,batch",
                     help="estimators, comma-separated (default: %(default)s)")
    smb.add_argument("--outliers", default="0.1,0.3",
                     help="outlier fractions, comma-separated (default: %(default)s)")
    smb.add_argument("--long-frames", type=int, default=3000,
                     help="frames of the drift and speed run (0 to skip)")
    smb.add_argument("--memory-frames", type=int, default=10_000,
                     help="frames of the memory run (0 to skip)")
    smb.add_argument("--model-sigma", type=model_sigma, default=None, metavar="MM,DEG",
                     help="also run the smoother with model error as noise (tip position mm, "
                     "rotation deg) beside the exact one on the same sequences "
                     "(row smoother-noise)")
    smb.set_defaults(run=run_smoother)

    _add_selfcal(benches)

    _add_mounts(benches)

    imb = _bench(
        benches, "images", "1,2,3,4,5",
        help="images -> tracks -> smoother vs the same motion as simulated tracks",
        description="Render each tip camera's view of a textured room along a simulated "
        "motion, track the images (KLT) and run the smoother; compare with the same motion "
        "observed as simulated 1 px tracks, and time the tracker.",
        parents=[frames_option(150, minimum=10)])
    imb.add_argument("--noise", type=non_negative, default=2.0,
                     help="sensor noise, grey levels (default 2)")
    imb.add_argument("--texture", choices=("skimage", "procedural"), default="skimage")
    imb.set_defaults(run=run_images)

    spb = _bench(
        benches, "spatial", "1,2,3",
        help="robots that bend in 3-D: bending vectors beside the Cramer-Rao bound",
        description="Simulate room-scene sequences of the 3-segment robot with turning "
        "bending planes (1 px noise, 10%% outliers, 30 fps) and measure the chained 2-point "
        "estimate, the spatial batch and the fixed-lag smoother beside the bound of the "
        "bending vectors theta (cos psi, sin psi) of the same sequences.",
        parents=[frames_option(600, minimum=30)])
    spb.add_argument("--outliers", type=float, default=0.1, help="outlier fraction")
    spb.add_argument("--methods", default="chain,batch,smoother",
                     help="estimators, comma-separated (default: %(default)s)")
    spb.set_defaults(run=run_spatial)

    _add_young_tracks(benches)


def _add_young_tracks(benches: argparse._SubParsersAction) -> None:
    """Add ``apcc-graph bench young-tracks``."""
    ytb = _bench(
        benches, "young-tracks", "0,1,2",
        help="what tracks in their 2nd and 3rd frame add to the smoother's newest frame",
        description="Run the fixed-lag smoother on room-scene sequences of the 3-segment "
        "robot (1 px, 30 fps) with young tracks joining the newest frame's estimate after 4 "
        "observations (the default) and after 2 (every observation at once: an upper bound "
        "on what epipolar factors for young tracks could add), and print the newest-frame "
        "and final RMS errors per segment.",
        parents=[frames_option(300, minimum=30)])
    ytb.add_argument("--outliers", type=float, default=0.1, help="outlier fraction")
    ytb.set_defaults(run=run_young_tracks)


def _add_selfcal(benches: argparse._SubParsersAction) -> None:
    """Add ``bench selfcal``."""
    scb = _bench(
        benches, "selfcal", "1,2,3",
        help="self-calibration of k and delta_max beside the Cramer-Rao bound",
        description="Simulate room-scene sequences of the 3-segment robot, give the batch "
        "segment models with k and delta_max off, and compare the batch with the true "
        "models, the wrong ones and the wrong ones self-calibrated, beside the bound with "
        "the models known and unknown (which also bounds k and delta_max).",
        parents=[frames_option(600, minimum=30)])
    scb.add_argument("--outliers", type=float, default=0.1, help="outlier fraction")
    scb.add_argument("--dk", type=float, default=0.03, help="error of every segment's k")
    scb.add_argument("--dd-deg", type=float, default=3.0,
                     help="error of every segment's delta_max, degrees")
    scb.set_defaults(run=run_selfcal)


def _add_mounts(benches: argparse._SubParsersAction) -> None:
    """Add ``bench mounts``."""
    mnb = _bench(
        benches, "mounts", "1,2,3",
        help="calibration of the camera mounts beside the Cramer-Rao bound",
        description="Simulate room-scene sequences of the 3-segment robot, give the batch "
        "camera mounts turned by --deg and moved by --mm, and compare the batch with the "
        "true mounts, the wrong ones, the wrong ones calibrated, and calibrated with the "
        "segment models, beside the bound with the mounts known and unknown (which also "
        "bounds the mounts).",
        parents=[frames_option(600, minimum=30)])
    mnb.add_argument("--outliers", type=float, default=0.1, help="outlier fraction")
    mnb.add_argument("--deg", type=non_negative, default=2.0,
                     help="rotation error of every mount, degrees (default: %(default)s)")
    mnb.add_argument("--mm", type=non_negative, default=5.0,
                     help="translation error of every mount, mm (default: %(default)s)")
    mnb.set_defaults(run=run_mounts)


def run_smoother(args: argparse.Namespace) -> str:
    """Run the back-end benchmark; return its tables."""
    from apcc_graph.bench.smoother import METHODS, run_smoother_benchmark
    from apcc_graph.bench.smoother_tables import format_smoother_benchmark

    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    unknown = [m for m in methods if m not in METHODS]
    if unknown or not methods:
        raise UserError(f"--methods {args.methods!r}: expected a comma-separated subset of "
                        f"{', '.join(METHODS)}")
    if args.long_frames and args.long_frames < 400:
        raise UserError(f"--long-frames {args.long_frames}: expected 0 (skip) or at least 400")
    if args.memory_frames and args.memory_frames < 1000:
        raise UserError(f"--memory-frames {args.memory_frames}: expected 0 (skip) or at least "
                        "1000")
    try:
        outliers = [float(v) for v in args.outliers.split(",") if v.strip()]
    except ValueError:
        outliers = []
    if not outliers or not all(0.0 <= v < 1.0 for v in outliers):
        raise UserError(f"--outliers {args.outliers!r}: expected comma-separated fractions in "
                        "[0, 1), e.g. 0.1,0.3")
    result = run_smoother_benchmark(frames=args.frames, seeds=int_list(args.seeds, "--seeds"),
                                    outliers=outliers, methods=methods,
                                    long_frames=args.long_frames,
                                    memory_frames=args.memory_frames, progress=True,
                                    model_sigma=args.model_sigma)
    return format_smoother_benchmark(result)


def run_spatial(args: argparse.Namespace) -> str:
    """Run the spatial benchmark; return its tables."""
    from apcc_graph.bench.spatial import (
        METHODS,
        format_spatial_benchmark,
        run_spatial_benchmark,
    )

    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    if not methods or any(m not in METHODS for m in methods):
        raise UserError(f"--methods {args.methods!r}: expected a comma-separated subset of "
                        f"{', '.join(METHODS)}")
    if not 0.0 <= args.outliers < 1.0:
        raise UserError(f"--outliers {args.outliers!r}: expected a fraction in [0, 1)")
    result = run_spatial_benchmark(frames=args.frames, seeds=int_list(args.seeds, "--seeds"),
                                   outliers=args.outliers, methods=methods, progress=True)
    return format_spatial_benchmark(result)


def run_selfcal(args: argparse.Namespace) -> str:
    """Run the self-calibration benchmark; return its table."""
    from apcc_graph.bench.self_calibration import (
        format_self_calibration_benchmark,
        run_self_calibration_benchmark,
    )

    if not 0.0 <= args.outliers < 1.0:
        raise UserError(f"--outliers {args.outliers!r}: expected a fraction in [0, 1)")
    result = run_self_calibration_benchmark(
        frames=args.frames, seeds=int_list(args.seeds, "--seeds"), outliers=args.outliers,
        dk=args.dk, dd=math.radians(args.dd_deg), progress=True)
    return format_self_calibration_benchmark(result)


def run_mounts(args: argparse.Namespace) -> str:
    """Run the mount-calibration benchmark; return its table."""
    from apcc_graph.bench.mount_calibration import format_mount_benchmark, run_mount_benchmark

    if not 0.0 <= args.outliers < 1.0:
        raise UserError(f"--outliers {args.outliers!r}: expected a fraction in [0, 1)")
    result = run_mount_benchmark(frames=args.frames, seeds=int_list(args.seeds, "--seeds"),
                                 outliers=args.outliers, deg=args.deg, mm=args.mm,
                                 progress=True)
    return format_mount_benchmark(result)


def run_images(args: argparse.Namespace) -> str:
    """Run the images benchmark; return its table."""
    from apcc_graph.bench.images import format_images_benchmark, run_images_benchmark

    seeds = int_list(args.seeds, "--seeds")
    try:
        runs = run_images_benchmark(frames=args.frames, seeds=tuple(seeds),
                                    noise_grey=args.noise, texture_source=args.texture,
                                    progress=True)
    except ImportError as error:
        raise UserError(str(error)) from None
    return format_images_benchmark(runs, args.frames, args.noise)


def run_young_tracks(args: argparse.Namespace) -> str:
    """Run the young-tracks benchmark; return its table."""
    from apcc_graph.bench.young_tracks import format_young_tracks, run_young_tracks_benchmark

    if not 0.0 <= args.outliers < 1.0:
        raise UserError(f"--outliers {args.outliers!r}: expected a fraction in [0, 1)")
    return format_young_tracks(run_young_tracks_benchmark(
        frames=args.frames, seeds=int_list(args.seeds, "--seeds"), outliers=args.outliers,
        progress=True))
