"""How far from the truth the per-frame epipolar step may start:
``python tests/epipolar_step_sweep.py [seeds]``.

On the constructed scene of ``tests/test_epipolar_step.py`` (three cameras, 40 points each,
1 px, 10% outliers, a frame a few degrees from its keyframe), starts the step a share of the
frame's motion off in a random direction and counts the seeds whose result is outside its own
covariance (chi-square over 16.3 with 3 degrees of freedom, p = 0.001), with the worst error.
"""

from __future__ import annotations

import sys

import numpy as np
from test_epipolar_step import FOCAL, _scene

from apcc_graph.estimation.epipolar_step import epipolar_step


def main() -> None:
    """Print one line per starting offset."""
    seeds = int(sys.argv[1]) if len(sys.argv) > 1 else 60
    for share in (0.1, 0.25, 0.5):
        failed, worst = 0, 0.0
        for seed in range(100, 100 + seeds):
            chains, x_key, x_now, bearings, _ = _scene(seed, 1.0, 0.1)
            way = np.random.default_rng(seed + 1000).normal(size=3)
            guess = x_now + share * np.linalg.norm(x_now - x_key) * way / np.linalg.norm(way)
            step = epipolar_step(chains, 4, x_key, 5, guess, bearings,
                                 sigma=np.sqrt(2.0) / FOCAL, prior_sigma=1.0)
            err = step.x - x_now
            failed += float(err @ np.linalg.solve(step.covariance, err)) > 16.3
            worst = max(worst, float(np.max(np.abs(err))))
        print(f"start {share:.2f} of the motion off: {failed} of {seeds} outside their "
              f"covariance, worst error {np.degrees(worst):.2f} deg", flush=True)


if __name__ == "__main__":
    main()
