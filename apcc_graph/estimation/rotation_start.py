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
better. A camera whose pair into a frame was not measured (fewer than :data:`MIN_PAIRS` shared
tracks, or no consensus) counts for nothing in that frame, and its chain starts again from the
model's camera rotation at the vector fitted to the frame before: after a blind spell its
relative rotations are right again, but what it turned while blind is lost (the full graph,
through the translations, is what can tell it).
"""

from __future__ import annotations

from collections.abc import Mapping
from functools import partial

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from apcc_graph.estimation.chain import chain_vectors
from apcc_graph.estimation.graph import observed_cameras
from apcc_graph.estimation.model_noise import approximate, segment_sigmas
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


def frame_rotations(sequence: Sequence, options: GraphOptions | None = None, seed: int = 0
                    ) -> dict[int, tuple[FloatArray, np.ndarray]]:
    """Camera -> ``(F, 3, 3)`` the rotation ``R`` with ``a ~ R b`` from each frame ``f - 1``
    (bearings ``a``) to ``f`` (``b``; row 0 the identity), and ``(F,)`` whether it was
    measured (:data:`MIN_PAIRS` shared tracks and as many inliers)."""
    rng = np.random.default_rng(seed)
    out = {}
    for obs in observed_cameras(sequence, options or GraphOptions()):
        bearings = np.column_stack([obs.xy, np.ones(len(obs.xy))])
        bearings /= np.linalg.norm(bearings, axis=1, keepdims=True)
        pair = np.flatnonzero((obs.tracks[1:] == obs.tracks[:-1])
                              & (obs.frames[1:] == obs.frames[:-1] + 1))
        later = obs.frames[pair + 1]
        order = np.argsort(later, kind="stable")
        pair, later = pair[order], later[order]
        bounds = np.searchsorted(later, np.arange(sequence.n_frames + 1))
        rel = np.tile(np.eye(3), (sequence.n_frames, 1, 1))
        measured = np.zeros(sequence.n_frames, dtype=bool)
        for f in range(1, sequence.n_frames):
            rows = pair[bounds[f]:bounds[f + 1]]
            if len(rows) < MIN_PAIRS:
                continue
            R, inliers = relative_rotation(bearings[rows], bearings[rows + 1], THRESHOLD, rng)
            if R is not None and inliers.sum() >= MIN_PAIRS:
                rel[f], measured[f] = R, True
        out[obs.camera] = (rel, measured)
    return out


def chained_rotations(sequence: Sequence, start_rotations: dict[int, FloatArray],
                      options: GraphOptions | None = None, seed: int = 0
                      ) -> dict[int, tuple[FloatArray, np.ndarray]]:
    """Camera -> ``(F, 3, 3)`` its ``world_R_cam`` chained from ``start_rotations[cam]`` (its
    rotation at frame 0) by :func:`frame_rotations` (held where a pair was not measured), and
    ``(F,)`` whether each frame's pair was measured (frame 0: True)."""
    out = {}
    for cam, (rel, measured) in frame_rotations(sequence, options, seed).items():
        R = np.empty_like(rel)
        R[0] = start_rotations[cam]
        for f in range(1, len(rel)):
            R[f] = R[f - 1] @ rel[f]
        known = measured.copy()
        known[0] = True
        out[cam] = (R, known)
    return out


def rotation_start(sequence: Sequence, x0: FloatArray, bending: Bending,
                   options: GraphOptions | None = None, seed: int = 0) -> FloatArray:
    """``(F, dim)`` frame vectors of ``bending`` whose tip rotations fit the cameras' chained
    rotations, from ``x0`` (the start's vector, at frame 0) (module docstring). A camera whose
    pair into frame ``f`` was measured has the target ``R_cam(f - 1) R``: its chained rotation
    at ``f - 1`` when that one was measured too, else (it was blind, or its tracks were all
    new) the model's at the vector fitted to ``f - 1``, from which its chain starts again."""
    robot = sequence.robot
    x0 = np.asarray(x0, dtype=float)
    tip_rotations = partial(_tip_rotations, bending, sequence.world_T_base)
    mounts = {c: robot.cameras[c].tip_T_cam[:3, :3]  # type: ignore[union-attr]
              for c in robot.camera_segments}

    pairs = frame_rotations(sequence, options, seed)
    first = tip_rotations(x0)
    chain = {c: first[c] @ mounts[c] for c in pairs}
    alive = dict.fromkeys(pairs, True)
    x = np.empty((sequence.n_frames, bending.dim))
    x[0] = x0
    for f in range(1, sequence.n_frames):
        targets = {}
        for c, (rel, measured) in pairs.items():
            if not measured[f]:
                alive[c] = False
                continue
            if not alive[c]:  # its chain starts again from the fit of the frame before
                chain[c] = tip_rotations(x[f - 1])[c] @ mounts[c]
                alive[c] = True
            chain[c] = chain[c] @ rel[f]
            targets[c] = chain[c] @ mounts[c].T
        x[f] = _fit(tip_rotations, targets, x[f - 1])
    return x


def propagated(sequence: Sequence, x0: FloatArray, bending: Bending, options: GraphOptions
               ) -> FloatArray:
    """``(F, dim)`` frame vectors from ``x0`` (frame 0's) for a solver to start from: those
    whose tip rotations fit the cameras' (:func:`rotation_start`) where ``options``' model
    noise says the model is materially off
    (:func:`~apcc_graph.estimation.model_noise.approximate`), else the exact model's chain
    (:func:`~apcc_graph.estimation.chain.chain_vectors`). The rule of the batch's
    ``init = "auto"``, for the unknown-start search's hypotheses (which the exact model
    refines). The smoother's re-acquisitions keep the chain: from the rotations, a 20-frame
    re-acquisition with a model noise of 5 mm / 2 deg ended degrees further off."""
    if approximate(segment_sigmas(options.model_sigma, sequence.robot)):
        return rotation_start(sequence, x0, bending, options)
    return chain_vectors(sequence, bending, x0, options.threshold_px)[0]


def _tip_rotations(bending: Bending, base: FloatArray | None, x: FloatArray) -> FloatArray:
    """``(S, 3, 3)`` every segment tip's ``world_R_tip`` at frame vector ``x``."""
    T = np.eye(4) if base is None else np.asarray(base, dtype=float)
    out = np.empty((bending.n_segments, 3, 3))
    for j in range(bending.n_segments):
        T = T @ bending.transform(x, j)
        out[j] = T[:3, :3]
    return out


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


def rotation_guess(prediction: FloatArray, bending: Bending, base: FloatArray | None,
                   before: Mapping[int, tuple[NDArray[np.int64], FloatArray, FloatArray]],
                   rows: Mapping[int, tuple[NDArray[np.int64], FloatArray, FloatArray]],
                   cameras_before: Mapping[int, FloatArray], mounts: Mapping[int, FloatArray],
                   rng: np.random.Generator) -> tuple[FloatArray, int]:
    """A stream's next frame from the rotations: each camera's ``world_R_cam`` in the frame
    before (``cameras_before``; the smoother's estimate) turned by its RANSAC rotation between
    the two frames' rows (``camera -> (track ids, normalised points, whitening)``), and the
    vector near ``prediction`` whose tip rotations fit those (``mounts``: camera ->
    ``tip_R_cam``). Returns the vector and how many cameras told it."""
    tip_rotations = partial(_tip_rotations, bending, base)

    targets = {}
    for cam, (ids, xy, _) in rows.items():
        if cam not in before or cam not in cameras_before:
            continue
        ids0, xy0, _ = before[cam]
        shared, i0, i1 = np.intersect1d(ids0, ids, return_indices=True)
        if len(shared) < MIN_PAIRS:
            continue
        a = np.column_stack([xy0[i0], np.ones(len(i0))])
        b = np.column_stack([xy[i1], np.ones(len(i1))])
        a /= np.linalg.norm(a, axis=1, keepdims=True)
        b /= np.linalg.norm(b, axis=1, keepdims=True)
        R, inliers = relative_rotation(a, b, THRESHOLD, rng)
        if R is None or inliers.sum() < MIN_PAIRS:
            continue
        targets[cam] = cameras_before[cam] @ R @ mounts[cam].T
    return _fit(tip_rotations, targets, np.asarray(prediction, dtype=float)), len(targets)
