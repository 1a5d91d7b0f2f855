"""The projection factor in joint space: every observation once, each track's point eliminated.

Variables: one ``Vector(S)`` per frame, the angles of all S segments (radians); key
:func:`frame_key`. The camera on segment ``c`` depends on the first ``c + 1`` of them
(:mod:`factors.camera_chain`); the robot base poses are known inputs.

Residual (:mod:`factors.track_points`): ``r_k = W_k (m(R^T (p_t - o)) - x_k)`` per observation,
the pixel reprojection error in units of the pixel noise. Each track's point ``p_t`` is a
nuisance: for the current angles it is re-triangulated (weighted least squares) and eliminated
by the Schur complement, so the factor's cost is ``sum_k w_k |r_k|^2`` minimised over the points
(variable projection), and its Gauss-Newton system in the angles is

    H = sum_k Jt_k^T Jt_k - sum_t B_t C_t^-1 B_t^T,    g = sum_k Jt_k^T r_k - sum_t B_t C_t^-1 b_t

with ``Jt_k = d r_k / d theta`` (point held fixed in the world), ``Jp_k = d r_k / d p_t``,
``C_t = sum_k Jp_k^T Jp_k``, ``B_t = sum_k Jt_k^T Jp_k`` (one block row per observation) and
``b_t = sum_k Jp_k^T r_k``: exactly the system bundle adjustment solves after eliminating the
points, and the information the Cramer-Rao bound of the angles counts. Row weights ``w_k``
(robust decisions, 0 for an outlier) are held fixed while the factor is linearised; the
estimators update them between solves (graduated non-convexity).

gtsam sees a factor over a chunk of tracks (:class:`ProjectionFactor`): its Jacobian is the
Cholesky factor ``A`` of ``H`` (``A^T A = H``), its error ``e`` solves ``A^T e = g`` and one more
row carries the rest of the cost, so ``|A dx + e|^2`` is the factor's Gauss-Newton model and
``|e|^2`` its cost. One Python callback per chunk and linearisation, vectorised over the chunk's
observations (Python factors run serially).

Jacobian convention: the tangent space of a ``Vector`` is the identity (``x + dx``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import gtsam
import numpy as np
import scipy.linalg
from numpy.typing import ArrayLike, NDArray

from apcc_graph.segment import Segment
from factors.camera_chain import camera_poses
from factors.track_points import MIN_DEPTH, TrackObservations, project, segment_sum, triangulate

FloatArray = NDArray[np.float64]


def frame_key(frame: int) -> int:
    """The graph key of frame ``frame``'s angles (a ``Vector(S)``)."""
    return int(gtsam.symbol("x", frame))


@dataclass(frozen=True)
class ReducedSystem:
    """The Gauss-Newton system of a chunk of tracks in the angles, points eliminated.

    Attributes:
        H: ``(D, D)`` information, ``D = frames x (camera + 1)``, frame-major.
        g: ``(D,)`` gradient of half the cost.
        cost: weighted sum of squared whitened residuals at the optimal points.
        points: ``(T, 3)`` the points (world, metres).
        residuals: ``(N,)`` unweighted whitened residual norms per row (pixel-noise units);
            ``inf`` where the point is behind the camera.
    """

    H: FloatArray
    g: FloatArray
    cost: float
    points: FloatArray
    residuals: FloatArray


@dataclass(frozen=True)
class CameraChain:
    """What fixes one camera's pose given the angles: its segments, mounting, base poses."""

    segments: tuple[Segment, ...]  # segments 0..c
    tip_T_cam: FloatArray
    world_T_base: FloatArray | None  # (F, 4, 4) over the whole sequence, or None
    psis: FloatArray | None  # (F, S) bending-plane angles, or None

    def poses(self, thetas: FloatArray, first: int,
              derivatives: bool) -> tuple[FloatArray, FloatArray | None]:
        """Poses (and derivatives) of frames ``first .. first + len(thetas) - 1``."""
        n = len(self.segments)
        rows = slice(first, first + len(thetas))
        base = None if self.world_T_base is None else self.world_T_base[rows]
        psis = None if self.psis is None else self.psis[rows, :n]
        return camera_poses(thetas[:, :n], self.segments, self.tip_T_cam, base, psis,
                            derivatives)


def _residuals(obs: TrackObservations, R: FloatArray, o: FloatArray, points: FloatArray
               ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    q, m, dm = project(R, o, points[obs.tracks])
    r = np.einsum("nij,nj->ni", obs.whiten, m - obs.xy)
    valid = q[:, 2] > MIN_DEPTH
    return q, r, dm, valid


def residual_norms(obs: TrackObservations, chain: CameraChain, thetas: FloatArray, first: int,
                   weights: FloatArray, points: FloatArray | None = None
                   ) -> tuple[FloatArray, FloatArray]:
    """Whitened residual norms per row at re-triangulated points, and the points.

    Args:
        obs: the tracks; their frames lie in ``first .. first + len(thetas) - 1``.
        chain: the camera's chain.
        thetas: ``(F', S)`` angles of those frames.
        first: the frame of ``thetas[0]``.
        weights: ``(N,)`` row weights used to triangulate.
        points: starting points (previous solution) or ``None``.
    """
    poses, _ = chain.poses(thetas, first, derivatives=False)
    lf = obs.frames - first
    R, o = poses[lf, :3, :3], poses[lf, :3, 3]
    points = triangulate(obs, R, o, weights, points)
    _, r, _, valid = _residuals(obs, R, o, points)
    return np.where(valid, np.linalg.norm(r, axis=1), np.inf), points


def reduced_system(obs: TrackObservations, chain: CameraChain, thetas: FloatArray, first: int,
                   weights: FloatArray, points: FloatArray | None = None,
                   jacobians: bool = True, refine_points: bool = True) -> ReducedSystem:
    """The chunk's reduced Gauss-Newton system (see the module docstring).

    Args:
        obs: the chunk's tracks; their frames lie in ``first .. first + len(thetas) - 1``.
        chain: the camera's chain.
        thetas: ``(F', S)`` angles of those frames (radians).
        first: the frame of ``thetas[0]``.
        weights: ``(N,)`` row weights (robust decisions; 0 leaves a row out).
        points: ``(T, 3)`` starting points for the triangulation (a previous solution).
        jacobians: build ``H`` and ``g`` (otherwise they are empty and only the cost is
            computed).
        refine_points: triangulate (default); ``False`` uses ``points`` as they are (the
            Fisher information at known points, for the Cramer-Rao bound).
    """
    n = len(chain.segments)
    n_frames = len(thetas)
    poses, d_poses = chain.poses(thetas, first, derivatives=jacobians)
    lf = obs.frames - first
    R, o = poses[lf, :3, :3], poses[lf, :3, 3]
    if refine_points or points is None:
        points = triangulate(obs, R, o, weights, points)
    q, r_raw, dm, valid = _residuals(obs, R, o, points)
    norms = np.where(valid, np.linalg.norm(r_raw, axis=1), np.inf)
    sw = np.sqrt(np.where(valid, weights, 0.0))
    r = r_raw * sw[:, None]
    if not jacobians:
        return ReducedSystem(np.zeros((0, 0)), np.zeros(0), float(np.sum(r * r)), points, norms)
    assert d_poses is not None
    WA = np.einsum("nij,njk->nik", obs.whiten, dm) * sw[:, None, None]  # W dm/dq, weighted
    Jp = np.einsum("nik,nlk->nil", WA, R)  # d r / d p = W dm/dq R^T
    d = points[obs.tracks] - o
    dR, do = d_poses[lf, :, :3, :3], d_poses[lf, :, :3, 3]
    # q = R^T (p - o): dq/dtheta_j = dR_j^T (p - o) - R^T do_j.
    dq = np.einsum("njba,nb->nja", dR, d) - np.einsum("nba,njb->nja", R, do)
    Jt = np.einsum("nik,njk->nij", WA, dq)  # (N, 2, n)

    # Frame blocks of sum_k Jt^T Jt and sum_k Jt^T r.
    Hk = np.einsum("nki,nkj->nij", Jt, Jt).reshape(len(lf), n * n)
    gk = np.einsum("nki,nk->ni", Jt, r)
    H_blocks = np.stack([np.bincount(lf, Hk[:, c], n_frames) for c in range(n * n)], axis=1)
    g = np.stack([np.bincount(lf, gk[:, c], n_frames) for c in range(n)], axis=1).ravel()
    D = n_frames * n
    H = np.zeros((D, D))
    for i in range(n):
        for j in range(n):
            H[np.arange(i, D, n), np.arange(j, D, n)] = H_blocks[:, i * n + j]

    # Schur complement of the points: with C_t = L_t L_t^T, V_k = B_k L_t^-T and
    # y_t = L_t^-1 b_t, the correction is -V V^T and the gradient's -V y.
    C = segment_sum(np.einsum("nki,nkj->nij", Jp, Jp), obs.starts)
    C += (1e-9 * np.trace(C, axis1=1, axis2=2) + 1e-12)[:, None, None] * np.eye(3)
    b = segment_sum(np.einsum("nki,nk->ni", Jp, r), obs.starts)
    L_inv = np.linalg.inv(np.linalg.cholesky(C))
    y = np.einsum("tij,tj->ti", L_inv, b)
    B = np.einsum("nki,nkj->nij", Jt, Jp)  # (N, n, 3)
    V = np.einsum("nja,nba->njb", B, L_inv[obs.tracks])
    M = np.zeros((D, 3 * obs.n_tracks))
    rows = (lf * n)[:, None, None] + np.arange(n)[None, :, None]
    cols = (3 * obs.tracks)[:, None, None] + np.arange(3)[None, None, :]
    M[rows, cols] = V
    H -= M @ M.T
    g -= M @ y.ravel()
    cost = float(np.sum(r * r) - np.sum(y * y))
    return ReducedSystem(H, g, max(cost, 0.0), points, norms)


def compress(H: FloatArray, g: FloatArray, cost: float) -> tuple[FloatArray, FloatArray]:
    """``A`` ``(D + 1, D)`` and ``e`` ``(D + 1,)`` with ``A^T A = H``, ``A^T e = g`` and
    ``|e|^2 = cost`` (when ``cost >= g^T H^-1 g``, as it is for a least-squares cost).

    ``H`` is positive semi-definite; a relative jitter of ``1e-12`` keeps its Cholesky factor
    defined where a chunk leaves some direction unobserved (it adds no information to speak of).
    """
    D = len(g)
    jitter = 1e-12 * max(float(np.max(np.diag(H), initial=0.0)), 1e-300)
    U = scipy.linalg.cholesky(H + jitter * np.eye(D), lower=False, check_finite=False)
    e = scipy.linalg.solve_triangular(U, g, trans="T", check_finite=False)
    rest = cost - float(e @ e)
    A = np.zeros((D + 1, D), order="F")
    A[:D] = U
    return A, np.append(e, np.sqrt(max(rest, 0.0)))


class ProjectionFactor:
    """One camera's chunk of tracks as a gtsam factor over the frames they span.

    Args:
        obs: the tracks (rows of a contiguous range of frames).
        chain: the camera's chain.
        n_segments: S, the dimension of each frame's angle vector.
        weights: ``(N,)`` row weights; the array is used in place, so an estimator can
            update the robust decisions between solves.

    The frames spanned are ``first .. last``; the factor's keys are their :func:`frame_key`.
    The latest points are kept and start the next triangulation.
    """

    def __init__(self, obs: TrackObservations, chain: CameraChain, n_segments: int,
                 weights: FloatArray | None = None) -> None:
        if len(obs) == 0:
            raise ValueError("a projection factor needs at least one observation")
        self.obs, self.chain, self.n_segments = obs, chain, n_segments
        self.weights = np.ones(len(obs)) if weights is None else weights
        self.first = int(obs.frames.min())
        self.last = int(obs.frames.max())
        self.frames = np.arange(self.first, self.last + 1)
        self.keys = [frame_key(int(f)) for f in self.frames]
        self.points: FloatArray | None = None
        self.n = len(chain.segments)
        self.dim = len(self.frames) * self.n + 1

    def thetas(self, values: gtsam.Values) -> FloatArray:
        """``(F', S)`` the chunk's angles in ``values``."""
        return np.array([values.atVector(k) for k in self.keys])

    def system(self, thetas: FloatArray, jacobians: bool = True) -> ReducedSystem:
        """The reduced system at ``thetas`` (and remember the points)."""
        out = reduced_system(self.obs, self.chain, thetas, self.first, self.weights,
                             self.points, jacobians)
        self.points = out.points
        return out

    def residual_norms(self, thetas: FloatArray) -> FloatArray:
        """Whitened residual norms of every row at ``thetas`` (for robust decisions)."""
        norms, self.points = residual_norms(self.obs, self.chain, thetas, self.first,
                                            self.weights, self.points)
        return norms

    def error_func(self, this: gtsam.CustomFactor, values: gtsam.Values,
                   H: list[np.ndarray] | None) -> np.ndarray:
        """gtsam's callback: compressed error and, when asked, the Jacobian blocks."""
        thetas = self.thetas(values)
        out = self.system(thetas, jacobians=H is not None)
        if H is None:
            e = np.zeros(self.dim)
            e[-1] = np.sqrt(out.cost)
            return e
        A, e = compress(out.H, out.g, out.cost)
        n, S = self.n, self.n_segments
        for i in range(len(self.keys)):
            block = np.zeros((self.dim, S), order="F")
            block[:, :n] = A[:, i * n:(i + 1) * n]
            H[i] = block
        return e

    def factor(self) -> gtsam.CustomFactor:
        """The ``gtsam.CustomFactor`` (unit noise: the residuals are already whitened)."""
        return gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(self.dim), self.keys,
                                  self.error_func)


def chunk_tracks(obs: TrackObservations, frames_per_chunk: int = 15) -> list[NDArray[np.int64]]:
    """Group a camera's tracks into chunks (compact indices) by the frame they start in.

    Tracks starting within ``frames_per_chunk`` frames of each other share a chunk, and long
    tracks (longer than four chunks) get chunks of their own length class, so that a chunk's
    span, and so its dense block, stays close to its tracks' own length.
    """
    if obs.n_tracks == 0:
        return []
    start = obs.frames[obs.starts[:-1]]
    end = obs.frames[obs.starts[1:] - 1]
    length = end - start + 1
    span_class = np.ceil(np.log2(np.maximum(length / (4 * frames_per_chunk), 1.0)))
    key = np.column_stack([start // frames_per_chunk, span_class])
    _, inverse = np.unique(key, axis=0, return_inverse=True)
    inverse = inverse.ravel()
    return [np.flatnonzero(inverse == c) for c in range(inverse.max() + 1)]


def build_observations(camera: int, frames: ArrayLike, track_ids: ArrayLike, xy: ArrayLike,
                       whiten: ArrayLike, keep: Sequence[bool] | NDArray[np.bool_] | None = None
                       ) -> TrackObservations:
    """:meth:`TrackObservations.build` over the rows ``keep`` (default all)."""
    frames, track_ids = np.asarray(frames), np.asarray(track_ids)
    xy, whiten = np.asarray(xy), np.asarray(whiten)
    if keep is not None:
        keep = np.asarray(keep, dtype=bool)
        frames, track_ids, xy, whiten = frames[keep], track_ids[keep], xy[keep], whiten[keep]
    return TrackObservations.build(camera, frames, track_ids, xy, whiten)
