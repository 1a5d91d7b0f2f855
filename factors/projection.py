"""The projection factor in joint space: every observation once, each track's point eliminated.

Variables: one vector per frame (radians; key :func:`frame_key`) in the robot's
parameterisation (:class:`~apcc_graph.model.parameterisation.Bending`: an angle per segment in
fixed planes, or a bending vector per segment). The camera on segment ``c`` depends on the
components of segments ``0..c`` (:mod:`apcc_graph.factors.camera_chain`); the robot base poses
are known inputs.

The factor's maths, the pixel reprojection error with each track's point eliminated by the
Schur complement, is :mod:`apcc_graph.factors.reduced_system` (docs/estimation.md, "Eliminating each
track's point"): for the current angles, a Gauss-Newton system ``H``, ``g`` and a cost.

gtsam sees a factor over a chunk of tracks (:class:`ProjectionFactor`): its Jacobian is the
Cholesky factor ``A`` of ``H`` (``A^T A = H``), its error ``e`` solves ``A^T e = g`` and one more
row carries the rest of the cost (:func:`compress`), so ``|A dx + e|^2`` is the factor's
Gauss-Newton model and ``|e|^2`` its cost. One Python callback per chunk and linearisation,
vectorised over the chunk's observations (Python factors run serially).

Self-calibration: with calibration keys, the factor also depends on one ``Vector2`` per segment
``0..c``, that segment's ``(k, delta_max)`` (key :func:`calibration_key`); its columns come after
the frames' in ``H`` and ``g``, and the segments' values are read from those variables (clamped
to their valid range) instead of the chain's. Mount calibration: with a mount key, the factor
also depends on the camera's ``tip_T_cam`` (a ``Pose3``, key :func:`mount_key`), whose six
columns come last; its value replaces the chain's mounting.

Points between linearisations: a factor keeps its points, and with ``point_iterations`` of 1
(the smoother's iSAM2) each linearisation takes one step from them, which suffices while the
angles move little between linearisations. After a restart the angles of a window can move by
degrees from one update to the next (new tracks, a loose prior), the kept points then lag far
behind, up to a point a few centimetres in front of a camera or behind it, and the system at
such a point is not the eliminated one: rows thousands of pixels off and information of 1e11 to
1e13 per track (about 1e6 at the optimum), which left iSAM2's factorisation of the window
"indeterminate". A track with a row the robust decisions kept that is more than :data:`STALE`
noise sigmas off (or behind a camera) is triangulated afresh, from its rays, and takes that point
where it costs less.

Jacobian convention: the tangent space of a ``Vector`` is the identity (``x + dx``); that of
a ``Pose3`` is gtsam's, ``T . Exp(xi)`` with ``xi = (omega, v)`` in the body frame.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import gtsam
import numpy as np
import scipy.linalg
from numpy.typing import ArrayLike, NDArray

from apcc_graph.factors.camera_chain import CameraChain
from apcc_graph.factors.keys import calibration_key, frame_key, mount_key
from apcc_graph.factors.reduced_system import (
    ReducedSystem,
    reduced_system,
    residual_norms,
    robust_residual_norms,
)
from apcc_graph.factors.track_points import TrackObservations, segment_sum
from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.segment import calibrated

STALE = 100.0
"""Whitened residual norm (pixel-noise units) of a kept row above which its track's point is
triangulated afresh (module docstring, "Points between linearisations")."""


def _track_costs(norms: FloatArray, weights: FloatArray, obs: TrackObservations) -> FloatArray:
    """``(T,)`` each track's weighted cost from its rows' residual norms (``inf`` where a kept
    row's point is behind its camera)."""
    return segment_sum(weights * np.where(weights > 0.0, norms, 0.0) ** 2, obs.starts)


def restarted_points(obs: TrackObservations, weights: FloatArray, out: ReducedSystem,
                     fresh: Callable[[TrackObservations, FloatArray], ReducedSystem]
                     ) -> FloatArray | None:
    """The points of ``out`` with those of :data:`STALE` tracks triangulated afresh where that
    lowers their cost; ``None`` when no track is stale or none got better (module docstring,
    "Points between linearisations"). ``fresh(part, weights)``: the cost-only system of the
    stale tracks ``part`` (rows weighted ``weights``) with points triangulated from scratch."""
    live = weights > 0.0
    stale_rows = live & ~(out.residuals <= STALE)
    if not stale_rows.any():
        return None
    stale = np.unique(obs.tracks[stale_rows])
    part = obs.select(stale)
    rows = np.concatenate([np.arange(obs.starts[t], obs.starts[t + 1]) for t in stale])
    part_weights = weights[rows]
    found = fresh(part, part_weights)
    points = out.points.copy()
    before = _track_costs(out.residuals[rows], part_weights, part)
    after = _track_costs(found.residuals, part_weights, part)
    better = after < before
    points[stale[better]] = found.points[better]
    return points if better.any() else None


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
        # numpy's Cholesky, not scipy's: scipy's is far slower here when cores are busy.
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
        n_segments: the dimension of each frame's vector (the robot's
            :attr:`~apcc_graph.model.parameterisation.Bending.dim`: S angles in fixed planes,
            or 2 S bending-vector components).
        weights: ``(N,)`` row weights; the array is used in place, so an estimator can
            update the robust decisions between solves.
        calibrate: also depend on the ``(k, delta_max)`` variables (:func:`calibration_key`)
            of the chain's segments, whose values then replace the chain's.
        mount: also depend on the camera's mounting (:func:`mount_key`), whose value then
            replaces the chain's ``tip_T_cam``.

    The frames spanned are ``first .. last``; the factor's keys are their :func:`frame_key`,
    then (with ``calibrate``) the calibration keys of segments ``0..c``, then (with ``mount``)
    the camera's mount key. The latest points are kept and start the next triangulation.
    """

    def __init__(self, obs: TrackObservations, chain: CameraChain, n_segments: int,
                 weights: FloatArray | None = None, calibrate: bool = False,
                 mount: bool = False) -> None:
        if len(obs) == 0:
            raise ValueError("a projection factor needs at least one observation")
        self.obs, self.chain, self.n_segments = obs, chain, n_segments
        self.weights = np.ones(len(obs)) if weights is None else weights
        self.first = int(obs.frames.min())
        self.last = int(obs.frames.max())
        self.frames = np.arange(self.first, self.last + 1)
        self.n = chain.n_parameters  # columns of a frame's vector this camera depends on
        self.calibrate = bool(calibrate)
        self.frame_keys = [frame_key(int(f)) for f in self.frames]
        self.calibration_keys = ([calibration_key(j) for j in range(len(chain.segments))]
                                 if self.calibrate else [])
        self.mount_keys = [mount_key(obs.camera)] if mount else []
        self.keys = self.frame_keys + self.calibration_keys + self.mount_keys
        self.points: FloatArray | None = None
        self.norms: FloatArray | None = None  # residual norms of the last evaluation
        self.point_iterations = 10  # see reduced_system; 1 suits iSAM2's re-linearisations
        self.dim = (len(self.frames) * self.n + 2 * len(self.calibration_keys)
                    + 6 * len(self.mount_keys) + 1)

    def thetas(self, values: gtsam.Values) -> FloatArray:
        """``(F', S)`` the chunk's angles in ``values``."""
        return np.array([values.atVector(k) for k in self.frame_keys])

    def chain_at(self, values: gtsam.Values | None) -> CameraChain:
        """The chain, with the calibration variables' segment models and mounting when
        calibrating them."""
        chain = self.chain
        if values is None:
            return chain
        if self.calibrate:
            chain = chain.with_segments([
                calibrated(seg, *values.atVector(key))
                for seg, key in zip(chain.segments, self.calibration_keys, strict=True)])
        if self.mount_keys:
            chain = chain.with_mount(values.atPose3(self.mount_keys[0]).matrix())
        return chain

    def system(self, thetas: FloatArray, jacobians: bool = True,
               chain: CameraChain | None = None) -> ReducedSystem:
        """The reduced system at ``thetas`` (and remember the points); ``chain`` overrides the
        factor's (calibrated segments)."""
        chain = self.chain if chain is None else chain

        def solve(points: FloatArray | None) -> ReducedSystem:
            return reduced_system(self.obs, chain, thetas, self.first, self.weights, points,
                                  jacobians, calibration=self.calibrate and jacobians,
                                  point_iterations=self.point_iterations,
                                  mount=bool(self.mount_keys) and jacobians)

        out = solve(self.points)
        if self.points is not None:
            restarted = self._restarted_points(out, thetas, chain)
            if restarted is not None:
                out = solve(restarted)
        self.points, self.norms = out.points, out.residuals
        return out

    def _restarted_points(self, out: ReducedSystem, thetas: FloatArray,
                          chain: CameraChain) -> FloatArray | None:
        """:func:`restarted_points` of the chunk at ``thetas``."""
        return restarted_points(self.obs, self.weights, out, lambda part, weights: reduced_system(
            part, chain, thetas, self.first, weights, None, jacobians=False))

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
        if self.mount_keys:
            D1 = D0 + 2 * len(self.calibration_keys)
            H[len(self.keys) - 1] = np.asfortranarray(A[:, D1:D1 + 6])
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
