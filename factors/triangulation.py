"""Each track's 3-D point for given camera poses: the nuisance the projection factor eliminates.

:func:`triangulate` solves weighted least squares of a track's whitened reprojection errors
(:mod:`apcc_graph.factors.track_points`; docs/estimation.md, "Eliminating each track's point") by
Levenberg-Marquardt in inverse-depth coordinates anchored at the track's first row
(``p = o_a + R_a (alpha, beta, 1) / rho``), which stays well conditioned for the small baselines
of a tip camera; all tracks are solved at once (vectorised). :func:`robust_triangulate` adds
robustness to wrong associations (ray agreement, then Cauchy reweighting).
"""

from __future__ import annotations

import numpy as np

from apcc_graph.factors import triangulation_jit
from apcc_graph.factors.engine import resolve
from apcc_graph.factors.track_points import (
    MIN_DEPTH,
    TrackObservations,
    project_rows,
    rows_last,
    segment_sum,
)
from apcc_graph.model.arrays import FloatArray, IntArray

MIN_INVERSE_DEPTH = 1e-3
"""1/metres: a point's inverse depth from its track's first camera stays above this (1 km); a
track whose rays meet behind the cameras (noise without parallax) keeps its point there."""
DEFAULT_DEPTH = 3.0
"""Metres: depth a track's point starts at when its rays do not fix it."""


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
        norms = project_rows(obs, Rb, ob, pts[:, obs.tracks]).norms
        w = weights / (1.0 + (norms / scale) ** 2)
    pts = triangulate_rows(obs, Rb, ob, w, pts, iterations=10)
    return pts.T.copy(), project_rows(obs, Rb, ob, pts[:, obs.tracks]).norms


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
                     tolerance: float = 1e-6, engine: str | None = None) -> FloatArray:
    """:func:`triangulate`, row-last: ``Rb`` ``(3, 3, N)``, ``ob`` ``(3, N)``, points
    ``(3, T)`` in and out. ``engine``: ``"numba"``, the compiled kernels
    (:mod:`apcc_graph.factors.triangulation_jit`), or ``"numpy"``, the reference below; both give
    the same points to rounding; ``None``: the default (:mod:`apcc_graph.factors.engine`)."""
    if resolve(engine) == "numba":
        args = (obs.xy_t, obs.starts, np.ascontiguousarray(Rb), np.ascontiguousarray(ob),
                np.ascontiguousarray(weights, dtype=float))
        start = (triangulation_jit.initial_points(*args) if points is None
                 else np.ascontiguousarray(points, dtype=float))
        return triangulation_jit.triangulate(obs.xy_t, obs.whiten_t, *args[1:], start,
                                             iterations, tolerance)
    if points is None:
        points = _initial_points(obs, Rb, ob, weights)
    problem = _InverseDepth(obs, Rb, ob, weights)
    params = problem.parameters(points)
    lam = np.full(params.shape[1], 1e-3)
    cost, p, N, g = problem.evaluate(params, True)
    for _ in range(iterations):
        step = _bounded_step(params, N, g, lam)
        trial = params + step
        new_cost, new_p, _, _ = problem.evaluate(trial, False)
        better = new_cost <= cost
        params = np.where(better, trial, params)
        p = np.where(better, new_p, p)
        cost = np.where(better, new_cost, cost)
        lam = np.clip(np.where(better, lam * 0.3, lam * 10.0), 1e-9, 1e9)
        if np.max(np.abs(step), initial=0.0) < tolerance:
            break
        if better.any():  # a rejected step leaves that track's system as it was
            cost, p, N, g = problem.evaluate(params, True)
    return p


def _bounded_step(params: FloatArray, N: FloatArray, g: FloatArray,
                  lam: FloatArray) -> FloatArray:
    """The damped Gauss-Newton step ``(3, T)`` of each track, inverse depth kept above
    :data:`MIN_INVERSE_DEPTH`."""
    diag = np.maximum(np.einsum("iit->it", N), 1e-12)
    A = N + lam * diag[:, None, :] * np.eye(3)[:, :, None]
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
    return step


class _InverseDepth:
    """Each track's point in inverse depth from its first row's camera,
    ``p = o_a + R_a (alpha, beta, 1) / rho``: its weighted cost and normal equations."""

    def __init__(self, obs: TrackObservations, Rb: FloatArray, ob: FloatArray,
                 weights: FloatArray) -> None:
        self.obs, self.Rb, self.ob = obs, Rb, ob
        self.anchor = obs.starts[:-1]
        self.Ra, self.oa = Rb[:, :, self.anchor], ob[:, self.anchor]
        self.sw = np.sqrt(weights)
        self.live = weights > 0.0

    def parameters(self, points: FloatArray) -> FloatArray:
        """``(alpha, beta, rho)`` ``(3, T)`` of ``(3, T)`` points (a point not in front of its
        anchor camera restarts on the anchor's ray at :data:`DEFAULT_DEPTH`)."""
        v = np.einsum("jit,jt->it", self.Ra, points - self.oa)
        bad = ~(v[2] > MIN_DEPTH)
        v[:, bad] = (np.vstack([self.obs.xy_t[:, self.anchor[bad]], np.ones(bad.sum())])
                     * DEFAULT_DEPTH)
        return np.vstack([v[0] / v[2], v[1] / v[2], 1.0 / v[2]])

    def evaluate(self, prm: FloatArray, jacobian: bool
                 ) -> tuple[FloatArray, FloatArray, FloatArray | None, FloatArray | None]:
        """Cost per track (a point behind a live row's camera costs 1e12), the points
        ``(3, T)`` and, with ``jacobian``, each track's ``J^T J`` ``(3, 3, T)`` and
        ``J^T r`` ``(3, T)`` in the parameters."""
        obs, starts, tracks, Ra = self.obs, self.obs.starts, self.obs.tracks, self.Ra
        ray = np.vstack([prm[0], prm[1], np.ones(prm.shape[1])])
        Rray = np.einsum("ijt,jt->it", Ra, ray)
        p = self.oa + Rray / prm[2]
        proj = project_rows(obs, self.Rb, self.ob, p[:, tracks])
        r = proj.r * self.sw
        behind = ~proj.valid & self.live
        cost = segment_sum(r[0] ** 2 + r[1] ** 2 + behind * 1e12, starts)
        if not jacobian:
            return cost, p, None, None
        # d p / d (alpha, beta, rho) per track, (3, 3, T).
        dp = np.empty((3, 3, prm.shape[1]))
        dp[:, 0] = Ra[:, 0] / prm[2]
        dp[:, 1] = Ra[:, 1] / prm[2]
        dp[:, 2] = -Rray / prm[2] ** 2
        # J = W dm/dq R^T dp, per row (2, 3, N).
        Jp = np.einsum("ain,jin->ajn", proj.whitened_dm(obs.whiten_t) * self.sw, self.Rb)
        J = np.einsum("ajn,jkn->akn", Jp, dp[:, :, tracks])
        N = segment_sum(np.einsum("akn,aln->kln", J, J), starts)
        g = segment_sum(np.einsum("akn,an->kn", J, r), starts)
        return cost, p, N, g
