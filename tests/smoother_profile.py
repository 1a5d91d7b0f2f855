"""Where the smoother's time goes, solving at every frame and at keyframes:
``python tests/smoother_profile.py [frames] [seed]``.

On the smoother benchmark's room scene (the shipped three-segment robot, 1 px, 10% outliers,
30 fps, lag 1 s, uncertainty off), one stream each way under :mod:`cProfile` (after one
unprofiled run that compiles the kernels). Prints the total and, per stage, the cumulative
seconds and calls: the window's iSAM2 updates (inside them gtsam's own time, and the Python
callbacks of the projection and landmark factors), the live factors built for each update, the
make-room stage (commits), the predict stage (the frame's fit to known points), the keyframe
decisions, the end of the stream and the residual test. cProfile slows Python code more than
gtsam's: read the shares, not the seconds.
"""

from __future__ import annotations

import cProfile
import pstats
import sys
import warnings

from apcc_graph.bench.smoother import ROBOT_FILE, room_simulation
from apcc_graph.estimation.keyframes import KeyframeRule
from apcc_graph.estimation.smoother import FixedLagSmoother
from apcc_graph.estimation.smoother_options import SmootherOptions, WindowOptions
from apcc_graph.io.robot_file import load_robot

STAGES = (
    ("fixed_lag.py", "update", "iSAM2 updates"),
    ("projection.py", "error_func", "  projection factor callbacks"),
    ("landmark.py", "error_func", "  landmark factor callbacks"),
    ("projection_tracks.py", "live_factors", "live factors built"),
    ("core.py", "_make_room", "make room (commits)"),
    ("core.py", "_predict", "predict (fit to known points)"),
    ("keyframing.py", "decide", "keyframe decisions"),
    ("core.py", "finish", "finish"),
    ("fit_monitor.py", "final", "residual test"),
)


def stream(robot, seq, rule: KeyframeRule | None) -> None:
    """One smoother over the sequence."""
    smoother = FixedLagSmoother(robot, theta0=seq.thetas[0], settings=SmootherOptions(
        window=WindowOptions(uncertainty=False), keyframes=rule))
    for f in range(seq.n_frames):
        smoother.update(seq.frame(f))
    smoother.finish()


def main() -> None:
    """Profile both ways; print the stages."""
    frames = int(sys.argv[1]) if len(sys.argv) > 1 else 300
    seed = int(sys.argv[2]) if len(sys.argv) > 2 else 0
    warnings.simplefilter("ignore")
    robot = load_robot(ROBOT_FILE)
    seq = room_simulation(robot, frames, 0.1, seed).sequence
    stream(robot, seq.head(30), KeyframeRule())  # compiles the kernels
    for name, rule in (("every frame", None), ("keyframes", KeyframeRule())):
        profile = cProfile.Profile()
        profile.enable()
        stream(robot, seq, rule)
        profile.disable()
        stats = pstats.Stats(profile).stats  # type: ignore[attr-defined]
        gtsam_own = sum(v[2] for k, v in stats.items()
                        if k[2] == "<built-in method gtsam.gtsam.update>")
        total = sum(v[2] for v in stats.values())
        print(f"{name}: {total:.2f} s profiled; gtsam's own update {gtsam_own:.2f} s")
        for file, function, label in STAGES:
            found = [v for k, v in stats.items() if k[0].endswith("/" + file) and k[2] == function]
            if found:
                calls, seconds = sum(v[1] for v in found), sum(v[3] for v in found)
                print(f"  {label:<34} {seconds:7.2f} s {calls:7d} calls")


if __name__ == "__main__":
    main()
