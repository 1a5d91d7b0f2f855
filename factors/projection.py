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

Self-calibration: with calibration keys, the factor also depends on one ``Vector2`` per segment
``0..c``, that segment's ``(k, delta_max)`` (key :func:`calibration_key`); its columns come after
the frames' in ``H`` and ``g``, and the segments' values are read from those variables (clamped
to their valid range) instead of the chain's.

Jacobian convention: the tangent space of a ``Vector`` is the identity (``x + dx``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import gtsam
import numpy as np
import scipy.linalg
from numpy.typing import ArrayLike, NDArray

from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.segment import Segment, calibrated
from factors.camera_chain import camera_poses
from factors.track_points import (
    TrackObservations,
    project_rows,
    robust_triangulate,
    segment_sum,
    triangulate_rows,
)


def frame_key(frame: int) -> int:
    """The graph key of frame ``frame``'s angles (a ``Vector(S)``)."""
    return int(gtsam.symbol("x", frame))


def calibration_key(segment: int) -> int:
    """The graph key of segment ``segment``'s ``(k, delta_max)`` (a ``Vector2``; radians for
    ``delta_max``) when self-calibrating."""
    return int(gtsam.symbol("c", segment))




@dataclass(frozen=True)
class ReducedSystem:
    """The Gauss-Newton system of a chunk of tracks in the angles, points eliminated.

    Attributes:
        H: ``(D, D)`` information, ``D = frames x (camera + 1)``, frame-major.
        g: ``(D,)`` gradient of half the cost.
        cost: weighted sum of squared whitened residuals at the points (the triangulation's
            optimum), so the same angles always give the same cost.
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
    world_T_base: FloatArray | None  # (F, 4, 4) base poses of frames frame0.., or None
    psis: FloatArray | None  # (F, S) bending-plane angles of frames frame0.., or None
    frame0: int = 0  # the frame of world_T_base[0] and psis[0]

    def poses(self, thetas: FloatArray, first: int, derivatives: bool,
              calibration: bool = False) -> tuple:
        """Poses (and derivatives) of frames ``first .. first + len(thetas) - 1``; see
        :func:`factors.camera_chain.camera_poses`."""
        n = len(self.segments)
        rows = slice(first - self.frame0, first - self.frame0 + len(thetas))
        base = None if self.world_T_base is None else self.world_T_base[rows]
        psis = None if self.psis is None else self.psis[rows, :n]
        return camera_poses(thetas[:, :n], self.segments, self.tip_T_cam, base, psis,
                            derivatives, calibration)

    def with_segments(self, segments: Sequence[Segment]) -> CameraChain:
        """The same chain with other segment models (self-calibration)."""
        return CameraChain(tuple(segments), self.tip_T_cam, self.world_T_base, self.psis,
                           self.frame0)


def _row_poses(chain: CameraChain, thetas: FloatArray, first: int, frames: NDArray[np.int64],
               derivatives: bool, calibration: bool = False
               ) -> tuple[FloatArray, FloatArray, FloatArray | None, FloatArray | None]:
    """Row-last camera orientation ``(3, 3, N)``, position ``(3, N)``, pose derivatives
    ``(4, 4, n, N)`` of each row's frame and, with ``calibration``, their derivatives in
    ``(k_0, delta_0, k_1, ...)``, ``(4, 4, 2 n, N)``."""
    out = chain.poses(thetas, first, derivatives, calibration)
    poses, d_poses = out[0], out[1]
    lf = frames - first
    P = np.moveaxis(poses, 0, -1)[:, :, lf]
    dP = None if d_poses is None else np.moveaxis(d_poses, (0, 1), (-1, -2))[..., lf]
    dC = None
    if calibration:
        d_cal = out[2]
        F, n = d_cal.shape[:2]
        dC = np.moveaxis(d_cal.reshape(F, 2 * n, 4, 4), (0, 1), (-1, -2))[..., lf]
    return np.ascontiguousarray(P[:3, :3]), np.ascontiguousarray(P[:3, 3]), dP, dC


def residual_norms(obs: TrackObservations, chain: CameraChain, thetas: FloatArray, first: int,
                   weights: FloatArray, points: FloatArray | None = None
                   ) -> tuple[FloatArray, FloatArray]:
    """Whitened residual norms per row at re-triangulated points, and the ``(T, 3)`` points.

    Args:
        obs: the tracks; their frames lie in ``first .. first + len(thetas) - 1``.
        chain: the camera's chain.
        thetas: ``(F', S)`` angles of those frames.
        first: the frame of ``thetas[0]``.
        weights: ``(N,)`` row weights used to triangulate.
        points: starting points (previous solution) or ``None``.
    """
    Rb, ob, _, _ = _row_poses(chain, thetas, first, obs.frames, False)
    pts = triangulate_rows(obs, Rb, ob, weights, None if points is None else
                       np.ascontiguousarray(points.T))
    proj = project_rows(obs, Rb, ob, pts[:, obs.tracks])
    norms = np.where(proj.valid, np.sqrt(proj.r[0] ** 2 + proj.r[1] ** 2), np.inf)
    return norms, pts.T.copy()


def robust_residual_norms(obs: TrackObservations, chain: CameraChain, thetas: FloatArray,
                          first: int, weights: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Like :func:`residual_norms`, but each track's point is found robustly from scratch
    (:func:`factors.track_points.robust_triangulate`): the outlier decisions of a new
    estimate start here."""
    Rb, ob, _, _ = _row_poses(chain, thetas, first, obs.frames, False)
    points, norms = robust_triangulate(obs, np.moveaxis(Rb, -1, 0), ob.T, weights)
    return norms, points


def reduced_system(obs: TrackObservations, chain: CameraChain, thetas: FloatArray, first: int,
                   weights: FloatArray, points: FloatArray | None = None,
                   jacobians: bool = True, refine_points: bool = True,
                   calibration: bool = False, point_iterations: int = 10) -> ReducedSystem:
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
        calibration: add the ``2 n`` columns of the chain's segments' ``(k, delta_max)``
            after the frames' (``D = frames x n + 2 n``).
        point_iterations: most triangulation iterations from ``points`` (from scratch: 10).
            With one step from a previous solution the points are not exactly optimal; the
            system is then the joint Gauss-Newton system in (angles, points) with the points
            eliminated, whose angle step is as good, but whose ``cost`` is not minimised over
            the points (an estimator that compares costs, such as Levenberg-Marquardt, needs
            the default).
    """
    n = len(chain.segments)
    n_frames = len(thetas)
    Rb, ob, dP, dC = _row_poses(chain, thetas, first, obs.frames, jacobians,
                                jacobians and calibration)
    pts = None if points is None else np.ascontiguousarray(points.T)
    if refine_points or pts is None:
        pts = triangulate_rows(obs, Rb, ob, weights, pts,
                               10 if pts is None else point_iterations)
    proj = project_rows(obs, Rb, ob, pts[:, obs.tracks])
    norms = np.where(proj.valid, np.sqrt(proj.r[0] ** 2 + proj.r[1] ** 2), np.inf)
    sw = np.sqrt(np.where(proj.valid, weights, 0.0))
    r = proj.r * sw
    if not jacobians:
        return ReducedSystem(np.zeros((0, 0)), np.zeros(0), float(np.sum(r * r)), pts.T.copy(),
                             norms)
    assert dP is not None
    WA = proj.whitened_dm(obs.whiten_t) * sw  # (2, 3, N)
    Jp = np.einsum("ain,jin->ajn", WA, Rb)  # d r / d p = W dm/dq R^T
    # q = R^T (p - o): dq/dtheta_j = dR_j^T (p - o) - R^T do_j, (3, n, N).
    dq = (np.einsum("bijn,bn->ijn", dP[:3, :3], proj.d)
          - np.einsum("bin,bjn->ijn", Rb, dP[:3, 3]))
    Jt = np.einsum("ain,ijn->ajn", WA, dq)  # (2, n, N)

    lf = obs.frames - first
    # Frame blocks of sum_k Jt^T Jt and sum_k Jt^T r.
    Hk = np.einsum("ain,ajn->ijn", Jt, Jt).reshape(n * n, -1)
    gk = np.einsum("ain,an->in", Jt, r)
    D0 = n_frames * n
    D = D0 + (2 * n if calibration else 0)
    H = np.zeros((D, D))
    diag = np.arange(n_frames) * n
    for i in range(n):
        for j in range(n):
            H[diag + i, diag + j] = np.bincount(lf, Hk[i * n + j], n_frames)
    g = np.zeros(D)
    g[:D0] = np.stack([np.bincount(lf, gk[c], n_frames) for c in range(n)], axis=1).ravel()
    if calibration:
        assert dC is not None
        dqc = (np.einsum("bijn,bn->ijn", dC[:3, :3], proj.d)
               - np.einsum("bin,bjn->ijn", Rb, dC[:3, 3]))
        Jc = np.einsum("ain,ijn->ajn", WA, dqc)  # (2, 2n, N)
        cross = np.einsum("ain,acn->icn", Jt, Jc)  # (n, 2n, N)
        for i in range(n):
            for c in range(2 * n):
                H[diag + i, D0 + c] = np.bincount(lf, cross[i, c], n_frames)
        H[D0:, :D0] = H[:D0, D0:].T
        H[D0:, D0:] = np.einsum("acn,adn->cd", Jc, Jc)
        g[D0:] = np.einsum("acn,an->c", Jc, r)

    # Schur complement of the points: with C_t = L_t L_t^T, V_k = B_k L_t^-T and
    # y_t = L_t^-1 b_t, the correction is -V V^T and the gradient's -V y.
    C = np.moveaxis(segment_sum(np.einsum("ain,ajn->ijn", Jp, Jp), obs.starts), -1, 0)
    C += (1e-12 * np.trace(C, axis1=1, axis2=2) + 1e-12)[:, None, None] * np.eye(3)
    b = segment_sum(np.einsum("ain,an->in", Jp, r), obs.starts).T  # (T, 3)
    L_inv = np.linalg.inv(np.linalg.cholesky(C))  # (T, 3, 3)
    y = np.einsum("tij,tj->ti", L_inv, b)
    B = np.einsum("ain,ajn->ijn", Jt, Jp)  # (n, 3, N)
    V = np.einsum("jan,ban->jbn", B, np.moveaxis(L_inv, 0, -1)[:, :, obs.tracks])
    M = np.zeros((D, 3 * obs.n_tracks))
    rows = (lf * n)[None, None, :] + np.arange(n)[:, None, None]
    cols = (3 * obs.tracks)[None, None, :] + np.arange(3)[None, :, None]
    M[rows, cols] = V
    if calibration:
        L_inv_rows = np.moveaxis(L_inv, 0, -1)[:, :, obs.tracks]
        Vc = np.einsum("can,ban->cbn", np.einsum("acn,ajn->cjn", Jc, Jp), L_inv_rows)
        M[D0:] = np.moveaxis(segment_sum(Vc, obs.starts), -1, 1).reshape(2 * n, -1)
    H -= M @ M.T
    g -= M @ y.ravel()
    return ReducedSystem(H, g, float(np.sum(r * r)), pts.T.copy(), norms)


def compress(H: FloatArray, g: FloatArray, cost: float) -> tuple[FloatArray, FloatArray]:
    """``A`` ``(D + 1, D)`` and ``e`` ``(D + 1,)`` with ``A^T A = H``, ``A^T e = g`` and
    ``|e|^2 = cost`` (when ``cost >= g^T H^+ g``, as it is for a least-squares cost).

    ``H`` is positive semi-definite. The Cholesky factor is used when it exists (with a relative
    jitter of ``1e-12``, which adds no information to speak of); where round-off leaves ``H``
    indefinite in a direction the chunk does not observe, an eigen-decomposition drops the
    directions with eigenvalues below ``1e-12`` of the largest.
    """
    D = len(g)
    scale = max(float(np.max(np.diag(H), initial=0.0)), 1e-300)
    A = np.zeros((D + 1, D), order="F")
    try:
        # numpy's Cholesky: scipy's took 20x longer at D ~ 500 on 2 busy cores (threading).
        L = np.linalg.cholesky(H + 1e-12 * scale * np.eye(D))
        e = scipy.linalg.solve_triangular(L, g, lower=True, check_finite=False)
        A[:D] = L.T
    except np.linalg.LinAlgError:
        lam, vec = np.linalg.eigh(H)
        keep = lam > 1e-12 * max(float(lam[-1]), scale)
        root = np.sqrt(np.where(keep, lam, 0.0))
        A[:D] = root[:, None] * vec.T
        e = np.where(keep, (vec.T @ g) / np.where(keep, root, 1.0), 0.0)
    rest = cost - float(e @ e)
    return A, np.append(e, np.sqrt(max(rest, 0.0)))


class ProjectionFactor:
    """One camera's chunk of tracks as a gtsam factor over the frames they span.

    Args:
        obs: the tracks (rows of a contiguous range of frames).
        chain: the camera's chain.
        n_segments: S, the dimension of each frame's angle vector.
        weights: ``(N,)`` row weights; the array is used in place, so an estimator can
            update the robust decisions between solves.
        calibrate: also depend on the ``(k, delta_max)`` variables (:func:`calibration_key`)
            of the chain's segments, whose values then replace the chain's.

    The frames spanned are ``first .. last``; the factor's keys are their :func:`frame_key`,
    then (with ``calibrate``) the calibration keys of segments ``0..c``. The latest points are
    kept and start the next triangulation.
    """

    def __init__(self, obs: TrackObservations, chain: CameraChain, n_segments: int,
                 weights: FloatArray | None = None, calibrate: bool = False) -> None:
        if len(obs) == 0:
            raise ValueError("a projection factor needs at least one observation")
        self.obs, self.chain, self.n_segments = obs, chain, n_segments
        self.weights = np.ones(len(obs)) if weights is None else weights
        self.first = int(obs.frames.min())
        self.last = int(obs.frames.max())
        self.frames = np.arange(self.first, self.last + 1)
        self.n = len(chain.segments)
        self.calibrate = bool(calibrate)
        self.frame_keys = [frame_key(int(f)) for f in self.frames]
        self.calibration_keys = ([calibration_key(j) for j in range(self.n)]
                                 if self.calibrate else [])
        self.keys = self.frame_keys + self.calibration_keys
        self.points: FloatArray | None = None
        self.norms: FloatArray | None = None  # residual norms of the last evaluation
        self.point_iterations = 10  # see reduced_system; 1 suits iSAM2's re-linearisations
        self.dim = len(self.frames) * self.n + (2 * self.n if self.calibrate else 0) + 1

    def thetas(self, values: gtsam.Values) -> FloatArray:
        """``(F', S)`` the chunk's angles in ``values``."""
        return np.array([values.atVector(k) for k in self.frame_keys])

    def chain_at(self, values: gtsam.Values | None) -> CameraChain:
        """The chain, with the calibration variables' segment models when calibrating."""
        if not self.calibrate or values is None:
            return self.chain
        return self.chain.with_segments([
            calibrated(seg, *values.atVector(key))
            for seg, key in zip(self.chain.segments, self.calibration_keys, strict=True)])

    def system(self, thetas: FloatArray, jacobians: bool = True,
               chain: CameraChain | None = None) -> ReducedSystem:
        """The reduced system at ``thetas`` (and remember the points); ``chain`` overrides the
        factor's (calibrated segments)."""
        out = reduced_system(self.obs, self.chain if chain is None else chain, thetas,
                             self.first, self.weights, self.points, jacobians,
                             calibration=self.calibrate and jacobians,
                             point_iterations=self.point_iterations)
        self.points, self.norms = out.points, out.residuals
        return out

    def residual_norms(self, thetas: FloatArray, robust: bool = False,
                       chain: CameraChain | None = None) -> FloatArray:
        """Whitened residual norms of every row at ``thetas`` (for robust decisions); with
        ``robust``, each track's point is found afresh, robustly, ignoring the weights."""
        chain = self.chain if chain is None else chain
        if robust:
            norms, self.points = robust_residual_norms(self.obs, chain, thetas, self.first,
                                                       np.ones(len(self.obs)))
        else:
            norms, self.points = residual_norms(self.obs, chain, thetas, self.first,
                                                self.weights, self.points)
        return norms

    def error_func(self, this: gtsam.CustomFactor, values: gtsam.Values,
                   H: list[np.ndarray] | None) -> np.ndarray:
        """gtsam's callback: compressed error and, when asked, the Jacobian blocks."""
        thetas = self.thetas(values)
        out = self.system(thetas, jacobians=H is not None, chain=self.chain_at(values))
        if H is None:
            e = np.zeros(self.dim)
            e[-1] = np.sqrt(out.cost)
            return e
        A, e = compress(out.H, out.g, out.cost)
        n, S = self.n, self.n_segments
        for i in range(len(self.frame_keys)):
            block = np.zeros((self.dim, S), order="F")
            block[:, :n] = A[:, i * n:(i + 1) * n]
            H[i] = block
        D0 = len(self.frame_keys) * n
        for j in range(len(self.calibration_keys)):
            H[len(self.frame_keys) + j] = np.asfortranarray(A[:, D0 + 2 * j:D0 + 2 * j + 2])
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
