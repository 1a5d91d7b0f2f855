"""Outlier decisions that do not depend on the robot's model: a rotation-only RANSAC between
consecutive frames of one camera (``docs/estimation.md``, "Outliers without the model").

Between two consecutive frames a tip camera turns far more than it moves relative to what it
sees, so the bearings of the points both frames see are related by one rotation, up to a small
parallax: ``a_i ~ R b_i`` (``a`` in the earlier frame, ``b`` in the later one, unit vectors).
Two bearings fix ``R`` (Kabsch); the rotation that agrees with most pairs within ``threshold``
(radians of bearing) wins, is refitted to its inliers, and the pairs within ``threshold`` of it
are kept. An observation is an inlier when it agrees with the frame before or the frame after.

The decisions need neither the angles nor the model, so a real robot's departure from its
kinematic model cannot turn true observations into outliers, as residuals at the model's
camera poses do from a start a few degrees off. The threshold bounds the parallax tolerated
between consecutive frames; an outlier closer than that to the rotation survives this test and
is left to the residual test at the solution.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from apcc_graph.model.arrays import FloatArray

__all__ = ["kabsch", "pair_inliers", "relative_rotation"]


def kabsch(a: FloatArray, b: FloatArray) -> FloatArray:
    """Rotations ``R`` minimising ``sum_i |a_i - R b_i|^2``, batched.

    scipy's ``Rotation.align_vectors`` solves one problem per call; RANSAC scores all its
    hypotheses of a frame pair in one call here.

    Args:
        a, b: ``(..., n, 3)`` paired vectors.

    Returns:
        ``(..., 3, 3)`` proper rotations.
    """
    H = np.swapaxes(b, -1, -2) @ a
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(np.swapaxes(Vt, -1, -2) @ np.swapaxes(U, -1, -2)))
    D = np.zeros(d.shape + (3, 3))
    D[..., 0, 0] = D[..., 1, 1] = 1.0
    D[..., 2, 2] = np.where(d == 0.0, 1.0, d)
    return np.swapaxes(Vt, -1, -2) @ D @ np.swapaxes(U, -1, -2)


def relative_rotation(a: FloatArray, b: FloatArray, threshold: float,
                      rng: np.random.Generator, iterations: int = 64
                      ) -> tuple[FloatArray | None, NDArray[np.bool_]]:
    """The rotation ``R`` with ``a_i ~ R b_i`` for most pairs, by 2-point RANSAC.

    Args:
        a, b: ``(n, 3)`` unit bearings of the same points in two frames.
        threshold: a pair agrees when ``|a_i - R b_i| < threshold`` (radians, small angles).
        rng: the sampling's random generator.
        iterations: hypotheses drawn.

    Returns:
        ``R`` (``None`` with fewer than 3 pairs) and the ``(n,)`` inlier mask.
    """
    n = len(a)
    if n < 3:
        return None, np.zeros(n, dtype=bool)
    first = rng.integers(0, n, iterations)
    second = (first + rng.integers(1, n, iterations)) % n
    pick = np.stack([first, second], axis=1)
    R = kabsch(a[pick], b[pick])
    err = np.linalg.norm(a[None] - b[None] @ np.swapaxes(R, -1, -2), axis=-1)
    inliers = err < threshold
    best = inliers[int(np.argmax(inliers.sum(axis=1)))]
    R_best = None
    for _ in range(2):  # refit to the inliers, then once more to the refit's inliers
        if best.sum() < 2:
            return None, np.zeros(n, dtype=bool)
        R_best = kabsch(a[best], b[best])
        best = np.linalg.norm(a - b @ R_best.T, axis=1) < threshold
    return R_best, best


def pair_inliers(frames: ArrayLike, tracks: ArrayLike, bearings: ArrayLike,
                 threshold: float = 0.02, seed: int = 0) -> NDArray[np.bool_]:
    """One camera's observations that agree with a neighbouring frame (module docstring).

    Args:
        frames: ``(N,)`` frame of each observation.
        tracks: ``(N,)`` track of each observation; rows sorted by (track, frame).
        bearings: ``(N, 3)`` bearing of each observation in the camera frame (any length).
        threshold: the agreement threshold (radians of bearing).
        seed: the sampling's seed (the decisions are the same bytes for the same seed).

    Returns:
        ``(N,)`` inlier mask.

    Raises:
        ValueError: inconsistent lengths, or rows not sorted by (track, frame).
    """
    frames = np.asarray(frames, dtype=np.int64)
    tracks = np.asarray(tracks, dtype=np.int64)
    bear = np.asarray(bearings, dtype=float).reshape(-1, 3)
    if not len(frames) == len(tracks) == len(bear):
        raise ValueError(f"frames, tracks and bearings have {len(frames)}, {len(tracks)}, "
                         f"{len(bear)} rows: expected one each per observation")
    order = np.lexsort((frames, tracks))
    if np.any(order != np.arange(len(order))):
        raise ValueError("rows must be sorted by (track, frame)")
    bear = bear / np.linalg.norm(bear, axis=1, keepdims=True)
    rng = np.random.default_rng(seed)
    pair = np.flatnonzero((tracks[1:] == tracks[:-1]) & (frames[1:] == frames[:-1] + 1))
    later = frames[pair + 1]
    order = np.argsort(later, kind="stable")
    pair, later = pair[order], later[order]
    keep = np.zeros(len(frames), dtype=bool)
    for group in np.split(pair, np.flatnonzero(np.diff(later)) + 1):
        _, agree = relative_rotation(bear[group], bear[group + 1], threshold, rng)
        keep[group[agree]] = True
        keep[group[agree] + 1] = True
    return keep
