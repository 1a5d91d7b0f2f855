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

Layout: per-row arrays inside this module and :mod:`factors.projection` keep the row index
*last* (``R`` as ``(3, 3, N)``, points as ``(3, N)``): numpy's einsum over small leading axes
is then 10-25x faster than over trailing ones. The public functions take the usual row-first
arrays.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numpy.typing import ArrayLike, NDArray

from apcc_graph.model.arrays import FloatArray, IntArray

MIN_DEPTH = 0.02
"""Metres: a point closer than this in front of a camera it is seen from is not a valid point."""
MIN_INVERSE_DEPTH = 1e-3
"""1/metres: a point's inverse depth from its track's first camera stays above this (1 km); a
track whose rays meet behind the cameras (noise without parallax) keeps its point there."""
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


def cut_tracks(frames: ArrayLike, track_ids: ArrayLike, max_frames: int | None) -> IntArray:
    """New track ids that cut every track into pieces of at most ``max_frames`` frames
    (counted from the track's first frame), each piece its own track; ``None`` keeps them.

    The ids stay non-negative and distinct between pieces of different tracks.
    """
    frames = np.asarray(frames, dtype=np.int64)
    ids = np.asarray(track_ids, dtype=np.int64)
    if max_frames is None or len(ids) == 0:
        return ids.copy()
    if max_frames < 1:
        raise ValueError(f"max_frames = {max_frames}: expected at least 1 frame")
    unique, inverse = np.unique(ids, return_inverse=True)
    first = np.full(len(unique), np.iinfo(np.int64).max)
    np.minimum.at(first, inverse, frames)
    piece = (frames - first[inverse]) // max_frames
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


def _world_rays(obs: TrackObservations, Rb: FloatArray) -> FloatArray:
    """``(3, N)`` unit rays of the rows in the world frame."""
    rays = np.einsum("ijn,jn->in", Rb, np.vstack([obs.xy_t, np.ones(len(obs))]))
    return rays / np.linalg.norm(rays, axis=0)


def _initial_points(obs: TrackObservations, Rb: FloatArray, ob: FloatArray,
                    weights: FloatArray) -> FloatArray:
    """``(3, T)`` weighted midpoint of each track's rays, pulled weakly to DEFAULT_DEPTH along
    the mean ray (so that a track without parallax still gets a point in front of its
    cameras)."""
    rays = _world_rays(obs, Rb)
    w = np.where(weights > 0.0, weights, 1e-3)
    P = np.eye(3)[:, :, None] - rays[:, None, :] * rays[None, :, :]
    A = segment_sum(w * P, obs.starts)
    b = segment_sum(w * np.einsum("ijn,jn->in", P, ob), obs.starts)
    mean_ray = segment_sum(w * rays, obs.starts)
    mean_ray /= np.maximum(np.linalg.norm(mean_ray, axis=0), 1e-12)
    centre = segment_sum(w * ob, obs.starts) / segment_sum(w, obs.starts)
    lam = 1e-4 * np.einsum("iit->t", A)
    b = b + lam * (centre + DEFAULT_DEPTH * mean_ray)
    A = A + lam * np.eye(3)[:, :, None]
    return np.linalg.solve(np.moveaxis(A, -1, 0), b.T[..., None])[..., 0].T


def _segment_median(values: FloatArray, tracks: IntArray, starts: IntArray) -> FloatArray:
    """Per-track (lower) median of each row of ``values`` ``(d, N)``: ``(d, T)``."""
    out = np.empty((values.shape[0], len(starts) - 1))
    middle = starts[:-1] + (starts[1:] - starts[:-1] - 1) // 2
    for c in range(values.shape[0]):
        order = np.lexsort((values[c], tracks))
        out[c] = values[c, order[middle]]
    return out


def robust_weights_from_rays(obs: TrackObservations, R: FloatArray) -> FloatArray:
    """Rows whose world ray is far from their track's median ray get weight 0, the rest 1.

    ``R``: ``(N, 3, 3)`` camera orientations (or row-last ``(3, 3, N)``). A wrong
    association's pixel is anywhere in the image, tens of degrees off; a true observation's
    ray turns only by the parallax of the camera's motion. "Far" is five robust standard
    deviations of the track's ray angles, and at least 2 degrees.
    """
    Rb = R if R.shape[:2] == (3, 3) and R.shape[-1] == len(obs) else np.moveaxis(R, 0, -1)
    rays = _world_rays(obs, Rb)
    median = _segment_median(rays, obs.tracks, obs.starts)
    median /= np.maximum(np.linalg.norm(median, axis=0), 1e-12)
    angle = np.arccos(np.clip(np.einsum("in,in->n", rays, median[:, obs.tracks]), -1.0, 1.0))
    spread = _segment_median(angle[None], obs.tracks, obs.starts)[0]
    limit = np.maximum(5.0 * 1.4826 * spread, np.radians(2.0))
    return (angle <= limit[obs.tracks]).astype(float)


def robust_triangulate(
    obs: TrackObservations,
    R: FloatArray,
    o: FloatArray,
    weights: FloatArray,
    points: FloatArray | None = None,
    scale: float = 3.0,
    rounds: int = 3,
) -> tuple[FloatArray, FloatArray]:
    """Each track's point, robust to wrong associations; and every row's residual norm.

    Starts from the rows whose rays agree with their track's median ray
    (:func:`robust_weights_from_rays`) when no ``points`` are given, then reweights by the
    Cauchy weight ``1 / (1 + (|r| / scale)^2)`` of each row's whitened residual for ``rounds``
    rounds of :func:`triangulate`. Rows with ``weights`` 0 stay out.

    Args:
        obs: the tracks.
        R, o: ``(N, 3, 3)``, ``(N, 3)`` camera pose of each row.
        weights: ``(N,)`` row weights (0: left out).
        points: ``(T, 3)`` starting points, or ``None``.
        scale: Cauchy scale (pixel-noise units).
        rounds: reweighting rounds.

    Returns:
        ``(T, 3)`` points and ``(N,)`` whitened residual norms at them (``inf`` behind the
        camera).
    """
    Rb, ob = rows_last(R, o)
    pts = None if points is None else np.ascontiguousarray(points.T)
    w = weights * (robust_weights_from_rays(obs, Rb) if points is None else 1.0)
    for _ in range(rounds):
        pts = triangulate_rows(obs, Rb, ob, w, pts, iterations=4)
        norms = _norms(project_rows(obs, Rb, ob, pts[:, obs.tracks]))
        w = weights / (1.0 + (norms / scale) ** 2)
    pts = triangulate_rows(obs, Rb, ob, w, pts, iterations=10)
    return pts.T.copy(), _norms(project_rows(obs, Rb, ob, pts[:, obs.tracks]))


def _norms(proj: Projection) -> FloatArray:
    return np.where(proj.valid, np.sqrt(proj.r[0] ** 2 + proj.r[1] ** 2), np.inf)


def residual_norms_at(obs: TrackObservations, R: FloatArray, o: FloatArray,
                      points: FloatArray) -> FloatArray:
    """``|r_k|`` of every row at the given ``(T, 3)`` points (``inf`` where the point is
    behind the camera)."""
    Rb, ob = rows_last(R, o)
    return _norms(project_rows(obs, Rb, ob, np.ascontiguousarray(points.T)[:, obs.tracks]))


def triangulate(
    obs: TrackObservations,
    R: FloatArray,
    o: FloatArray,
    weights: FloatArray,
    points: FloatArray | None = None,
    iterations: int = 10,
    tolerance: float = 1e-7,
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
    Rb, ob = rows_last(R, o)
    pts = None if points is None else np.ascontiguousarray(points.T)
    return triangulate_rows(obs, Rb, ob, weights, pts, iterations, tolerance).T.copy()


def triangulate_rows(obs: TrackObservations, Rb: FloatArray, ob: FloatArray, weights: FloatArray,
                 points: FloatArray | None, iterations: int = 10,
                 tolerance: float = 1e-6) -> FloatArray:
    """:func:`triangulate`, row-last: ``Rb`` ``(3, 3, N)``, ``ob`` ``(3, N)``, points
    ``(3, T)`` in and out."""
    starts, tracks = obs.starts, obs.tracks
    anchor = starts[:-1]
    Ra, oa = Rb[:, :, anchor], ob[:, anchor]
    if points is None:
        points = _initial_points(obs, Rb, ob, weights)
    v = np.einsum("jit,jt->it", Ra, points - oa)
    bad = ~(v[2] > MIN_DEPTH)
    v[:, bad] = np.vstack([obs.xy_t[:, anchor[bad]], np.ones(bad.sum())]) * DEFAULT_DEPTH
    params = np.vstack([v[0] / v[2], v[1] / v[2], 1.0 / v[2]])  # (alpha, beta, rho), (3, T)
    sw = np.sqrt(weights)
    live = weights > 0.0

    def evaluate(prm: FloatArray, jacobian: bool):
        ray = np.vstack([prm[0], prm[1], np.ones(prm.shape[1])])
        Rray = np.einsum("ijt,jt->it", Ra, ray)
        p = oa + Rray / prm[2]
        proj = project_rows(obs, Rb, ob, p[:, tracks])
        r = proj.r * sw
        behind = ~proj.valid & live
        cost = segment_sum(r[0] ** 2 + r[1] ** 2 + behind * 1e12, starts)
        if not jacobian:
            return cost, p, None, None
        # d p / d (alpha, beta, rho) per track, (3, 3, T).
        dp = np.empty((3, 3, prm.shape[1]))
        dp[:, 0] = Ra[:, 0] / prm[2]
        dp[:, 1] = Ra[:, 1] / prm[2]
        dp[:, 2] = -Rray / prm[2] ** 2
        # J = W dm/dq R^T dp, per row (2, 3, N).
        Jp = np.einsum("ain,jin->ajn", proj.whitened_dm(obs.whiten_t) * sw, Rb)
        J = np.einsum("ajn,jkn->akn", Jp, dp[:, :, tracks])
        N = segment_sum(np.einsum("akn,aln->kln", J, J), starts)
        g = segment_sum(np.einsum("akn,an->kn", J, r), starts)
        return cost, p, N, g

    lam = np.full(params.shape[1], 1e-3)
    cost, p, N, g = evaluate(params, True)
    eye = np.eye(3)[:, :, None]
    for _ in range(iterations):
        diag = np.maximum(np.einsum("iit->it", N), 1e-12)
        A = N + lam * diag[:, None, :] * eye
        At = np.moveaxis(A, -1, 0)
        step = -np.linalg.solve(At, g.T[..., None])[..., 0].T
        # Where the step would cross the inverse-depth floor, hold rho there and take the
        # model's best step in (alpha, beta) alone: the exact minimiser under the bound.
        low = params[2] + step[2] < MIN_INVERSE_DEPTH
        if low.any():
            d_rho = MIN_INVERSE_DEPTH - params[2, low]
            rhs = g[:2, low] + A[:2, 2, low] * d_rho
            step[:2, low] = -np.linalg.solve(At[low][:, :2, :2], rhs.T[..., None])[..., 0].T
            step[2, low] = d_rho
        trial = params + step
        new_cost, new_p, _, _ = evaluate(trial, False)
        better = new_cost <= cost
        params = np.where(better, trial, params)
        p = np.where(better, new_p, p)
        cost = np.where(better, new_cost, cost)
        lam = np.clip(np.where(better, lam * 0.3, lam * 10.0), 1e-9, 1e9)
        if np.max(np.abs(step), initial=0.0) < tolerance:
            break
        if better.any():  # a rejected step leaves that track's system as it was
            cost, p, N, g = evaluate(params, True)
    return p
