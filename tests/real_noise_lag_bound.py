"""The noise bound of a fixed-lag smoother on the real robot's replayed motion, stretch by
stretch: ``python tests/real_noise_lag_bound.py impulse_2 [step]``.

Calibrates the robot on the recording (as ``apcc-graph bench real``), replays each stretch of
at least 2 s (1 px, 10% outliers, seed 0), and prints per stretch the RMS over every
``step``-th frame (default the benchmark's) of the Cramer-Rao bound of the segment ends with
the calibration's model error as noise (drifting along the bends), from the frames up to the
smoother's default lag after each sampled frame, beside the same bound from the whole stretch
(``apcc-graph bench real``'s noise bound); then both pooled. One graph is factored per sampled
frame: about 10 min for slow_free_space's long stretch at the default step.
"""

from __future__ import annotations

import argparse
import math

import numpy as np
from helpers import recording_calibrated

from apcc_graph.bench.real_robot import BOUND_STEP, MIN_STRETCH
from apcc_graph.estimation.model_noise import segment_correlations, segment_sigmas
from apcc_graph.estimation.smoother_options import SmootherOptions
from apcc_graph.evaluation.noise_bound import model_noise_lag_bound, model_noise_tip_bound
from apcc_graph.evaluation.tip_floor import tip_floor
from apcc_graph.model.parameterisation import Bending
from apcc_graph.simulation.replay import motion_stretches, replay_motion


def main() -> None:
    """Parse the arguments, print a line per stretch and the pooled bounds (mm)."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("recording", help="a folder of data/real_tdcr")
    parser.add_argument("step", type=int, nargs="?", default=BOUND_STEP)
    args = parser.parse_args()
    model, ends = recording_calibrated(args.recording)
    sigmas, ties = segment_sigmas("robot", model), segment_correlations("robot", model)
    bending = Bending.free(model.segments)
    lagged, whole = [], []
    for k, (a, b, _) in enumerate(motion_stretches(ends)):
        if b - a < MIN_STRETCH:
            continue
        sim = replay_motion(model, ends, stretch=k, noise_px=1.0, outlier_fraction=0.1,
                            seed=0).simulation
        floor = tip_floor(model, sim.sequence.truth_tips)
        vectors = bending.vector(floor.thetas, floor.psis)
        lag = round(SmootherOptions().window.lag / np.median(np.diff(sim.sequence.timestamps)))
        common = (sim, vectors, bending, sigmas, 1.0, math.radians(2.0))
        lagged.append(model_noise_lag_bound(*common, lag_frames=lag, step=args.step,
                                            correlations=ties).sigmas)
        whole.append(model_noise_tip_bound(*common, step=args.step, correlations=ties).sigmas)
        print(f"{args.recording} stretch {k} ({sim.sequence.n_frames} frames, lag {lag}): "
              f"lag bound {_rms(lagged[-1])} mm, whole stretch {_rms(whole[-1])} mm", flush=True)
    print(f"{args.recording} pooled: lag bound {_rms(np.concatenate(lagged))} mm, whole "
          f"{_rms(np.concatenate(whole))} mm")


def _rms(sigmas: np.ndarray) -> str:
    return " / ".join(f"{v:.2f}" for v in 1e3 * np.sqrt(np.mean(sigmas ** 2, axis=0)))


if __name__ == "__main__":
    main()
