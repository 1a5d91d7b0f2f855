"""The real robot's replayed motion stretch by stretch, over replay seeds, with the model
error independent per frame and drifting along the bends (the default):
``python tests/real_stretch_sweep.py impulse_2 smoother 0 1 2``.

Calibrates the robot on the recording (as ``apcc-graph bench real``), replays each stretch of
at least 2 s (1 px, 10% outliers, the seed's room), estimates from the floor's first
configuration with a 2 deg prior, and prints per stretch the RMS tip error per segment end (mm)
of both. ``--stretches 0`` picks stretches; ``--start floor`` starts the batch at the floor's
bends of every frame instead (is a difference the start's, or the ties' optimum's?). For the
pooled table see ``apcc-graph bench real --methods
batch,smoother,batch-independent,smoother-independent``.
"""

from __future__ import annotations

import argparse
import math
import warnings

from helpers import replayed_stretches

from apcc_graph.estimation.batch import batch_estimate
from apcc_graph.estimation.methods import estimate
from apcc_graph.estimation.options import GraphOptions
from apcc_graph.evaluation.tip_floor import tip_errors
from apcc_graph.model.parameterisation import Bending


def main() -> None:
    """Parse the arguments, run the sweep, print a line per seed and stretch."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("recording", help="a folder of data/real_tdcr")
    parser.add_argument("method", choices=("batch", "smoother"))
    parser.add_argument("seeds", type=int, nargs="+")
    parser.add_argument("--stretches", type=int, nargs="+", default=None,
                        help="only these stretches (0-based; default: every one of 2 s)")
    parser.add_argument("--start", choices=("given", "floor"), default="given",
                        help="floor: the batch started at the floor's bends of every frame")
    args = parser.parse_args()
    if args.start == "floor" and args.method != "batch":
        parser.error("--start floor is for the batch")
    for model, seed, k, seq, floor in replayed_stretches(args.recording, args.seeds,
                                                          args.stretches):
        out = {}
        for name, correlation in (("independent", 0.0), ("drifting", "robot")):
            graph = GraphOptions(model_correlation=correlation,
                                 theta0_sigma=math.radians(2.0))
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                if args.start == "floor":
                    bending = Bending.free(model.segments)
                    est = batch_estimate(seq, floor.thetas[0], psi0=floor.psis[0],
                                         spatial=True, marginals=False, options=graph,
                                         initial=bending.vector(floor.thetas, floor.psis))
                else:
                    est = estimate(seq, method=args.method, theta0=floor.thetas[0],
                                   psi0=floor.psis[0], spatial=True,
                                   theta0_sigma=math.radians(2.0), graph=graph)
            rms = tip_errors(model.forward(est.thetas, est.psis),
                             seq.truth_tips).rms_position * 1e3
            out[name] = " / ".join(f"{v:.1f}" for v in rms)
        print(f"{args.recording} seed {seed} stretch {k} ({seq.n_frames} frames) "
              f"{args.method}: independent {out['independent']} mm, drifting "
              f"{out['drifting']} mm", flush=True)


if __name__ == "__main__":
    main()
