"""One fault on simulated recordings of several seeds, the smoother (or the batch) against the
truth: ``python tests/fault_sweep.py blind 7 11 12 13``.

The three-segment robot of the benchmarks in the room scene (4000 points), 240 frames at
30 fps, 1 px, 10% outliers; the fault at frame 80: ``blind`` (every camera blind for 1 s,
tracks back under new ids), ``blind_ids`` (the same, the tracks' old ids kept), ``pause``
(1.5 s of frames dropped, ids kept), ``pause_new`` (the same, tracks back under new ids),
``cam3`` (camera 3 blind for 3 s), ``nocam2`` (camera 2 never sees anything) or ``none``.
Prints per seed the RMS error per segment over every frame and over the frames from 2 s after
the tracks return, the worst error after their return, and the warnings (degrees).
``--method batch@smoother`` starts the batch from the smoother's answer (is the smoother's
error a basin?). For the
sweep over every fault and both measurement models see ``apcc-graph bench reliability``.
"""

from __future__ import annotations

import argparse
import math
import time
import warnings

import numpy as np

from apcc_graph.bench.smoother import FPS, ROBOT_FILE
from apcc_graph.estimation.batch import batch_estimate
from apcc_graph.estimation.methods import estimate
from apcc_graph.estimation.options import GraphOptions
from apcc_graph.io.robot_file import load_robot
from apcc_graph.simulation import faults
from apcc_graph.simulation.simulator import simulate

FRAMES, AT, POINTS = 240, 80, 4000


def run(kind: str, seed: int, method: str, model_sigma: tuple[float, float] | None) -> str:
    """One seed's line."""
    sim = simulate(load_robot(ROBOT_FILE), FRAMES, noise_px=1.0, outlier_fraction=0.1,
                   seed=seed, fps=FPS, scene="room", n_points=POINTS)
    back = AT + 30
    if kind.startswith("blind"):
        sim = faults.blind(sim, [0, 1, 2], AT, back, keep_ids=kind.endswith("ids"))
    elif kind.startswith("pause"):
        if kind == "pause_new":  # every track seen again comes back under a new id
            sim = faults.blind(sim, list(sim.sequence.tracks), AT, AT + 45)
        sim, back = faults.paused(sim, AT, AT + 45), AT
    elif kind == "cam3":  # the last camera blind for 3 s
        sim, back = faults.blind(sim, [2], AT, AT + 90), AT + 90
    elif kind == "nocam2":
        sim = faults.without_camera(sim, 1)
    seq = sim.sequence
    began = time.monotonic()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        graph = GraphOptions(model_sigma=model_sigma)
        est = estimate(seq, method=method.split("@")[-1], theta0=seq.thetas[0], noise_px=1.0,
                       graph=graph)
        if method == "batch@smoother":  # the batch started from the smoother's answer
            est = batch_estimate(seq, seq.thetas[0], initial=est.thetas, marginals=False,
                                 options=graph)
    err = np.degrees(est.thetas - seq.thetas)
    after = min(back + 2 * int(FPS), seq.n_frames - 1)
    said = sorted({w.category.__name__ for w in caught})
    return (f"{kind} seed {seed} {method} {time.monotonic() - began:.0f} s: RMS "
            f"{np.sqrt((err**2).mean(0)).round(3)}, from 2 s after "
            f"{np.sqrt((err[after:]**2).mean(0)).round(3)}, worst after "
            f"{np.abs(err[back:]).max(0).round(2)} {said}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("fault", choices=["none", "blind", "blind_ids", "pause", "pause_new",
                                          "cam3", "nocam2"])
    parser.add_argument("seeds", type=int, nargs="+")
    parser.add_argument("--method", default="smoother",
                        choices=["smoother", "batch", "batch@smoother"],
                        help="batch@smoother: the batch started from the smoother's answer")
    parser.add_argument("--model-sigma", default=None, metavar="MM,DEG",
                        help="model error as noise (default: the exact model)")
    args = parser.parse_args()
    sigma = None
    if args.model_sigma:
        mm, deg = (float(v) for v in args.model_sigma.split(","))
        sigma = (mm / 1000.0, math.radians(deg))
    for seed in args.seeds:
        print(run(args.fault, seed, args.method, sigma), flush=True)


if __name__ == "__main__":
    main()
