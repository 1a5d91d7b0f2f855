"""A new frame's initial angles, for a streaming estimator.

Where the window knows few points yet (the first frames of a sequence, or after a blackout), the
angles are first found from the previous frame by the 1-point front end: per segment from the
base outward, 1-point RANSAC on the generalized epipolar constraint between the previous and the
new frame (:func:`apcc_graph.frontend.ransac.one_point_ransac`) over their correspondences
(:class:`FramePairs`, :func:`frame_pairs`), with the segment's base motion from the angles below
it (:func:`one_point_guess`). Then the prediction (constant angular velocity from the two
previous estimates, :func:`predict`) is refined against the tracks the window already knows:
each live track's point (triangulated from its earlier observations) is held fixed and the new
frame's S angles are fitted to the new observations of those tracks, all cameras together, by
robust Gauss-Newton (Cauchy weights, then the truncated quadratic): a perspective-n-point
problem in joint space (:func:`refine`). Observations are whitened reprojection errors
(:mod:`apcc_graph.factors.track_points`); Jacobians come from the scalar APCC transforms
(:func:`apcc_graph.model.scalar_kinematics.apcc_transform_scalar`), one frame at a time. For a
spatial robot (``spatial=True``) the unknowns are the bending vectors
(:mod:`apcc_graph.model.bending`), and the 2-point front end replaces the 1-point one
(:mod:`apcc_graph.estimation.spatial_stream`).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from apcc_graph.frontend.ransac import one_point_ransac
from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.bending import bending_transform, bending_transform_derivative
from apcc_graph.model.kinematics import apcc_transform
from apcc_graph.model.robot import Robot
from apcc_graph.model.scalar_kinematics import apcc_transform_scalar


@dataclass(frozen=True)
class FrameRows:
    """One camera's observations in the new frame of tracks with known points."""

    camera: int
    points: FloatArray  # (n, 3) world points
    xy: FloatArray  # (n, 2) normalised image coordinates
    whiten: FloatArray  # (n, 2, 2)


@dataclass(frozen=True)
class InitialGuess:
    """The new frame's angles and what backed them.

    Attributes:
        thetas: ``(S,)`` angles (radians).
        inliers: ``(S,)`` per camera segment, observations within the threshold (0 where the
            segment has no camera or no known points).
        refined: whether the observations refined the prediction.
        row_inliers: per entry of the ``rows`` given, which observations are inliers at the
            returned angles.
    """

    thetas: FloatArray
    inliers: NDArray[np.int64]
    refined: bool
    row_inliers: tuple[NDArray[np.bool_], ...] = ()


def within_limits(x: FloatArray, robot: Robot, spatial: bool = False) -> FloatArray:
    """Angles clipped to ``[-theta_max, theta_max]``; with ``spatial``, bending vectors
    ``(2 S,)`` shortened to length ``theta_max`` where longer."""
    lim = np.array([s.theta_max for s in robot.segments])
    if not spatial:
        return np.clip(x, -lim, lim)
    b = np.asarray(x, dtype=float).reshape(-1, 2)
    norm = np.hypot(b[:, 0], b[:, 1])
    shrink = np.where(norm > lim, lim / np.maximum(norm, 1e-300), 1.0)
    return (b * shrink[:, None]).ravel()


def predict(previous: FloatArray, older: FloatArray | None, robot: Robot,
            spatial: bool = False) -> FloatArray:
    """Constant angular velocity from the two previous frames' estimates, within the limits
    (bending vectors with ``spatial``: constant velocity of ``b``, smooth through straight)."""
    prediction = previous if older is None else 2.0 * previous - older
    return within_limits(prediction, robot, spatial)


def frame_poses(thetas: FloatArray, robot: Robot, world_T_base: FloatArray | None,
                psis: FloatArray | None = None, spatial: bool = False
                ) -> tuple[list[FloatArray], list[FloatArray]]:
    """Per segment i, ``world_T_tip_i`` and its derivatives ``(i + 1, 4, 4)`` with respect to
    ``thetas[0..i]``, for one frame. With ``spatial``, ``thetas`` are the bending vectors
    ``(u_0, v_0, u_1, ...)`` and the derivatives ``(2 (i + 1), 4, 4)`` in ``u_0, v_0, ...``."""
    S = robot.n_segments
    if spatial:
        b = np.asarray(thetas, dtype=float).reshape(S, 2)
        T = [bending_transform(u, v, s) for (u, v), s in zip(b, robot.segments, strict=True)]
        dT = [np.stack(bending_transform_derivative(u, v, s))
              for (u, v), s in zip(b, robot.segments, strict=True)]
    else:
        psis = np.zeros(S) if psis is None else psis
        pairs = [apcc_transform_scalar(float(thetas[j]), s, float(psis[j]))
                 for j, s in enumerate(robot.segments)]
        T = [t for t, _ in pairs]
        dT = [d[None] for _, d in pairs]
    base = np.eye(4) if world_T_base is None else np.asarray(world_T_base, dtype=float)
    tips, derivs = [], []
    prefix = [base]
    for i in range(S):
        prefix.append(prefix[-1] @ T[i])
        d = []
        for j in range(i + 1):
            suffix = np.eye(4)
            for m in range(j + 1, i + 1):
                suffix = suffix @ T[m]
            d.extend(prefix[j] @ dTj @ suffix for dTj in dT[j])
        tips.append(prefix[-1])
        derivs.append(np.array(d))
    return tips, derivs


def _normal_equations(thetas: FloatArray, robot: Robot, base: FloatArray | None,
                      psis: FloatArray | None, rows: list[FrameRows], scale: float | None,
                      threshold: float, spatial: bool = False
                      ) -> tuple[FloatArray, FloatArray, float, list[NDArray[np.bool_]]]:
    P = len(thetas)
    tips, derivs = frame_poses(thetas, robot, base, psis, spatial)
    H, g, cost = np.zeros((P, P)), np.zeros(P), 0.0
    inliers: list[NDArray[np.bool_]] = []
    for r in rows:
        c = r.camera
        camera = robot.cameras[c]
        assert camera is not None
        pose = tips[c] @ camera.tip_T_cam
        dpose = derivs[c] @ camera.tip_T_cam
        R, o = pose[:3, :3], pose[:3, 3]
        d = r.points - o
        q = d @ R
        iz = 1.0 / np.maximum(q[:, 2], 1e-3)
        m = q[:, :2] * iz[:, None]
        res = np.einsum("nij,nj->ni", r.whiten, m - r.xy)
        norm = np.sqrt(np.sum(res * res, axis=1))
        valid = q[:, 2] > 1e-3
        if scale is None:
            w = (norm <= threshold) & valid
        else:
            w = valid / (1.0 + (norm / scale) ** 2)
        inliers.append((norm <= threshold) & valid)
        # dq/dtheta_j = dR_j^T d - R^T do_j; dm/dq; J = W dm/dq dq/dtheta.
        dq = np.einsum("jba,nb->nja", dpose[:, :3, :3], d) - (dpose[:, :3, 3] @ R)[None]
        dm = np.zeros((len(q), 2, 3))
        dm[:, 0, 0] = dm[:, 1, 1] = iz
        dm[:, :, 2] = -m * iz[:, None]
        J = np.einsum("nab,nbc,njc->naj", r.whiten, dm, dq)  # (n, 2, k): k = len(dpose)
        sw = np.sqrt(w)[:, None, None]
        Jw, rw = J * sw, res * sw[:, :, 0]
        k = len(dpose)
        H[:k, :k] += np.einsum("naj,nak->jk", Jw, Jw)
        g[:k] += np.einsum("naj,na->j", Jw, rw)
        cost += float(np.sum(rw * rw))
    return H, g, cost, inliers


def refine(prediction: FloatArray, robot: Robot, world_T_base: FloatArray | None,
           rows: list[FrameRows], threshold: float, psis: FloatArray | None = None,
           min_rows: int = 6, iterations: int = 6, spatial: bool = False) -> InitialGuess:
    """Refine the prediction against fixed points (see the module docstring).

    Args:
        prediction: ``(S,)`` predicted angles (radians).
        robot: the robot.
        world_T_base: the frame's base pose (``None``: identity).
        rows: per camera, observations of tracks with known points.
        threshold: inlier threshold on whitened residual norms (pixel-noise units).
        psis: the frame's bending-plane angles, or ``None``.
        min_rows: segments constrained by fewer inliers keep the prediction's angle.
        iterations: Gauss-Newton iterations (the first half Cauchy-weighted).
        spatial: ``prediction`` holds bending vectors ``(2 S,)`` (and so does the result;
            the limits then bound each one's length).

    Returns:
        The initial guess; ``refined`` is False (and the angles are the prediction) when no
        segment had ``min_rows`` observations.
    """
    S = robot.n_segments
    counts = np.zeros(S, dtype=np.int64)
    for r in rows:
        counts[r.camera] = len(r.points)
    # A segment is refined if a camera on it or further out sees enough.
    reach = np.array([counts[i:].sum() for i in range(S)])
    free = np.repeat(reach >= min_rows, 2 if spatial else 1)
    if not free.any():
        return InitialGuess(prediction.copy(), np.zeros(S, dtype=np.int64), False,
                            tuple(np.ones(len(r.points), dtype=bool) for r in rows))
    thetas = prediction.copy()
    for it in range(iterations):
        scale = 3.0 * threshold if it < iterations // 2 else None
        H, g, _, _ = _normal_equations(thetas, robot, world_T_base, psis, rows, scale,
                                       threshold, spatial)
        Hf = H[np.ix_(free, free)] + 1e-9 * max(float(np.trace(H)), 1e-12) * np.eye(free.sum())
        step = np.zeros(len(thetas))
        try:
            step[free] = -np.linalg.solve(Hf, g[free])
        except np.linalg.LinAlgError:
            break
        thetas = within_limits(thetas + step, robot, spatial)
        if np.max(np.abs(step)) < 1e-7:
            break
    *_, inliers = _normal_equations(thetas, robot, world_T_base, psis, rows, None, threshold,
                                    spatial)
    out = np.zeros(S, dtype=np.int64)
    for r, flags in zip(rows, inliers, strict=True):
        out[r.camera] = int(flags.sum())
    return InitialGuess(thetas, out, True, tuple(inliers))


@dataclass(frozen=True)
class FramePairs:
    """One camera's correspondences between the previous and the new frame."""

    camera: int
    f_a: FloatArray  # (n, 3) unit bearings in the previous frame
    f_b: FloatArray  # (n, 3) unit bearings in the new frame
    rows: NDArray[np.int64]  # (n,) their rows among the new frame's observations


def frame_pairs(previous: Mapping[int, tuple[NDArray[np.int64], FloatArray, FloatArray]],
                rows: Mapping[int, tuple[NDArray[np.int64], FloatArray, FloatArray]]
                ) -> list[FramePairs]:
    """Each camera's correspondences between the previous frame and the new one, from their
    observations ``camera -> (track ids, normalised points, whitening)``."""
    out = []
    for cam, (ids, xy, _) in rows.items():
        before = previous.get(cam)
        if before is None:
            continue
        common, now, then = np.intersect1d(ids, before[0], return_indices=True)
        if len(common) == 0:
            continue
        out.append(FramePairs(cam, _unit(before[1][then]), _unit(xy[now]), now))
    return out


def _unit(xy: FloatArray) -> FloatArray:
    """Unit bearings of normalised image points."""
    b = np.column_stack([xy, np.ones(len(xy))])
    return b / np.linalg.norm(b, axis=1, keepdims=True)


def segment_bases(x: FloatArray, robot: Robot, world_T_base: FloatArray | None,
                  spatial: bool = False) -> list[FloatArray]:
    """``world_T_base`` of every segment for one frame's angles ``(S,)`` or, with
    ``spatial``, bending vectors ``(2 S,)`` (``world_T_base`` ``None``: identity)."""
    pose = np.eye(4) if world_T_base is None else np.asarray(world_T_base, dtype=float)
    out = []
    for j, seg in enumerate(robot.segments):
        out.append(pose)
        step = (bending_transform(x[2 * j], x[2 * j + 1], seg) if spatial
                else apcc_transform(float(x[j]), seg))
        pose = pose @ step
    return out


#: One segment's solver in :func:`chained_guess`: (segment index, its previous value(s),
#: ``base_prev_T_base_now`` of the segment, the camera's pairs, threshold in radians, rng) ->
#: (the new value(s), or None if it failed; inlier mask over the pairs).
SegmentSolver = Callable[[int, FloatArray, FloatArray, "FramePairs", float,
                          np.random.Generator], tuple[FloatArray | None, NDArray[np.bool_]]]


def chained_guess(previous: FloatArray, prediction: FloatArray, robot: Robot,
                  base_previous: FloatArray | None, base_now: FloatArray | None,
                  pairs: list[FramePairs], threshold_px: float, rng: np.random.Generator | None,
                  solve: SegmentSolver, spatial: bool = False
                  ) -> tuple[FloatArray, dict[int, NDArray[np.bool_]]]:
    """A front end's guess, segment by segment from the base outward: each segment's base
    motion comes from the new values of the segments below it; ``solve`` gives its own
    (arguments and result as :func:`one_point_guess`, ``spatial`` for bending vectors)."""
    rng = np.random.default_rng(0) if rng is None else rng
    x = np.array(prediction, dtype=float)
    width = 2 if spatial else 1
    by_camera = {p.camera: p for p in pairs}
    before = segment_bases(previous, robot, base_previous, spatial)
    inliers: dict[int, NDArray[np.bool_]] = {}
    for i in range(robot.n_segments):
        camera = robot.cameras[i]
        found = by_camera.get(i)
        if camera is None or found is None or len(found.f_a) < 5:
            continue
        motion = np.linalg.inv(before[i]) @ segment_bases(x, robot, base_now, spatial)[i]
        value, mask = solve(i, previous[width * i:width * (i + 1)], motion, found,
                            threshold_px / camera.fx, rng)
        if value is not None:
            x[width * i:width * (i + 1)] = value
            inliers[i] = mask
    return x, inliers


def one_point_guess(previous: FloatArray, prediction: FloatArray, robot: Robot,
                    base_previous: FloatArray | None, base_now: FloatArray | None,
                    pairs: list[FramePairs], threshold_px: float,
                    rng: np.random.Generator | None = None
                    ) -> tuple[FloatArray, dict[int, NDArray[np.bool_]]]:
    """The new frame's angles by the 1-point front end, from the previous frame's.

    Args:
        previous: ``(S,)`` the previous frame's angles (radians).
        prediction: ``(S,)`` the fallback of a segment whose RANSAC fails or that has no
            camera (a camera-less segment keeps it).
        robot: the robot.
        base_previous, base_now: the two frames' base poses (``None``: identity).
        pairs: per camera, its correspondences between the two frames.
        threshold_px: inlier threshold (pixels, divided by the camera's focal length).
        rng: RANSAC sampling (default seeded, deterministic).

    Returns:
        The angles, and per camera that succeeded the inlier mask over its pairs.
    """
    def solve(i: int, before: FloatArray, motion: FloatArray, found: FramePairs,
              threshold: float, rng: np.random.Generator
              ) -> tuple[FloatArray | None, NDArray[np.bool_]]:
        theta, info = one_point_ransac(found.f_a, found.f_b, float(before[0]),
                                       robot.segments[i], robot.cameras[i].tip_T_cam, motion,
                                       threshold=threshold, rng=rng)
        return (np.array([theta]) if info.success else None), info.inliers

    return chained_guess(previous, prediction, robot, base_previous, base_now, pairs,
                         threshold_px, rng, solve)
