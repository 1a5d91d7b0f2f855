"""The unknown start on the real robot's replayed motion, stretch by stretch, over replay
seeds: ``python tests/real_start_sweep.py impulse_2 0 1 2``.

Calibrates the robot on the recording (as ``apcc-graph bench real``; the robot file then
carries the model error), replays each stretch of at least 2 s (1 px, 10% outliers, the
seed's room), and estimates each with the batch twice: from the floor's first configuration
with a 2 deg prior (the given start), and with no start at all (the search). Prints per seed
and stretch both RMS tip errors per segment end (mm), the given start's mean (e / sigma)^2 of
the bends against the floor's, and the worse ratio of the two tip errors, or the
:class:`~apcc_graph.estimation.start_search.UnknownStartError` the search raised. The
contract: the unknown start within 2x the given start's tip error, or the error.
"""

from __future__ import annotations

import argparse
import math
import time
import warnings

import numpy as np
from helpers import replayed_stretches

from apcc_graph.estimation.methods import estimate
from apcc_graph.estimation.result import Estimate
from apcc_graph.estimation.start_search import UnknownStartError
from apcc_graph.evaluation.tip_floor import tip_errors
from apcc_graph.model.robot import Robot
from apcc_graph.model.sequence import Sequence


def _rms(model: Robot, seq: Sequence, est: Estimate) -> np.ndarray:
    """``(S,)`` the RMS tip error per segment end of ``est`` (mm)."""
    tips = model.forward(est.thetas, est.psis)
    return tip_errors(tips, seq.truth_tips).rms_position * 1e3


def main() -> None:
    """Parse the arguments, run the sweep, print a line per seed and stretch."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("recording", help="a folder of data/real_tdcr")
    parser.add_argument("seeds", type=int, nargs="+")
    parser.add_argument("--stretches", type=int, nargs="+", default=None,
                        help="only these stretches (0-based; default: every one of 2 s)")
    args = parser.parse_args()
    for model, seed, k, seq, floor in replayed_stretches(args.recording, args.seeds,
                                                          args.stretches):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            from_floor = estimate(seq, "batch", floor.thetas[0], math.radians(2.0),
                                  psi0=floor.psis[0], spatial=True)
            given = _rms(model, seq, from_floor)
            t0 = time.perf_counter()
            try:
                found, why = estimate(seq, "batch", spatial=True), ""
            except UnknownStartError as error:
                found, why = None, str(error)
        seconds = time.perf_counter() - t0
        with np.errstate(divide="ignore", invalid="ignore"):
            nees = np.mean((from_floor.errors(floor.thetas, floor.psis)
                            / from_floor.bend_sigmas()) ** 2, axis=0)
        head = (f"{args.recording} seed {seed} stretch {k} ({seq.n_frames} frames): given "
                f"{' / '.join(f'{v:.1f}' for v in given)} mm (mean (e/sigma)^2 of the bends "
                f"{' / '.join(f'{v:.2f}' for v in nees)}); unknown")
        if found is None:
            print(f"{head} UnknownStartError ({seconds:.0f} s): {why}", flush=True)
            continue
        got = _rms(model, seq, found)
        ratio = float(np.max(got / given))
        start = ", ".join(f"{v:.1f}" for v in np.degrees(found.start.theta0))
        print(f"{head} {' / '.join(f'{v:.1f}' for v in got)} mm, {ratio:.1f}x "
              f"({'ok' if ratio <= 2.0 else 'WRONG'}; start {start} deg, floor "
              f"{', '.join(f'{v:.1f}' for v in np.degrees(floor.thetas[0]))} deg; "
              f"{seconds:.0f} s)", flush=True)


if __name__ == "__main__":
    main()
