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

__all__ = ["draw_pairs", "kabsch", "kabsch_of", "pair_inliers", "relative_rotation"]


def kabsch(a: FloatArray, b: FloatArray) -> FloatArray:
    """Rotations ``R`` minimising ``sum_i |a_i - R b_i|^2``, batched.

    scipy's ``Rotation.align_vectors`` solves one problem per call; RANSAC scores all its
    hypotheses of a frame pair in one call here.

    Args:
        a, b: ``(..., n, 3)`` paired vectors.

    Returns:
        ``(..., 3, 3)`` proper rotations.
    """
    return kabsch_of(np.swapaxes(b, -1, -2) @ a)


def kabsch_of(H: FloatArray) -> FloatArray:
    """The rotations of :func:`kabsch` from the correlations ``H = sum_i b_i a_i^T``
    (``(..., 3, 3)``), so that sums over ragged groups can be formed first."""
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(np.swapaxes(Vt, -1, -2) @ np.swapaxes(U, -1, -2)))
    D = np.zeros(d.shape + (3, 3))
    D[..., 0, 0] = D[..., 1, 1] = 1.0
    D[..., 2, 2] = np.where(d == 0.0, 1.0, d)
    return np.swapaxes(Vt, -1, -2) @ D @ np.swapaxes(U, -1, -2)


def draw_pairs(sizes: NDArray[np.int64], rng: np.random.Generator,
               iterations: int = 64) -> NDArray[np.int64]:
    """RANSAC's minimal samples: ``(G, iterations, 2)`` two distinct indices into each of
    ``G`` groups of ``sizes`` pairs (zeros for a group of fewer than two)."""
    sizes = np.asarray(sizes, dtype=np.int64)
    u = rng.random((2, len(sizes), iterations))
    n = sizes[:, None]
    first = np.minimum((u[0] * n).astype(np.int64), n - 1)
    offset = 1 + np.minimum((u[1] * (n - 1)).astype(np.int64), n - 2)
    pick = np.stack([first, (first + offset) % np.maximum(n, 1)], axis=-1)
    return np.where((n >= 2)[..., None], pick, 0)


def relative_rotation(a: FloatArray, b: FloatArray, threshold: float,
                      rng: np.random.Generator | None = None, iterations: int = 64,
                      pick: NDArray[np.int64] | None = None
                      ) -> tuple[FloatArray | None, NDArray[np.bool_]]:
    """The rotation ``R`` with ``a_i ~ R b_i`` for most pairs, by 2-point RANSAC: one group,
    the reference of :func:`pair_inliers`' batched decisions.

    Args:
        a, b: ``(n, 3)`` unit bearings of the same points in two frames.
        threshold: a pair agrees when ``|a_i - R b_i| < threshold`` (radians, small angles).
        rng: the sampling's random generator (when ``pick`` is not given).
        iterations: hypotheses drawn.
        pick: ``(iterations, 2)`` the hypotheses' samples (:func:`draw_pairs`), instead of
            drawing them.

    Returns:
        ``R`` (``None`` with fewer than 3 pairs) and the ``(n,)`` inlier mask.
    """
    n = len(a)
    if n < 3:
        return None, np.zeros(n, dtype=bool)
    if pick is None:
        if rng is None:
            raise ValueError("relative_rotation needs rng or pick")
        pick = draw_pairs(np.array([n]), rng, iterations)[0]
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
                 threshold: float = 0.02, seed: int = 0,
                 iterations: int = 64) -> NDArray[np.bool_]:
    """One camera's observations that agree with a neighbouring frame (module docstring).

    Every frame pair's RANSAC runs at once: the hypotheses of all pairs are scored in one pass
    per hypothesis index, and the refits sum each pair's correlations before one batched SVD.
    The decisions are :func:`relative_rotation`'s on each pair with the same samples.

    Args:
        frames: ``(N,)`` frame of each observation.
        tracks: ``(N,)`` track of each observation; rows sorted by (track, frame).
        bearings: ``(N, 3)`` bearing of each observation in the camera frame (any length).
        threshold: the agreement threshold (radians of bearing).
        seed: the sampling's seed (the decisions are the same bytes for the same seed).
        iterations: hypotheses drawn per frame pair.

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
    keep = np.zeros(len(frames), dtype=bool)
    pair = np.flatnonzero((tracks[1:] == tracks[:-1]) & (frames[1:] == frames[:-1] + 1))
    if not len(pair):
        return keep
    later = frames[pair + 1]
    order = np.argsort(later, kind="stable")
    pair, later = pair[order], later[order]
    starts = np.flatnonzero(np.r_[True, np.diff(later) != 0])
    sizes = np.diff(np.r_[starts, len(pair)])
    group = np.repeat(np.arange(len(sizes)), sizes)
    agree = _consensus(bear[pair], bear[pair + 1], group, starts, sizes,
                       draw_pairs(sizes, np.random.default_rng(seed), iterations), threshold)
    keep[pair[agree]] = True
    keep[pair[agree] + 1] = True
    return keep


def _consensus(a: FloatArray, b: FloatArray, group: NDArray[np.int64],
               starts: NDArray[np.int64], sizes: NDArray[np.int64], pick: NDArray[np.int64],
               threshold: float) -> NDArray[np.bool_]:
    """:func:`relative_rotation`'s inlier masks of all groups at once: ``a, b`` the ``(P, 3)``
    unit pairs sorted by group, ``group`` each pair's group, ``starts`` and ``sizes`` each
    group's rows, ``pick`` ``(G, iterations, 2)`` the samples within each group.

    For unit vectors ``|a - R b|^2 = 2 - 2 vec(R) . vec(a b^T)``: with each group's ``a b^T``
    laid out in a zero-padded ``(G, n_max, 9)`` block, scoring every hypothesis of every group
    is one batched matrix product."""
    G = len(sizes)
    at = np.arange(len(group)) - starts[group]
    ab = np.zeros((G, int(sizes.max()), 9))
    ab[group, at] = (a[:, :, None] * b[:, None, :]).reshape(-1, 9)
    cut = 1.0 - 0.5 * threshold**2  # |a - R b| < threshold  <=>  vec(R) . vec(a b^T) > cut
    rows = starts[:, None, None] + pick
    R = kabsch(a[rows], b[rows]).reshape(G, -1, 9)  # (G, iterations, 9)
    best = np.argmax(np.sum(ab @ np.swapaxes(R, 1, 2) > cut, axis=1), axis=1)
    Rg = R[np.arange(G), best]
    alive = sizes >= 3
    outer = b[:, :, None] * a[:, None, :]  # each pair's b a^T, whose sums refit (kabsch_of)

    def agree() -> NDArray[np.bool_]:
        return alive[group] & (np.einsum("pk,pk->p", ab[group, at], Rg[group]) > cut)

    for _ in range(2):  # refit to the winner's inliers, then once more to the refit's
        inlier = agree()
        alive &= np.bincount(group, weights=inlier, minlength=G) >= 2
        inlier &= alive[group]
        H = np.add.reduceat(outer * inlier[:, None, None], starts, axis=0)
        Rg = np.where(alive[:, None, None], kabsch_of(H), np.eye(3)).reshape(G, 9)
    return agree()
