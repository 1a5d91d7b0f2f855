"""A new frame's initial vector, for a streaming estimator.

Where the window knows few points yet (the first frames of a sequence, or after a blackout), the
frame is first found from the previous one by the two-frame front end
(:mod:`apcc_graph.estimation.front_end`). Then the prediction (constant velocity of the frame
vector from the two previous estimates, :func:`predict`) is refined against the tracks the
window already knows: each live track's point (triangulated from its earlier observations) is
held fixed and the new frame's vector is fitted to the new observations of those tracks, all
cameras together, by robust Gauss-Newton (Cauchy weights, then the truncated quadratic): a
perspective-n-point problem in joint space (:func:`refine`). Observations are whitened
reprojection errors (:mod:`apcc_graph.factors.track_points`); Jacobians come from the
parameterisation's one-frame transforms
(:meth:`~apcc_graph.model.parameterisation.Bending.frame_transforms`). Frame vectors are the
parameterisation's: angles in fixed planes, or bending vectors, smooth through straight.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from apcc_graph.factors import reduced_jit
from apcc_graph.factors.engine import resolve
from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.parameterisation import Bending
from apcc_graph.model.robot import Robot


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
        thetas: the new frame's vector (the parameterisation's, radians).
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


def predict(previous: FloatArray, older: FloatArray | None, bending: Bending) -> FloatArray:
    """Constant velocity of the frame vector from the two previous frames' estimates, within
    the limits (for bending vectors, smooth through straight)."""
    prediction = previous if older is None else 2.0 * previous - older
    return bending.clip(prediction)


def frame_poses(x: FloatArray, bending: Bending, world_T_base: FloatArray | None
                ) -> tuple[list[FloatArray], list[FloatArray]]:
    """Per segment i, ``world_T_tip_i`` and its derivatives ``(w (i + 1), 4, 4)`` in the
    components of segments ``0..i`` of one frame's vector ``x`` (``w`` components per
    segment)."""
    S = bending.n_segments
    T, dT = bending.frame_transforms(x)
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


def _normal_equations(thetas: FloatArray, robot: Robot, bending: Bending,
                      base: FloatArray | None, rows: list[FrameRows], scale: float | None,
                      threshold: float, engine: str | None = None
                      ) -> tuple[FloatArray, FloatArray, float, list[NDArray[np.bool_]]]:
    """The frame's Gauss-Newton system from every camera's rows of known points (Cauchy
    weights of ``scale``, or 0/1 at ``threshold`` when ``None``), its cost and the rows'
    inlier flags. ``engine``: ``"numba"`` (:func:`~apcc_graph.factors.reduced_jit.
    known_points_system`) or ``"numpy"``, the reference below."""
    P = len(thetas)
    tips, derivs = frame_poses(thetas, bending, base)
    H, g, cost = np.zeros((P, P)), np.zeros(P), 0.0
    inliers: list[NDArray[np.bool_]] = []
    for r in rows:
        c = r.camera
        camera = robot.cameras[c]
        assert camera is not None
        pose = tips[c] @ camera.tip_T_cam
        dpose = derivs[c] @ camera.tip_T_cam
        k = len(dpose)
        if resolve(engine) == "numba":
            Hc, gc, cc, flags = reduced_jit.known_points_system(
                np.ascontiguousarray(r.points, dtype=float), np.ascontiguousarray(r.xy),
                np.ascontiguousarray(r.whiten), pose, dpose,
                math.nan if scale is None else float(scale), float(threshold))
            H[:k, :k] += Hc
            g[:k] += gc
            cost += cc
            inliers.append(flags > 0.0)
            continue
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
        H[:k, :k] += np.einsum("naj,nak->jk", Jw, Jw)
        g[:k] += np.einsum("naj,na->j", Jw, rw)
        cost += float(np.sum(rw * rw))
    return H, g, cost, inliers


def refine(prediction: FloatArray, robot: Robot, bending: Bending,
           world_T_base: FloatArray | None, rows: list[FrameRows], threshold: float,
           min_rows: int = 6, iterations: int = 6) -> InitialGuess:
    """Refine the prediction against fixed points (see the module docstring).

    Args:
        prediction: the predicted frame vector (``bending``'s, radians).
        robot: the robot (its cameras).
        bending: the parameterisation (the limits bound each segment's bend).
        world_T_base: the frame's base pose (``None``: identity).
        rows: per camera, observations of tracks with known points.
        threshold: inlier threshold on whitened residual norms (pixel-noise units).
        min_rows: segments constrained by fewer inliers keep the prediction's values.
        iterations: Gauss-Newton iterations (the first half Cauchy-weighted).

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
    free = np.repeat(reach >= min_rows, bending.width)
    if not free.any():
        return InitialGuess(prediction.copy(), np.zeros(S, dtype=np.int64), False,
                            tuple(np.ones(len(r.points), dtype=bool) for r in rows))
    thetas = prediction.copy()
    for it in range(iterations):
        scale = 3.0 * threshold if it < iterations // 2 else None
        H, g, _, _ = _normal_equations(thetas, robot, bending, world_T_base, rows, scale,
                                       threshold)
        Hf = H[np.ix_(free, free)] + 1e-9 * max(float(np.trace(H)), 1e-12) * np.eye(free.sum())
        step = np.zeros(len(thetas))
        try:
            step[free] = -np.linalg.solve(Hf, g[free])
        except np.linalg.LinAlgError:
            break
        thetas = bending.clip(thetas + step)
        if np.max(np.abs(step)) < 1e-7:
            break
    *_, inliers = _normal_equations(thetas, robot, bending, world_T_base, rows, None,
                                    threshold)
    out = np.zeros(S, dtype=np.int64)
    for r, flags in zip(rows, inliers, strict=True):
        out[r.camera] = int(flags.sum())
    return InitialGuess(thetas, out, True, tuple(inliers))


def row_inliers(thetas: FloatArray, robot: Robot, bending: Bending,
                world_T_base: FloatArray | None, rows: list[FrameRows],
                threshold: float) -> tuple[NDArray[np.bool_], ...]:
    """Each row's inlier flag (whitened residual norm below ``threshold``) at the frame vector
    ``thetas``, against its known point: the decisions :func:`refine` returns, for rows it did
    not solve with (those the model-free gate held out of the solve still get a residual
    decision, so that a later agreement with a neighbour cannot admit them unchecked)."""
    if not rows:
        return ()
    *_, inliers = _normal_equations(thetas, robot, bending, world_T_base, rows, None, threshold)
    return tuple(inliers)


def fit_blocks(thetas: FloatArray, robot: Robot, bending: Bending,
               world_T_base: FloatArray | None, rows: list[FrameRows],
               threshold: float) -> FloatArray:
    """The flattened per-segment covariance blocks ``(S w^2,)`` of the frame vector
    ``thetas`` fitted to fixed points (the inverse of the inliers' Gauss-Newton information;
    the points' own uncertainty left out); ``inf`` where no row constrains a component."""
    P = len(thetas)
    H = (np.zeros((P, P)) if not rows else
         _normal_equations(thetas, robot, bending, world_T_base, rows, None, threshold)[0])
    free = np.diag(H) > 0.0
    C = np.zeros((P, P))
    if free.any():
        try:
            C[np.ix_(free, free)] = np.linalg.inv(H[np.ix_(free, free)])
        except np.linalg.LinAlgError:
            free[:] = False
    C[np.flatnonzero(~free), np.flatnonzero(~free)] = np.inf
    return bending.blocks(C).reshape(-1)
