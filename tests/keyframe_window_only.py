"""The keyframe-only window measured against the smoother that keeps every frame:
``python tests/keyframe_window_only.py FRAMES SEED CONFIG...``, e.g.
``python tests/keyframe_window_only.py 300 0 all 9,0.09,9,0 0.1,0.2,0.03``.

Each CONFIG is ``all`` (every frame in the window) or a rule ``rotation[,max_interval[,
parallax[,survival]]]`` (radians, seconds; ``9,0.09,9,0``: every third frame by time alone).
On the smoother benchmark's room scene (1 px, 10% outliers, 30 fps, lag 1 s). Prints per
config the final RMS per segment (deg), that of the keyframes and of the frames between, the
RMS of the estimates returned at once, the time, and the keyframes' reasons. This branch
records a design that was measured and left out (frames between keyframes fitted to their
keyframes' values; their rows never enter the graph).
"""

import sys
import time

import numpy as np

from apcc_graph.bench.smoother import ROBOT_FILE, room_simulation
from apcc_graph.estimation.keyframes import KeyframeRule
from apcc_graph.estimation.smoother import FixedLagSmoother
from apcc_graph.estimation.smoother_options import SmootherOptions, WindowOptions
from apcc_graph.io.robot_file import load_robot


def main() -> None:
    frames, seed = int(sys.argv[1]), int(sys.argv[2])
    robot = load_robot(ROBOT_FILE)
    seq = room_simulation(robot, frames, 0.1, seed).sequence
    truth = seq.thetas
    for cfg in sys.argv[3:] or ["all", "0.1,0.2,0.03"]:
        rule = None
        if cfg != "all":
            values = [float(v) for v in cfg.split(",")]
            names = ["rotation", "max_interval", "parallax", "survival"]
            rule = KeyframeRule(**dict(zip(names, values)))
        s = SmootherOptions(window=WindowOptions(lag=1.0, uncertainty=False), keyframes=rule)
        sm = FixedLagSmoother(robot, theta0=truth[0], settings=s)
        start, now = time.perf_counter(), []
        for f in range(frames):
            now.append(sm.update(seq.frame(f)).thetas)
        out = sm.finish()
        seconds = time.perf_counter() - start
        est = np.array([fr.thetas for fr in out])
        between = np.array([fr.status[0] == "between" for fr in out])

        def rms(x, m=slice(None)):
            return np.round(np.degrees(np.sqrt(np.mean((x[m] - truth[m]) ** 2, axis=0))), 4)

        line = f"{cfg}: final {rms(est)} at once {rms(np.array(now))} {seconds:.1f} s"
        if between.any():
            line += (f"; keyframes {rms(est, ~between)} between {rms(est, between)}; "
                     f"{sm._keys.keyframes}/{frames} keyframes {sm._keys.reasons}")
        print(line, flush=True)


if __name__ == "__main__":
    main()
