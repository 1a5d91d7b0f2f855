"""Tracks of one tip camera and their observation model (the rows the projection factor
sees).

Observation model (``docs/estimation.md``): row k of a track sees the track's point ``p``
(world frame, metres) from camera pose ``world_T_cam = [R | o]`` as the undistorted normalised
image point ``x_k`` (``pixel = K distort(x_k)``)::

    q_k = R^T (p - o),   m(q) = (q_x / q_z, q_y / q_z),   r_k = W_k (m(q_k) - x_k)

``W_k = D_k / sigma_px`` whitens it: ``D_k`` is the 2x2 derivative of the pixel with respect to
``x`` at ``x_k`` (``diag(fx, fy)`` for a pinhole), so ``r_k`` is the pixel error in units of the
pixel noise, to first order, and ``|r_k|^2`` is chi-square with 2 degrees of freedom for an
inlier. Each track's point is found by :mod:`apcc_graph.factors.triangulation`.

Layout: per-row arrays inside this module, :mod:`apcc_graph.factors.triangulation` and
:mod:`apcc_graph.factors.reduced_system` keep the row index *last* (``R`` as ``(3, 3, N)``, points
as ``(3, N)``): numpy's einsum over small leading axes is then much faster than over trailing ones.
The public functions take the usual row-first arrays.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numpy.typing import ArrayLike, NDArray

from apcc_graph.model.arrays import FloatArray, IntArray

MIN_DEPTH = 0.02
"""Metres: a point closer than this in front of a camera it is seen from is not a valid point."""


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

    @cached_property
    def xy_t(self) -> FloatArray:
        """``(2, N)`` :attr:`xy`, row index last."""
        return np.ascontiguousarray(self.xy.T)

    @cached_property
    def whiten_t(self) -> FloatArray:
        """``(2, 2, N)`` :attr:`whiten`, row index last."""
        return np.ascontiguousarray(np.moveaxis(self.whiten, 0, -1))

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


def cut_tracks(frames: ArrayLike, track_ids: ArrayLike, max_frames: int | None,
               clock: ArrayLike | None = None) -> IntArray:
    """New track ids that cut every track into pieces of at most ``max_frames`` frames
    (counted from the track's first frame), each piece its own track; ``None`` keeps them.

    With ``clock`` (``(F,)``, non-decreasing, indexed by frame) a piece spans at most
    ``max_frames`` of its ticks instead of frames (e.g. a clock that barely ticks while the
    robot stands still: :func:`apcc_graph.estimation.image_motion.motion_clock`).

    The ids stay non-negative and distinct between pieces of different tracks.
    """
    frames = np.asarray(frames, dtype=np.int64)
    ids = np.asarray(track_ids, dtype=np.int64)
    if max_frames is None or len(ids) == 0:
        return ids.copy()
    if max_frames < 1:
        raise ValueError(f"max_frames = {max_frames}: expected at least 1 frame")
    time = frames.astype(float) if clock is None else np.asarray(clock, dtype=float)[frames]
    unique, inverse = np.unique(ids, return_inverse=True)
    first = np.full(len(unique), np.inf)
    np.minimum.at(first, inverse, time)
    piece = np.floor((time - first[inverse]) / max_frames + 1e-9).astype(np.int64)
    return inverse * (int(piece.max()) + 1) + piece


def segment_sum(values: FloatArray, starts: IntArray) -> FloatArray:
    """Sums of ``values`` over each track's rows along the *last* axis (``starts`` as in
    :class:`TrackObservations`): ``(..., N)`` in, ``(..., T)`` out."""
    if values.shape[-1] == 0:
        return np.zeros(values.shape[:-1] + (len(starts) - 1,))
    return np.add.reduceat(values, starts[:-1], axis=-1)


def rows_last(R: FloatArray, o: FloatArray) -> tuple[FloatArray, FloatArray]:
    """``(N, 3, 3)``, ``(N, 3)`` poses to the row-last ``(3, 3, N)``, ``(3, N)``."""
    return np.ascontiguousarray(np.moveaxis(R, 0, -1)), np.ascontiguousarray(o.T)


@dataclass(frozen=True)
class Projection:
    """Row-last projection of world points: ``q = R^T (p - o)``, ``m`` and whitened ``r``.

    Attributes:
        d: ``(3, N)`` ``p - o`` (world frame).
        q: ``(3, N)`` the point in the camera frame.
        iz: ``(N,)`` ``1 / q_z`` (depth clamped at :data:`MIN_DEPTH`).
        m: ``(2, N)`` the projection.
        r: ``(2, N)`` whitened residual ``W (m - x)``.
        valid: ``(N,)`` the point is in front of the camera.
    """

    d: FloatArray
    q: FloatArray
    iz: FloatArray
    m: FloatArray
    r: FloatArray
    valid: NDArray[np.bool_]

    @property
    def norms(self) -> FloatArray:
        """``(N,)`` ``|r|`` per row, ``inf`` where the point is behind the camera."""
        return np.where(self.valid, np.sqrt(self.r[0] ** 2 + self.r[1] ** 2), np.inf)

    def whitened_dm(self, whiten_t: FloatArray) -> FloatArray:
        """``(2, 3, N)`` ``W dm/dq``."""
        iz, m = self.iz, self.m
        out = np.empty((2, 3, len(iz)))
        out[:, 0] = whiten_t[:, 0] * iz
        out[:, 1] = whiten_t[:, 1] * iz
        out[:, 2] = -(whiten_t[:, 0] * m[0] + whiten_t[:, 1] * m[1]) * iz
        return out


def project_rows(obs: TrackObservations, Rb: FloatArray, ob: FloatArray,
                 points_b: FloatArray) -> Projection:
    """:class:`Projection` of each row's track point, row-last (``points_b`` ``(3, N)``)."""
    d = points_b - ob
    q = np.einsum("jin,jn->in", Rb, d)
    valid = q[2] > MIN_DEPTH
    iz = 1.0 / np.maximum(q[2], MIN_DEPTH)
    m = q[:2] * iz
    r = np.einsum("abn,bn->an", obs.whiten_t, m - obs.xy_t)
    return Projection(d, q, iz, m, r, valid)
