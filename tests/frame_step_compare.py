"""The two candidates for a keyframe smoother's per-frame step, side by side:
``python tests/frame_step_compare.py [frames] [every] [seeds...]``.

On the smoother benchmark's room scene (the shipped three-segment robot, 1 px, 10% outliers,
30 fps), every ``every``-th frame is a keyframe whose vector is known as well as a smoother
knows it (the truth plus 0.05 deg of noise: an idealisation of the window's final values).
Each other frame is estimated from the constant-velocity prediction of the two frames before
it (each candidate from its own estimates), by:

- ``points``: the fit to known points (:func:`~apcc_graph.estimation.initial_guess.refine`),
  each track's point triangulated from its rows in the keyframes so far (at least two);
- ``epipolar``: the generalized epipolar constraints against the last keyframe
  (:func:`~apcc_graph.estimation.epipolar_step.epipolar_step`).

Prints per seed the RMS error of the non-keyframes per segment (deg) and the median time of
a step (ms; the step alone: this script's slow triangulation of the points is not counted).
Both candidates see the same frames; neither sees the truth beyond the keyframes.
"""

from __future__ import annotations

import math
import sys
import time

import numpy as np

from apcc_graph.bench.smoother import NOISE_PX, ROBOT_FILE, room_simulation
from apcc_graph.estimation.epipolar_step import epipolar_step
from apcc_graph.estimation.initial_guess import FrameRows, refine
from apcc_graph.factors.camera_chain import CameraChain
from apcc_graph.io.robot_file import load_robot
from apcc_graph.model.parameterisation import Bending

KEY_NOISE = math.radians(0.05)


def _midpoints(origins: list[np.ndarray], rays: list[np.ndarray]) -> np.ndarray | None:
    """The point closest to rays ``o + s d`` (least squares), or None when they are parallel."""
    A, b = np.zeros((3, 3)), np.zeros(3)
    for o, d in zip(origins, rays, strict=True):
        P = np.eye(3) - np.outer(d, d)
        A += P
        b += P @ o
    if np.linalg.cond(A) > 1e6:
        return None
    return np.linalg.solve(A, b)


def run(seed: int, frames: int, every: int) -> None:
    """One seed: both candidates over the sequence, one printed line."""
    robot = load_robot(ROBOT_FILE)
    seq = room_simulation(robot, frames, 0.1, seed).sequence
    bending = Bending.fixed(robot.segments)
    chains = {c: CameraChain(Bending.fixed(robot.segments[:c + 1]),
                             robot.cameras[c].tip_T_cam, None) for c in robot.camera_segments}
    focal = robot.cameras[0].fx
    rng = np.random.default_rng(seed)
    truth = seq.thetas
    keys = list(range(0, frames, every))
    known = {k: truth[k] + rng.normal(0.0, KEY_NOISE, truth.shape[1]) for k in keys}
    rows = {}
    for c, tr in seq.tracks.items():
        b = seq.bearings(c)
        rows[c] = (tr.frames, tr.track_ids, b)
    est = {"points": {}, "epipolar": {}}
    times = {"points": [], "epipolar": []}
    for name in est:
        est[name].update(known)
    for n in range(every + 1, frames):
        if n in known:
            continue
        k = max(key for key in keys if key < n)
        for name, out in est.items():
            prev, older = out[n - 1], out.get(n - 2, out[n - 1])
            guess = prev + (prev - older)
            t0 = time.perf_counter()
            if name == "epipolar":
                bearings = {}
                for c, (fr, ids, b) in rows.items():
                    _, i_k, i_n = np.intersect1d(ids[fr == k], ids[fr == n], return_indices=True)
                    if len(i_k) >= 5:
                        bearings[c] = (b[fr == k][i_k], b[fr == n][i_n])
                step = epipolar_step(chains, k, known[k], n, guess, bearings,
                                     sigma=math.sqrt(2.0) * NOISE_PX / focal,
                                     prior_sigma=math.radians(5.0))
                out[n] = step.x
            else:
                frame_rows = []
                for c, (fr, ids, b) in rows.items():
                    now = fr == n
                    pts, xy = [], []
                    for tid, bn in zip(ids[now], b[now], strict=True):
                        seen = [g for g in keys if g <= k and np.any((fr == g) & (ids == tid))]
                        if len(seen) < 2:
                            continue
                        o, d = [], []
                        for g in seen:
                            pose = chains[c].poses(known[g][None], g, False)[0][0]
                            ray = b[(fr == g) & (ids == tid)][0]
                            o.append(pose[:3, 3])
                            d.append(pose[:3, :3] @ ray)
                        p = _midpoints(o, d)
                        if p is not None:
                            pts.append(p)
                            xy.append(bn[:2] / bn[2])
                    if pts:
                        frame_rows.append(FrameRows(c, np.array(pts), np.array(xy),
                                                    np.broadcast_to(focal / NOISE_PX * np.eye(2),
                                                                    (len(pts), 2, 2))))
                t0 = time.perf_counter()  # the step alone, not this script's triangulation
                out[n] = refine(guess, robot, bending, None, frame_rows, 3.5).thetas
            times[name].append(time.perf_counter() - t0)
    others = [n for n in range(every + 1, frames) if n not in known]
    line = [f"seed {seed}, a keyframe in {every}:"]
    for name, out in est.items():
        err = np.array([out[n] - truth[n] for n in others])
        rms = np.degrees(np.sqrt(np.mean(err**2, axis=0)))
        line.append(f"{name} {' / '.join(f'{v:.3f}' for v in rms)} deg, "
                    f"{1e3 * float(np.median(times[name])):.1f} ms")
        line.append(";")
    print(" ".join(line[:-1]), flush=True)


def main() -> None:
    """Parse the arguments and run every seed."""
    frames = int(sys.argv[1]) if len(sys.argv) > 1 else 300
    every = int(sys.argv[2]) if len(sys.argv) > 2 else 3
    for seed in [int(s) for s in sys.argv[3:]] or [0, 1, 2]:
        run(seed, frames, every)


if __name__ == "__main__":
    main()
