"""What a tracker option costs the offline smoother, and what it saves in tracking time:
``python tests/tracker_options.py [frames] [seeds] [options ...]``, e.g.
``python tests/tracker_options.py 600 1,2 "" motion_levels=1 window=15``.

For each seed, renders the live benchmark's three 640x480 videos (``apcc-graph bench live``'s
robot and room, 30 fps), then for each option set (``name=value`` pairs of
:class:`~apcc_graph.frontend.tracking.TrackerOptions` joined by ``;``; ``""``: the defaults)
tracks them (``apcc-graph track --video``; the time includes decoding) and runs the offline
smoother from the true start, as the benchmark's offline row does. Prints the tracking and
smoothing seconds and the RMS per segment against the simulated truth (deg).
"""

from __future__ import annotations

import sys
import tempfile
import time
import warnings
from dataclasses import fields
from pathlib import Path

import numpy as np
from threadpoolctl import threadpool_limits

from apcc_graph.bench.live import ROBOT_FILE, THETA0_SIGMA, render_videos
from apcc_graph.estimation.methods import estimate
from apcc_graph.frontend.recordings import track_recording, video_streams
from apcc_graph.frontend.tracking import TrackerOptions
from apcc_graph.io.robot_file import load_robot


def options_of(text: str) -> TrackerOptions:
    """``"window=15;motion_levels=1"`` -> the options (``""``: the defaults)."""
    types = {f.name: type(getattr(TrackerOptions(), f.name)) for f in fields(TrackerOptions)}
    values = {}
    for pair in filter(None, text.split(";")):
        name, value = pair.split("=")
        values[name] = value not in ("0", "false") if types[name] is bool else types[name](value)
    return TrackerOptions(**values)


def main() -> None:
    frames = int(sys.argv[1]) if len(sys.argv) > 1 else 600
    seeds = [int(s) for s in (sys.argv[2] if len(sys.argv) > 2 else "1").split(",")]
    configs = sys.argv[3:] or [""]
    robot = load_robot(ROBOT_FILE)
    warnings.simplefilter("ignore")
    for seed in seeds:
        with tempfile.TemporaryDirectory(prefix="apcc-options-") as tmp, \
                threadpool_limits(limits=1, user_api="blas"):
            files, truth = render_videos(Path(tmp), frames, seed)
            for config in configs:
                began = time.perf_counter()
                seq, _ = track_recording(video_streams(files), robot, options=options_of(config))
                tracked = time.perf_counter() - began
                began = time.perf_counter()
                result = estimate(seq, method="smoother", theta0=truth[0],
                                  theta0_sigma=THETA0_SIGMA, progress=False)
                smoothed = time.perf_counter() - began
                error = result.thetas - truth[:seq.n_frames]
                rms = np.degrees(np.sqrt(np.mean(error**2, axis=0)))
                print(f"seed {seed} {config or 'defaults':<28} tracking {tracked:5.1f} s, "
                      f"smoother {smoothed:5.1f} s, RMS {' / '.join(f'{v:.4f}' for v in rms)} "
                      "deg", flush=True)


if __name__ == "__main__":
    main()
