"""Tracks of one tip camera and the 3-D point behind each track (the nuisance the projection
factor eliminates).

Observation model (``docs/estimation.md``): row k of a track sees the track's point ``p``
(world frame, metres) from camera pose ``world_T_cam = [R | o]`` as the undistorted normalised
image point ``x_k`` (``pixel = K distort(x_k)``)::

    q_k = R^T (p - o),   m(q) = (q_x / q_z, q_y / q_z),   r_k = W_k (m(q_k) - x_k)

``W_k = D_k / sigma_px`` whitens it: ``D_k`` is the 2x2 derivative of the pixel with respect to
``x`` at ``x_k`` (``diag(fx, fy)`` for a pinhole), so ``r_k`` is the pixel error in units of the
pixel noise, to first order, and ``|r_k|^2`` is chi-square with 2 degrees of freedom for an
inlier.

:func:`triangulate` finds each track's point for given camera poses: weighted least squares of
its rows' ``r_k``, solved by Levenberg-Marquardt in inverse-depth coordinates anchored at the
track's first row (``p = o_a + R_a (alpha, beta, 1) / rho``), which stays well conditioned for the
small baselines of a tip camera; all tracks are solved at once (vectorised).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

MIN_DEPTH = 0.02
"""Metres: a point closer than this in front of a camera it is seen from is not a valid point."""
DEFAULT_DEPTH = 3.0
"""Metres: depth a track's point starts at when its rays do not fix it."""


@dataclass(frozen=True)
class TrackObservations:
    """One camera's observations grouped by track; each track has its own 3-D point.

    Attributes:
        camera: the segment the camera rides on (0-based).
        frames: ``(N,)`` frame of each row; rows are sorted by (track, frame).
        tracks: ``(N,)`` compact track index of each row, ``0..T-1``, non-decreasing.
        xy: ``(N, 2)`` undistorted normalised image coordinates.
        whiten: ``(N, 2, 2)`` ``W_k``: pixel Jacobian divided by the pixel noise.
        ids: ``(T,)`` the tracks' ids in the sequence.
        starts: ``(T + 1,)`` row offsets: track t owns rows ``starts[t]:starts[t+1]``.
    """

    camera: int
    frames: IntArray
    tracks: IntArray
    xy: FloatArray
    whiten: FloatArray
    ids: IntArray
    starts: IntArray

    @classmethod
    def build(cls, camera: int, frames: ArrayLike, track_ids: ArrayLike, xy: ArrayLike,
              whiten: ArrayLike) -> TrackObservations:
        """Group rows by track id (any order in; sorted by (track, frame) out).

        Raises:
            ValueError: inconsistent lengths, or a track seen twice in one frame.
        """
        frames = np.asarray(frames, dtype=np.int64)
        ids = np.asarray(track_ids, dtype=np.int64)
        xy = np.asarray(xy, dtype=float).reshape(-1, 2)
        whiten = np.asarray(whiten, dtype=float).reshape(-1, 2, 2)
        if not len(frames) == len(ids) == len(xy) == len(whiten):
            raise ValueError(f"camera {camera + 1}: frames, track ids, points and whitening "
                             f"have {len(frames)}, {len(ids)}, {len(xy)}, {len(whiten)} rows")
        order = np.lexsort((frames, ids))
        frames, ids, xy, whiten = frames[order], ids[order], xy[order], whiten[order]
        new = np.ones(len(ids), dtype=bool)
        new[1:] = ids[1:] != ids[:-1]
        if np.any(~new[1:] & (frames[1:] == frames[:-1])):
            raise ValueError(f"camera {camera + 1}: a track is observed twice in one frame")
        tracks = np.cumsum(new) - 1
        starts = np.append(np.flatnonzero(new), len(ids)).astype(np.int64)
        return cls(camera, frames, tracks.astype(np.int64), xy, whiten, ids[new], starts)

    @property
    def n_tracks(self) -> int:
        """Number of tracks T."""
        return len(self.ids)

    def __len__(self) -> int:
        return len(self.frames)

    def select(self, tracks: ArrayLike) -> TrackObservations:
        """The rows of the given tracks (compact indices, increasing), re-indexed."""
        tracks = np.asarray(tracks, dtype=np.int64)
        lengths = self.starts[tracks + 1] - self.starts[tracks]
        rows = np.repeat(self.starts[tracks] - np.cumsum(np.append(0, lengths[:-1])),
                         lengths) + np.arange(lengths.sum())
        new_tracks = np.repeat(np.arange(len(tracks)), lengths)
        starts = np.append(0, np.cumsum(lengths)).astype(np.int64)
        return TrackObservations(self.camera, self.frames[rows], new_tracks, self.xy[rows],
                                 self.whiten[rows], self.ids[tracks], starts)


def segment_sum(values: FloatArray, starts: IntArray) -> FloatArray:
    """Sums of ``values`` over each track's rows (``starts`` as in :class:`TrackObservations`)."""
    if len(values) == 0:
        return np.zeros((len(starts) - 1,) + values.shape[1:])
    return np.add.reduceat(values, starts[:-1], axis=0)


def project(R: FloatArray, o: FloatArray, points: FloatArray
            ) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Camera-frame points ``q``, projections ``m`` and ``dm/dq`` of world points per row.

    Args:
        R, o: ``(N, 3, 3)``, ``(N, 3)`` camera orientation and position per row.
        points: ``(N, 3)`` world points per row.

    Returns:
        ``q`` ``(N, 3)``, ``m`` ``(N, 2)`` and ``dm/dq`` ``(N, 2, 3)``. Depths below
        :data:`MIN_DEPTH` are clamped there (the caller marks such rows invalid).
    """
    q = np.einsum("nji,nj->ni", R, points - o)
    iz = 1.0 / np.maximum(q[:, 2], MIN_DEPTH)
    m = q[:, :2] * iz[:, None]
    dm = np.zeros((len(q), 2, 3))
    dm[:, 0, 0] = iz
    dm[:, 1, 1] = iz
    dm[:, :, 2] = -m * iz[:, None]
    return q, m, dm


def _initial_points(obs: TrackObservations, R: FloatArray, o: FloatArray,
                    weights: FloatArray) -> FloatArray:
    """Weighted midpoint of each track's rays, pulled weakly to DEFAULT_DEPTH along the mean
    ray (so that a track without parallax still gets a point in front of its cameras)."""
    rays = np.einsum("nij,nj->ni", R, np.column_stack([obs.xy, np.ones(len(obs))]))
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    w = np.where(weights > 0.0, weights, 1e-3)
    P = np.eye(3) - rays[:, :, None] * rays[:, None, :]
    A = segment_sum(w[:, None, None] * P, obs.starts)
    b = segment_sum(w[:, None] * np.einsum("nij,nj->ni", P, o), obs.starts)
    mean_ray = segment_sum(w[:, None] * rays, obs.starts)
    mean_ray /= np.maximum(np.linalg.norm(mean_ray, axis=1, keepdims=True), 1e-12)
    centre = segment_sum(w[:, None] * o, obs.starts) / segment_sum(w, obs.starts)[:, None]
    lam = 1e-4 * np.trace(A, axis1=1, axis2=2)[:, None]
    b = b + lam * (centre + DEFAULT_DEPTH * mean_ray)
    A = A + lam[:, :, None] * np.eye(3)
    return np.linalg.solve(A, b[..., None])[..., 0]


def triangulate(
    obs: TrackObservations,
    R: FloatArray,
    o: FloatArray,
    weights: FloatArray,
    points: FloatArray | None = None,
    iterations: int = 10,
    tolerance: float = 1e-9,
) -> FloatArray:
    """Each track's point: weighted least squares of its whitened reprojection errors.

    Args:
        obs: the tracks.
        R, o: ``(N, 3, 3)``, ``(N, 3)`` camera pose (``world_T_cam``) of each row.
        weights: ``(N,)`` row weights (0 leaves a row out).
        points: ``(T, 3)`` starting points (a previous solution); ``None`` to start from the
            rays' midpoints.
        iterations: most Levenberg-Marquardt iterations.
        tolerance: stop when no track's parameters move more than this (inverse depth in 1/m,
            normalised coordinates).

    Returns:
        ``(T, 3)`` world points (metres).
    """
    starts = obs.starts
    anchor = starts[:-1]
    Ra, oa = R[anchor], o[anchor]
    if points is None:
        points = _initial_points(obs, R, o, weights)
    v = np.einsum("tji,tj->ti", Ra, points - oa)
    bad = ~(v[:, 2] > MIN_DEPTH)
    v[bad] = np.column_stack([obs.xy[anchor[bad]], np.ones(bad.sum())]) * DEFAULT_DEPTH
    params = np.column_stack([v[:, 0] / v[:, 2], v[:, 1] / v[:, 2], 1.0 / v[:, 2]])
    track_of_row = obs.tracks
    sw = np.sqrt(weights)

    def evaluate(prm: FloatArray, jacobian: bool):
        ray = np.column_stack([prm[:, 0], prm[:, 1], np.ones(len(prm))])
        p = oa + np.einsum("tij,tj->ti", Ra, ray) / prm[:, 2:3]
        q, m, dm = project(R, o, p[track_of_row])
        r = np.einsum("nij,nj->ni", obs.whiten, m - obs.xy) * sw[:, None]
        behind = (q[:, 2] <= MIN_DEPTH) & (weights > 0.0)
        cost = segment_sum(np.einsum("ni,ni->n", r, r) + behind * 1e12, starts)
        if not jacobian:
            return cost, p, None, None
        dp = np.empty((len(prm), 3, 3))
        dp[:, :, 0] = Ra[:, :, 0] / prm[:, 2:3]
        dp[:, :, 1] = Ra[:, :, 1] / prm[:, 2:3]
        dp[:, :, 2] = -np.einsum("tij,tj->ti", Ra, ray) / prm[:, 2:3] ** 2
        # J = W dm/dq R^T dp/dparam, per row.
        WA = np.einsum("nij,njk->nik", obs.whiten, dm) * sw[:, None, None]
        J = np.einsum("nik,nlk,nlj->nij", WA, R, dp[track_of_row])
        N = segment_sum(np.einsum("nki,nkj->nij", J, J), starts)
        g = segment_sum(np.einsum("nki,nk->ni", J, r), starts)
        return cost, p, N, g

    lam = np.full(len(params), 1e-3)
    cost, p, N, g = evaluate(params, True)
    for _ in range(iterations):
        diag = np.einsum("tii->ti", N)
        A = N + (lam[:, None] * np.maximum(diag, 1e-12))[:, :, None] * np.eye(3)
        step = -np.linalg.solve(A, g[..., None])[..., 0]
        trial = params + step
        trial[:, 2] = np.maximum(trial[:, 2], 1e-6)  # keep the point in front of its anchor
        new_cost, _, _, _ = evaluate(trial, False)
        better = new_cost <= cost
        params = np.where(better[:, None], trial, params)
        lam = np.where(better, lam * 0.3, lam * 10.0)
        cost, p, N, g = evaluate(params, True)
        if np.max(np.abs(step), initial=0.0) < tolerance:
            break
    return p
