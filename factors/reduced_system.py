"""The projection model's Gauss-Newton system in the angles, each track's point eliminated.

Residual (:mod:`apcc_graph.factors.track_points`; docs/estimation.md, "Eliminating each track's
point"): ``r_k = W_k (m(R^T (p_t - o)) - x_k)`` per observation, the pixel reprojection error in
units of the pixel noise, with the camera pose ``[R | o]`` of the row's frame along the chain
(:class:`apcc_graph.factors.camera_chain.CameraChain`). Each track's point ``p_t`` is a nuisance:
for the current angles it is re-triangulated (:mod:`apcc_graph.factors.triangulation`) and
eliminated by the Schur complement, so the cost is ``sum_k w_k |r_k|^2`` minimised over the points
(variable projection), and its Gauss-Newton system in the angles is

    H = sum_k Jt_k^T Jt_k - sum_t B_t C_t^-1 B_t^T,    g = sum_k Jt_k^T r_k - sum_t B_t C_t^-1 b_t

with ``Jt_k = d r_k / d theta`` (point held fixed in the world), ``Jp_k = d r_k / d p_t``,
``C_t = sum_k Jp_k^T Jp_k``, ``B_t = sum_k Jt_k^T Jp_k`` (one block row per observation) and
``b_t = sum_k Jp_k^T r_k``: exactly the system bundle adjustment solves after eliminating the
points, and the information the Cramer-Rao bound of the angles counts. Row weights ``w_k``
(robust decisions, 0 for an outlier) are held fixed while the system is built; the estimators
update them between solves (graduated non-convexity).

Self-calibration: with ``calibration``, the system also has the ``2 m`` columns of the chain's
``m`` segments' ``(k, delta_max)``, after the frames' (``n`` columns per frame: ``m`` angles in
fixed planes, or ``2 m`` bending-vector components); with ``mount``, six more for the camera's
mounting ``tip_T_cam`` (:func:`~apcc_graph.factors.camera_chain.mount_derivatives`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from apcc_graph.factors import reduced_jit
from apcc_graph.factors.camera_chain import CameraChain, mount_derivatives
from apcc_graph.factors.engine import resolve
from apcc_graph.factors.track_points import TrackObservations, project_rows, segment_sum
from apcc_graph.factors.triangulation import robust_triangulate, triangulate_rows
from apcc_graph.model.arrays import FloatArray


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


def _row_poses(chain: CameraChain, thetas: FloatArray, first: int, frames: NDArray[np.int64],
               derivatives: bool, calibration: bool = False, mount: bool = False,
               engine: str | None = None
               ) -> tuple[FloatArray, FloatArray, FloatArray | None, FloatArray | None]:
    """Row-last camera orientation ``(3, 3, N)``, position ``(3, N)``, pose derivatives
    ``(4, 4, n, N)`` of each row's frame and, with ``calibration`` or ``mount``, the
    derivatives in the model parameters: ``(k_0, delta_0, k_1, ...)`` of the chain's ``m``
    segments, then the mounting's six (:func:`mount_derivatives`), ``(4, 4, C, N)``."""
    out = chain.poses(thetas, first, derivatives, calibration, engine)
    poses, d_poses = out[0], out[1]
    lf = frames - first
    P = np.moveaxis(poses, 0, -1)[:, :, lf]
    dP = None if d_poses is None else np.moveaxis(d_poses, (0, 1), (-1, -2))[..., lf]
    extra = []
    if calibration:
        d_cal = out[2]
        F, m = d_cal.shape[:2]
        extra.append(d_cal.reshape(F, 2 * m, 4, 4))
    if mount:
        extra.append(mount_derivatives(poses))
    dC = (np.moveaxis(np.concatenate(extra, axis=1), (0, 1), (-1, -2))[..., lf]
          if extra else None)
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
    return project_rows(obs, Rb, ob, pts[:, obs.tracks]).norms, pts.T.copy()


def robust_residual_norms(obs: TrackObservations, chain: CameraChain, thetas: FloatArray,
                          first: int, weights: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Like :func:`residual_norms`, but each track's point is found robustly from scratch
    (:func:`apcc_graph.factors.triangulation.robust_triangulate`): the outlier decisions of a new
    estimate start here."""
    Rb, ob, _, _ = _row_poses(chain, thetas, first, obs.frames, False)
    points, norms = robust_triangulate(obs, np.moveaxis(Rb, -1, 0), ob.T, weights)
    return norms, points


def reduced_system(obs: TrackObservations, chain: CameraChain, thetas: FloatArray, first: int,
                   weights: FloatArray, points: FloatArray | None = None,
                   jacobians: bool = True, refine_points: bool = True,
                   calibration: bool = False, point_iterations: int = 10,
                   mount: bool = False, engine: str | None = None) -> ReducedSystem:
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
        calibration: add the ``2 m`` columns of the chain's ``m`` segments' ``(k,
            delta_max)`` after the frames' (``D = frames x n + 2 m``).
        mount: add the six columns of the camera's mounting (a right perturbation of
            ``tip_T_cam``, rotation first, as gtsam's ``Pose3``) after those.
        point_iterations: most triangulation iterations from ``points`` (from scratch: 10).
            With one step from a previous solution the points are not exactly optimal; the
            system is then the joint Gauss-Newton system in (angles, points) with the points
            eliminated, whose angle step is as good, but whose ``cost`` is not minimised over
            the points (an estimator that compares costs, such as Levenberg-Marquardt, needs
            the default).
        engine: ``"numba"``, the compiled kernels (:mod:`apcc_graph.factors.reduced_jit`), or
            ``"numpy"``, the reference; both give the same system to rounding. ``None``: the
            default (:mod:`apcc_graph.factors.engine`).
    """
    engine = resolve(engine)
    Rb, ob, dP, dC = _row_poses(chain, thetas, first, obs.frames, jacobians,
                                jacobians and calibration, jacobians and mount, engine)
    dX = None if dP is None else (dP if dC is None else np.concatenate([dP, dC], axis=2))
    return reduced_at_poses(obs, Rb, ob, dX, len(thetas), None if dP is None else dP.shape[2],
                            obs.frames - first, weights, points, refine_points,
                            point_iterations, engine)


def reduced_at_poses(obs: TrackObservations, Rb: FloatArray, ob: FloatArray,
                     dX: FloatArray | None, n_frames: int, n: int | None,
                     lf: NDArray[np.int64], weights: FloatArray,
                     points: FloatArray | None = None, refine_points: bool = True,
                     point_iterations: int = 10, engine: str | None = None) -> ReducedSystem:
    """The reduced system of :func:`reduced_system` from the rows' camera poses, whatever the
    variables they depend on: ``Rb`` ``(3, 3, N)`` and ``ob`` ``(3, N)`` each row's camera
    orientation and position, ``dX`` ``(4, 4, n + C, N)`` the derivatives of its pose in its
    frame's ``n`` columns, then ``C`` columns shared by the chunk (``None``: the cost and
    residuals only); ``lf`` ``(N,)`` each row's frame, counted from the chunk's first of
    ``n_frames``. The other arguments are :func:`reduced_system`'s."""
    engine = resolve(engine)
    jacobians = dX is not None
    pts = None if points is None else np.ascontiguousarray(points.T)
    if refine_points or pts is None:
        pts = triangulate_rows(obs, Rb, ob, weights, pts,
                               10 if pts is None else point_iterations, engine=engine)
    if engine == "numba" and jacobians:
        assert n is not None
        H, g, cost, norms = reduced_jit.reduced(
            obs.xy_t, obs.whiten_t, obs.tracks, obs.starts, np.ascontiguousarray(lf), Rb, ob,
            np.ascontiguousarray(dX), np.ascontiguousarray(weights, dtype=float), pts,
            n_frames, n)
        return ReducedSystem(H, g, cost, pts.T.copy(), norms)
    proj = project_rows(obs, Rb, ob, pts[:, obs.tracks])
    norms = proj.norms
    sw = np.sqrt(np.where(proj.valid, weights, 0.0))
    r = proj.r * sw
    cost = float(np.sum(r * r))
    if not jacobians:
        return ReducedSystem(np.zeros((0, 0)), np.zeros(0), cost, pts.T.copy(), norms)
    assert dX is not None and n is not None
    dP, dC = dX[:, :, :n], (dX[:, :, n:] if dX.shape[2] > n else None)
    WA = proj.whitened_dm(obs.whiten_t) * sw  # (2, 3, N)
    Jp = np.einsum("ain,jin->ajn", WA, Rb)  # d r / d p = W dm/dq R^T
    Jt = _pose_jacobian(WA, Rb, dP, proj.d)  # (2, n, N)
    Jc = None if dC is None else _pose_jacobian(WA, Rb, dC, proj.d)  # (2, C, N)
    H, g = _normal_equations(Jt, r, lf, n_frames, Jc)
    M, y = _point_elimination(obs, Jt, Jp, r, lf, len(H), Jc)
    H -= M @ M.T
    g -= M @ y.ravel()
    return ReducedSystem(H, g, cost, pts.T.copy(), norms)


def _pose_jacobian(WA: FloatArray, Rb: FloatArray, dP: FloatArray, d: FloatArray) -> FloatArray:
    """``d r / d x`` ``(2, m, N)`` with the point held fixed, for pose derivatives ``dP``
    ``(4, 4, m, N)``: ``q = R^T (p - o)`` gives ``dq/dx_j = dR_j^T (p - o) - R^T do_j``."""
    dq = (np.einsum("bijn,bn->ijn", dP[:3, :3], d)
          - np.einsum("bin,bjn->ijn", Rb, dP[:3, 3]))
    return np.einsum("ain,ijn->ajn", WA, dq)


def _normal_equations(Jt: FloatArray, r: FloatArray, lf: NDArray[np.int64], n_frames: int,
                      Jc: FloatArray | None) -> tuple[FloatArray, FloatArray]:
    """``sum_k Jt^T Jt`` and ``sum_k Jt^T r`` in frame blocks (points held fixed), then the
    calibration columns ``Jc`` when given."""
    n = Jt.shape[1]
    Hk = np.einsum("ain,ajn->ijn", Jt, Jt).reshape(n * n, -1)
    gk = np.einsum("ain,an->in", Jt, r)
    D0 = n_frames * n
    D = D0 + (0 if Jc is None else Jc.shape[1])
    H = np.zeros((D, D))
    diag = np.arange(n_frames) * n
    for i in range(n):
        for j in range(n):
            H[diag + i, diag + j] = np.bincount(lf, Hk[i * n + j], n_frames)
    g = np.zeros(D)
    g[:D0] = np.stack([np.bincount(lf, gk[c], n_frames) for c in range(n)], axis=1).ravel()
    if Jc is not None:
        cross = np.einsum("ain,acn->icn", Jt, Jc)  # (n, 2m, N)
        for i in range(n):
            for c in range(Jc.shape[1]):
                H[diag + i, D0 + c] = np.bincount(lf, cross[i, c], n_frames)
        H[D0:, :D0] = H[:D0, D0:].T
        H[D0:, D0:] = np.einsum("acn,adn->cd", Jc, Jc)
        g[D0:] = np.einsum("acn,an->c", Jc, r)
    return H, g


def _point_elimination(obs: TrackObservations, Jt: FloatArray, Jp: FloatArray, r: FloatArray,
                       lf: NDArray[np.int64], D: int, Jc: FloatArray | None
                       ) -> tuple[FloatArray, FloatArray]:
    """The Schur complement of the points as ``M`` ``(D, 3T)`` and ``y`` ``(T, 3)``: the system
    loses ``M M^T`` and the gradient ``M y``.

    With ``C_t = L_t L_t^T``, ``V_k = B_k L_t^-T`` and ``y_t = L_t^-1 b_t``, the correction is
    ``-V V^T`` and the gradient's ``-V y``; ``M`` holds each row's ``V_k`` in its frame's rows
    and its track's columns (the calibration rows sum over each track).
    """
    n = Jt.shape[1]
    C = np.moveaxis(segment_sum(np.einsum("ain,ajn->ijn", Jp, Jp), obs.starts), -1, 0)
    C += (1e-12 * np.trace(C, axis1=1, axis2=2) + 1e-12)[:, None, None] * np.eye(3)
    b = segment_sum(np.einsum("ain,an->in", Jp, r), obs.starts).T  # (T, 3)
    L_inv = np.linalg.inv(np.linalg.cholesky(C))  # (T, 3, 3)
    y = np.einsum("tij,tj->ti", L_inv, b)
    B = np.einsum("ain,ajn->ijn", Jt, Jp)  # (n, 3, N)
    L_inv_rows = np.moveaxis(L_inv, 0, -1)[:, :, obs.tracks]
    V = np.einsum("jan,ban->jbn", B, L_inv_rows)
    M = np.zeros((D, 3 * obs.n_tracks))
    rows = (lf * n)[None, None, :] + np.arange(n)[:, None, None]
    cols = (3 * obs.tracks)[None, None, :] + np.arange(3)[None, :, None]
    M[rows, cols] = V
    if Jc is not None:
        Vc = np.einsum("can,ban->cbn", np.einsum("acn,ajn->cjn", Jc, Jp), L_inv_rows)
        C = Jc.shape[1]
        M[D - C:] = np.moveaxis(segment_sum(Vc, obs.starts), -1, 1).reshape(C, -1)
    return M, y
