"""What the images and an approximate model tell: the Fisher information of the model-noise
graph, each point eliminated (``docs/estimation.md``, "The yardsticks of real motion").

With the model's error as noise at the calibration's size
(:mod:`apcc_graph.estimation.model_noise`) the unknowns are every frame's vector, every segment
end's pose ``world_T_tip`` (tied to the model with that noise:
:mod:`~apcc_graph.estimation.model_ties`), and a point per track; the observations are the tip
cameras' pixels, pinholes ``fx, fy, cx, cy`` with the pixel noise (distortion left out: it
changes the Jacobians by little). :func:`noise_graph` builds that graph at given values, and
:func:`marginal_columns` solves its information ``J^T J`` for the marginal covariance of chosen
variables: each point's ``3 x 3`` block is eliminated exactly (a Schur complement: a point seen
from nearly one place, whose depth only the weak prior fixes, makes gtsam's ``Marginals``
refuse the whole graph), and the reduced sparse system is factored once (LU). The measurement
values do not enter; the Jacobians are taken at the values.

Two users: the Cramér-Rao bound of real motion (:mod:`apcc_graph.evaluation.noise_bound`, at
the truth) and the unknown-start search (:func:`start_blocks`, at its best start), whose exact
model's sigmas ignore what the model's error hides.
"""

from __future__ import annotations

from collections.abc import Mapping

import gtsam
import numpy as np
import scipy.sparse
import scipy.sparse.linalg

from apcc_graph.estimation.graph import camera_chain, observed_cameras
from apcc_graph.estimation.model_noise import segment_correlations, segment_sigmas
from apcc_graph.estimation.model_ties import ModelTies
from apcc_graph.estimation.options import GraphOptions
from apcc_graph.estimation.terms.noisy import POINT_PRIOR_SIGMA, forward_tips
from apcc_graph.factors.keys import frame_key, kind, point_key, tip_key
from apcc_graph.factors.reduced_system import robust_residual_norms
from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.parameterisation import Bending
from apcc_graph.model.robot import Robot
from apcc_graph.model.sequence import Sequence

POINT_SIZE = 3
"""A point's tangent size."""
POSE_SIZE = 6
"""A segment end's pose's tangent size."""
LOOSE_POINT_SIGMA = 1000.0
"""The prior of a point around its triangulation at an estimate (metres): it only keeps the
elimination finite. The estimators' 10 m prior, centred there, would be information the
images never gave: a track of a robot that barely moves is triangulated decimetres to metres
off along its ray, and such priors made the information of a model-exact second of motion
tell segment 1 to 0.24 deg where its bound is 1.9 (0.235 against 1.947 at 1 km)."""

Rows = tuple[np.ndarray, np.ndarray, FloatArray]
"""One camera's kept observations: ``(N,)`` frames, ``(N,)`` track indices (a point each),
``(N, 3)`` the point of each row (world, metres)."""


def noise_graph(robot: Robot, bases: FloatArray | None, vectors: FloatArray,
                tips: FloatArray, bending: Bending, sigmas: tuple[tuple[float, float], ...],
                noise_px: float, theta0_sigma: float | None, correlations: tuple[float, ...],
                rows: Mapping[int, Rows], point_sigma: float = POINT_PRIOR_SIGMA
                ) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values]:
    """The model-noise graph at given values (module docstring).

    Args:
        robot: the robot (segments, cameras).
        bases: ``(F, 4, 4)`` the base pose per frame, or ``None`` (at the origin).
        vectors: ``(F, dim)`` the frame vectors of ``bending``.
        tips: ``(F, S, 4, 4)`` every segment end's ``world_T_tip``.
        bending: the parameterisation.
        sigmas: per segment, the model noise (position m, rotation rad).
        noise_px: the pixel noise (pixels).
        theta0_sigma: the start prior on frame 0's vector (radians), or ``None``.
        correlations: per segment, the model error's correlation length in bend (radians; 0:
            independent per frame).
        rows: camera -> its observations that count (:data:`Rows`; a track seen in one row
            only tells nothing and is left out).
        point_sigma: the prior of each point around its value (metres; default the
            estimators' weak prior).
    """
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    ties = ModelTies(bending, sigmas, correlations)
    vectors = np.asarray(vectors, dtype=float)
    for f, x in enumerate(vectors):
        base = np.eye(4) if bases is None else bases[f]
        values.insert(frame_key(f), x)
        for j in range(robot.n_segments):
            values.insert(tip_key(f, j), gtsam.Pose3(tips[f, j]))
        before = None if f == 0 else (f - 1, vectors[f - 1],
                                      np.eye(4) if bases is None else bases[f - 1])
        for factor in ties.frame(f, x, base, before):
            graph.add(factor)
    if theta0_sigma is not None:
        graph.add(gtsam.PriorFactorVector(frame_key(0), vectors[0],
                                          gtsam.noiseModel.Isotropic.Sigma(bending.dim,
                                                                           theta0_sigma)))
    pixel = gtsam.noiseModel.Isotropic.Sigma(2, noise_px)
    weak = gtsam.noiseModel.Isotropic.Sigma(POINT_SIZE, point_sigma)
    for cam, (frames, tracks, points) in rows.items():
        camera = robot.cameras[cam]
        assert camera is not None
        K = gtsam.Cal3_S2(camera.fx, camera.fy, 0.0, camera.cx, camera.cy)
        body = gtsam.Pose3(camera.tip_T_cam)
        for f, t, p in zip(frames.tolist(), tracks.tolist(), points, strict=True):
            key = point_key(cam, int(t))
            if not values.exists(key):
                values.insert(key, p)
                graph.add(gtsam.PriorFactorPoint3(key, p, weak))
            graph.add(gtsam.GenericProjectionFactorCal3_S2(
                np.array([camera.cx, camera.cy]), pixel, tip_key(int(f), cam), key, K, body))
    return graph, values


def information(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values
                ) -> tuple[scipy.sparse.csc_matrix, dict[int, int], list[int]]:
    """The Fisher information ``J^T J`` of ``graph`` at ``values`` (sparse), the first column
    of each key, and the columns of the points."""
    keys = sorted(values.keys())  # gtsam's sparse Jacobian orders the keys so
    start, column = {}, 0
    for key in keys:
        start[key] = column
        column += {"l": POINT_SIZE, "t": POSE_SIZE}.get(kind(key)) or len(values.atVector(key))
    triplets = graph.linearize(values).sparseJacobian_()
    rows, cols, data = triplets[0] - 1, triplets[1] - 1, triplets[2]
    inside = cols < column  # the last column is the right-hand side
    J = scipy.sparse.csc_matrix((data[inside], (rows[inside].astype(np.int64),
                                                cols[inside].astype(np.int64))),
                                shape=(int(rows.max()) + 1, column))
    points = [c for key in keys if kind(key) == "l"
              for c in range(start[key], start[key] + POINT_SIZE)]
    return (J.T @ J).tocsc(), start, points


def reduced(H: scipy.sparse.csc_matrix, points: list[int]
            ) -> tuple[scipy.sparse.csc_matrix, np.ndarray]:
    """The information of every variable but the points, the points eliminated (their blocks
    are 3 x 3 and independent), and the kept columns."""
    keep = np.setdiff1d(np.arange(H.shape[0]), points)
    if not points:
        return H, keep
    P = np.asarray(points).reshape(-1, POINT_SIZE)
    blocks = np.stack([H[p][:, p].toarray() for p in P])
    inverse = scipy.sparse.block_diag(list(np.linalg.inv(blocks)), format="csc")
    flat = P.ravel()
    H_xp = H[keep][:, flat]
    return (H[keep][:, keep] - H_xp @ inverse @ H_xp.T).tocsc(), keep


def marginal_columns(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values,
                     wanted: list[tuple[int, np.ndarray]]) -> list[FloatArray] | None:
    """For each ``(key, offsets)`` in ``wanted``, the marginal covariance of those tangent
    components of that key (``len(offsets)`` square), the points eliminated; ``None`` where
    the information is singular (some unknown undetermined)."""
    H, start, points = information(graph, values)
    system, keep = reduced(H, points)
    where = np.full(H.shape[0], -1)
    where[keep] = np.arange(len(keep))
    columns = [where[start[key] + np.asarray(offsets)] for key, offsets in wanted]
    rhs = np.zeros((len(keep), sum(len(c) for c in columns)))
    first = np.cumsum([0] + [len(c) for c in columns])
    for n, cols in enumerate(columns):
        rhs[cols, first[n] + np.arange(len(cols))] = 1.0
    try:
        solved = scipy.sparse.linalg.splu(system).solve(rhs)
    except RuntimeError:  # singular
        return None
    return [solved[cols][:, first[n]:first[n + 1]] for n, cols in enumerate(columns)]


def start_blocks(window: Sequence, x: FloatArray, bending: Bending, options: GraphOptions,
                 inlier_sigmas: float, prior_sigma: float) -> FloatArray | None:
    """``(S, w, w)`` frame 0's marginal covariance blocks at the frame vectors ``x`` of
    ``window`` with the model's error as
    noise as ``options`` say (its ``model_sigma`` and ``model_correlation``), or ``None``
    (the exact model, or a singular information). Each track's point is triangulated
    robustly at ``x``, and the observations within ``inlier_sigmas`` of it count; the start
    prior is ``prior_sigma`` (the search's weak one)."""
    robot = window.robot
    sigmas = segment_sigmas(options.model_sigma, robot)
    if sigmas is None:
        return None
    bases = window.world_T_base
    tips = forward_tips(bending, x, np.tile(np.eye(4), (len(x), 1, 1)) if bases is None
                        else bases)
    rows = {}
    for obs in observed_cameras(window, options):
        chain = camera_chain(robot, obs.camera, bending, bases)
        first, last = int(obs.frames.min()), int(obs.frames.max())
        norms, points = robust_residual_norms(obs, chain, x[first:last + 1], first,
                                              np.ones(len(obs)))
        kept = np.isfinite(norms) & (norms <= inlier_sigmas)
        seen = np.bincount(obs.tracks[kept], minlength=obs.n_tracks)
        kept &= seen[obs.tracks] >= 2
        rows[obs.camera] = (obs.frames[kept], obs.tracks[kept], points[obs.tracks[kept]])
    graph, values = noise_graph(robot, bases, x, tips, bending, sigmas, options.threshold_px,
                                prior_sigma, segment_correlations(options.model_correlation,
                                                                  robot), rows,
                                LOOSE_POINT_SIGMA)
    w = bending.width
    found = marginal_columns(graph, values, [(frame_key(0), np.arange(bending.dim))])
    if found is None:
        return None
    block = found[0]
    return np.stack([block[w * j:w * (j + 1), w * j:w * (j + 1)]
                     for j in range(bending.n_segments)])
