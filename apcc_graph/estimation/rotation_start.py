"""A start from the tip cameras' rotations (``docs/estimation.md``, "A start from the rotations").

A tip camera measures how it turned between two frames far better than how it moved, and it
does so without the robot's model: the bearings ``a`` (earlier frame) and ``b`` (later) of the
points both frames see satisfy ``a ~ R b`` up to a small parallax, and a 2-point RANSAC finds
``R`` (:func:`~apcc_graph.frontend.rotation_pairs.relative_rotation`). Chained from the start's
camera rotations (the model's at the given start) they give every camera's rotation at every
frame, ``world_R_cam(f + 1) = world_R_cam(f) R``, and through the mount the tip's. Each frame's
vector is then the one whose model tip rotations fit those (Gauss-Newton on the rotation vectors
of ``R_model^T R_chained``, warm-started from the frame before, with a weak pull towards it that
holds what no camera tells: a segment without a camera and no motion).

Where the model departs from the real robot, its tips' positions at the bends that fit their
rotations are off by a few millimetres (the rotation floor), but that is the basin the images
point to: the exact chain, fitting positions and rotations together through the model, can land
tens of millimetres away. What limits it: a tip camera also translates as it turns, and the
rotation-only model ignores the parallax, about 8% of the turn against a room 1-2 m away
(measured on a struck real segment turning 10-16 deg a frame: 0.8-1.5 deg per frame pair),
which the chain accumulates; OpenCV's essential matrix from the same 50-150 points did no
better. A camera pair with fewer than :data:`MIN_PAIRS` shared tracks (or no
consensus) holds that camera's rotation; its rows then count for nothing until it sees again.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from apcc_graph.estimation.graph import observed_cameras
from apcc_graph.estimation.options import GraphOptions
from apcc_graph.frontend.rotation_pairs import relative_rotation
from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.parameterisation import Bending
from apcc_graph.model.sequence import Sequence

MIN_PAIRS = 8
"""Shared tracks a frame pair needs for its rotation."""
THRESHOLD = 0.01
"""The RANSAC agreement threshold (radians of bearing; the parallax tolerated)."""
TURN_SIGMA = np.radians(0.2)
"""How well a chained camera rotation is taken to be known (radians per axis)."""
HOLD = np.radians(5.0)
"""The pull of each frame's vector towards the frame before (radians): far weaker than what a
seeing camera tells, it only holds the components no camera constrains."""
STEPS = 8
"""Gauss-Newton steps per frame."""


def chained_rotations(sequence: Sequence, start_rotations: dict[int, FloatArray],
                      options: GraphOptions | None = None, seed: int = 0
                      ) -> dict[int, tuple[FloatArray, np.ndarray]]:
    """Camera -> ``(F, 3, 3)`` its ``world_R_cam`` chained from ``start_rotations[cam]`` (its
    rotation at frame 0) by the frame-to-frame RANSAC rotations, and ``(F,)`` whether that
    frame's rotation was measured (False once a pair failed, until a pair succeeds again)."""
    rng = np.random.default_rng(seed)
    out = {}
    for obs in observed_cameras(sequence, options or GraphOptions()):
        cam = obs.camera
        bearings = np.column_stack([obs.xy, np.ones(len(obs.xy))])
        bearings /= np.linalg.norm(bearings, axis=1, keepdims=True)
        pair = np.flatnonzero((obs.tracks[1:] == obs.tracks[:-1])
                              & (obs.frames[1:] == obs.frames[:-1] + 1))
        later = obs.frames[pair + 1]
        R = np.empty((sequence.n_frames, 3, 3))
        R[0] = start_rotations[cam]
        known = np.zeros(sequence.n_frames, dtype=bool)
        known[0] = True
        order = np.argsort(later, kind="stable")
        pair, later = pair[order], later[order]
        bounds = np.searchsorted(later, np.arange(sequence.n_frames + 1))
        for f in range(1, sequence.n_frames):
            rows = pair[bounds[f]:bounds[f + 1]]
            rel = None
            if len(rows) >= MIN_PAIRS:
                rel, inliers = relative_rotation(bearings[rows], bearings[rows + 1], THRESHOLD,
                                                 rng)
                if rel is not None and inliers.sum() < MIN_PAIRS:
                    rel = None
            R[f] = R[f - 1] if rel is None else R[f - 1] @ rel
            known[f] = rel is not None
        out[cam] = (R, known)
    return out


def rotation_start(sequence: Sequence, x0: FloatArray, bending: Bending,
                   options: GraphOptions | None = None, seed: int = 0) -> FloatArray:
    """``(F, dim)`` frame vectors of ``bending`` whose tip rotations fit the cameras' chained
    rotations, from ``x0`` (the start's vector, at frame 0) (module docstring)."""
    robot = sequence.robot
    x0 = np.asarray(x0, dtype=float)
    base = np.eye(4) if sequence.world_T_base is None else np.asarray(sequence.world_T_base)
    mounts = {c: robot.cameras[c].tip_T_cam[:3, :3] for c in robot.camera_segments}  # type: ignore[union-attr]

    def tip_rotations(x: FloatArray) -> FloatArray:
        T, out = base, np.empty((robot.n_segments, 3, 3))
        for j in range(robot.n_segments):
            T = T @ bending.transform(x, j)
            out[j] = T[:3, :3]
        return out

    first = tip_rotations(x0)
    chained = chained_rotations(sequence, {c: first[c] @ mounts[c] for c in mounts}, options,
                                seed)
    cams = sorted(chained)
    x = np.empty((sequence.n_frames, bending.dim))
    x[0] = x0
    for f in range(1, sequence.n_frames):
        seen = [c for c in cams if chained[c][1][f]]
        targets = {c: chained[c][0][f] @ mounts[c].T for c in seen}
        x[f] = _fit(tip_rotations, targets, x[f - 1])
    return x


def _fit(tip_rotations: object, targets: dict[int, FloatArray], previous: FloatArray
         ) -> FloatArray:
    """The vector near ``previous`` whose tip rotations fit ``targets`` (segment -> rotation)."""
    x = previous.copy()
    if not targets:
        return x

    def rows(v: FloatArray) -> FloatArray:
        tips = tip_rotations(v)  # type: ignore[operator]
        rel = np.stack([tips[c].T @ R for c, R in targets.items()])
        fit = Rotation.from_matrix(rel).as_rotvec().ravel()
        return np.concatenate([fit / TURN_SIGMA, (v - previous) / HOLD])

    eps = 1e-6
    for _ in range(STEPS):
        r = rows(x)
        J = np.column_stack([(rows(x + eps * e) - r) / eps for e in np.eye(len(x))])
        step = np.linalg.lstsq(J, -r, rcond=None)[0]
        x = x + step
        if np.max(np.abs(step)) < 1e-9:
            break
    return x
