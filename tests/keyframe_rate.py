"""How often the keyframe rule picks a keyframe on the smoother benchmark's scene:
``python tests/keyframe_rate.py [frames] [seeds...]``.

Simulates the room scene of ``apcc-graph bench smoother`` (the shipped three-segment robot,
1 px, 10% outliers, 30 fps), walks its frames with the default
:class:`~apcc_graph.estimation.keyframes.KeyframeRule`, each camera's rotation since the last
keyframe from the rotation-only RANSAC on the shared tracks' bearings (no model, no truth),
and prints per seed the keyframes per second, the longest gap between keyframes and how often
each reason fired.
"""

from __future__ import annotations

import sys
from collections import Counter

import numpy as np

from apcc_graph.bench.smoother import ROBOT_FILE, room_simulation
from apcc_graph.estimation.keyframes import KeyframeRule, keyframe_reasons, view_change
from apcc_graph.frontend.rotation_pairs import relative_rotation
from apcc_graph.io.robot_file import load_robot


def main() -> None:
    """Print one line per seed."""
    frames = int(sys.argv[1]) if len(sys.argv) > 1 else 600
    seeds = [int(s) for s in sys.argv[2:]] or [0, 1, 2]
    rule = KeyframeRule()
    robot = load_robot(ROBOT_FILE)
    for seed in seeds:
        seq = room_simulation(robot, frames, 0.1, seed).sequence
        rows = {c: (t.frames, t.track_ids, seq.bearings(c)) for c, t in seq.tracks.items()}
        rng = np.random.default_rng(seed)
        keys, reasons = [0], Counter()
        for f in range(1, seq.n_frames):
            changes = {}
            for cam, (fr, ids, bear) in rows.items():
                at_key, now = fr == keys[-1], fr == f
                shared, i_key, i_now = np.intersect1d(ids[at_key], ids[now],
                                                      return_indices=True)
                f_key, f_now = bear[at_key][i_key], bear[now][i_now]
                R, inl = relative_rotation(f_key, f_now, 0.01, rng)
                if R is None:
                    R, inl = np.eye(3), np.zeros(len(shared), dtype=bool)
                changes[cam] = view_change(f_key[inl], f_now[inl], R, int(at_key.sum()),
                                           rule.min_shared)
            why = keyframe_reasons(rule, seq.timestamps[f] - seq.timestamps[keys[-1]], changes)
            if why:
                keys.append(f)
                reasons.update(r.split(" of ")[0] for r in why)
        gaps = np.diff(keys)
        duration = seq.timestamps[-1] - seq.timestamps[0]
        every = seq.n_frames / len(keys)
        print(f"seed {seed}: {len(keys)} keyframes in {seq.n_frames} frames "
              f"({len(keys) / duration:.1f} a second, one frame in {every:.1f}); "
              f"gaps {int(gaps.min())}-{int(gaps.max())} frames; reasons "
              + ", ".join(f"{k} {v}" for k, v in sorted(reasons.items())), flush=True)


if __name__ == "__main__":
    main()
