"""What a keyframe rate costs the smoother in accuracy, and what it saves in time:
``python tests/keyframe_cost.py [frames] [seeds] [rates] [outliers] [model_sigma]``, e.g.
``python tests/keyframe_cost.py 300 0,1 1,3,5,10,rule 0.1`` (``model_sigma``: ``MM,DEG``, the
smoother with model error as noise of that tip position and rotation; default the exact model).

On the smoother benchmark's room scene (the shipped three-segment robot, 1 px, 10% outliers
unless given,
30 fps, lag 1 s, uncertainty off), for each seed, the smoother that solves at every frame
(rate ``1``), at every n-th frame (rate ``n``: a rule of time alone, ``max_interval`` n frames)
and by the default :class:`~apcc_graph.estimation.keyframes.KeyframeRule` (``rule``). Every
frame enters the window whatever the rate. Prints per seed and rate: keyframes, the final RMS
per segment (deg) and its ratio to rate 1's, the RMS of the estimates returned at once (deg),
the seconds of the whole stream and its ratio to rate 1's.
"""

from __future__ import annotations

import math
import sys
import time
import warnings

import numpy as np

from apcc_graph.bench.smoother import FPS, ROBOT_FILE, room_simulation
from apcc_graph.estimation.keyframes import KeyframeRule
from apcc_graph.estimation.options import GraphOptions
from apcc_graph.estimation.smoother import FixedLagSmoother
from apcc_graph.estimation.smoother_options import SmootherOptions, WindowOptions
from apcc_graph.io.robot_file import load_robot


def rule_of(rate: str) -> KeyframeRule | None:
    """``"1"``: none (every frame); ``"n"``: every n-th frame; ``"rule"``: the default."""
    if rate == "rule":
        return KeyframeRule()
    n = int(rate)
    if n == 1:
        return None
    return KeyframeRule(max_interval=(n - 0.5) / FPS, rotation=math.inf, parallax=math.inf,
                        survival=0.0)


def run(robot, seq, rate: str, options: GraphOptions | None = None
        ) -> tuple[int, np.ndarray, np.ndarray, float, dict[str, int]]:
    """Keyframes, final RMS, at-once RMS (deg), seconds of one stream and why its keyframes
    were keyframes."""
    truth = seq.thetas
    settings = SmootherOptions(window=WindowOptions(lag=1.0, uncertainty=False),
                               keyframes=rule_of(rate))
    smoother = FixedLagSmoother(robot, theta0=truth[0], settings=settings, options=options)
    start = time.perf_counter()
    now = np.array([smoother.update(seq.frame(f)).thetas for f in range(seq.n_frames)])
    final = np.array([e.thetas for e in smoother.finish()])
    seconds = time.perf_counter() - start
    keys = seq.n_frames if smoother._keys is None else smoother._keys.keyframes
    reasons = {} if smoother._keys is None else smoother._keys.reasons

    def rms(x: np.ndarray) -> np.ndarray:
        return np.degrees(np.sqrt(np.mean((x - truth) ** 2, axis=0)))

    return keys, rms(final), rms(now), seconds, reasons


def main() -> None:
    """Parse the arguments, run every seed and rate, print one line each."""
    frames = int(sys.argv[1]) if len(sys.argv) > 1 else 300
    seeds = [int(s) for s in (sys.argv[2] if len(sys.argv) > 2 else "0").split(",")]
    rates = (sys.argv[3] if len(sys.argv) > 3 else "1,3,5,10,rule").split(",")
    outliers = float(sys.argv[4]) if len(sys.argv) > 4 else 0.1
    options = None
    if len(sys.argv) > 5:
        mm, deg = (float(v) for v in sys.argv[5].split(","))
        options = GraphOptions(model_sigma=(mm * 1e-3, math.radians(deg)))
    if "1" not in rates:
        rates = ["1", *rates]
    robot = load_robot(ROBOT_FILE)
    warnings.simplefilter("ignore")  # the residual test's warnings on the sparse rates
    for seed in seeds:
        seq = room_simulation(robot, frames, outliers, seed).sequence
        base = None
        for rate in sorted(rates, key=lambda r: (r != "1", r)):
            keys, final, now, seconds, reasons = run(robot, seq, rate, options)
            base = base or (final, seconds)
            print(f"seed {seed} rate {rate:>4}: {keys:4d} keyframes; final "
                  f"{' / '.join(f'{v:.3f}' for v in final)} deg "
                  f"({' / '.join(f'{v:.2f}' for v in final / base[0])}x); at once "
                  f"{' / '.join(f'{v:.3f}' for v in now)} deg; {seconds:.1f} s "
                  f"({seconds / base[1]:.2f}x)"
                  + (f"; {', '.join(f'{k} {v}' for k, v in sorted(reasons.items()))}"
                     if reasons else ""), flush=True)


if __name__ == "__main__":
    main()
