"""The Cramer-Rao bound of the segment ends with the model's error as noise: what the images and
an approximate model together tell (``docs/estimation.md``, "The yardsticks of real motion").

On a real robot the kinematic model is only approximately right. With its error as noise at
the calibration's size (:mod:`apcc_graph.estimation.model_noise`), the unknowns are every
frame's vector, every segment end's pose ``world_T_tip`` (tied to the model with that noise),
and every tracked point; the observations are the tip cameras' pixels. The bound of a segment
end's position is the position block of its pose's marginal covariance under the Fisher
information at the truth, ``sqrt(trace)`` the least RMS error norm an unbiased estimator can
have. This is the information of the model-noise graph
(:mod:`apcc_graph.estimation.terms.noisy`) linearised at the true values, so gtsam's marginals
of that graph are the bound:

- the values: the frame vectors given (on a replayed real motion, the floor's bends), the true
  segment ends (the measured ones), the true scene points;
- the factors: the start prior on frame 0's vector, the segment ties with the model noise
  (each a transition from the frame before where the model error drifts along the bends:
  :mod:`~apcc_graph.estimation.model_ties`, at the given frame vectors), a
  projection factor per observation that is not an outlier (the truth knows), a point per track
  seen twice or more (as the estimators keep them, a landmark tracked twice is two points) and
  the weak prior of each point that the estimators have too; no motion prior (as
  :mod:`~apcc_graph.evaluation.tip_bound`);
- the cameras as pinholes in pixels (``fx, fy, cx, cy``) with the pixel noise; their distortion
  is left out (the replays have none).

The measurement values do not enter (the Jacobians are taken at the values), so the
observations' noise does not matter. Units: metres.

The marginals are computed here rather than by gtsam's ``Marginals``, which refuses the whole
graph as indeterminate when a point is seen from nearly one place (a robot at rest: only the
weak prior fixes its depth, a condition number of about 1e8 in its block). Each point's 3 x 3
block of the information matrix is eliminated exactly (a Schur complement; the far points' rays
still tell the tips' rotations), and the reduced sparse system over the frame vectors and the
tips is factored once (LU) and solved for the sampled tips' translation columns.
"""

from __future__ import annotations

import math

import gtsam
import numpy as np
import scipy.sparse
import scipy.sparse.linalg

from apcc_graph.estimation.model_ties import ModelTies
from apcc_graph.estimation.terms.noisy import POINT_PRIOR_SIGMA
from apcc_graph.evaluation.tip_bound import TipBound
from apcc_graph.factors.keys import frame_key, kind, point_key, tip_key
from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.parameterisation import Bending
from apcc_graph.simulation.simulator import Simulation


def model_noise_graph(simulation: Simulation, vectors: FloatArray, bending: Bending,
                      sigmas: tuple[tuple[float, float], ...], noise_px: float,
                      theta0_sigma: float | None, correlations: tuple[float, ...] = ()
                      ) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values]:
    """The model-noise graph at the truth (module docstring): ``vectors`` ``(F, dim)`` the
    frame vectors, ``sigmas`` per segment (position m, rotation rad), ``correlations`` per
    segment the model error's correlation length in bend (radians; empty or 0: independent
    per frame)."""
    seq = simulation.sequence
    robot = seq.robot
    base = np.eye(4) if seq.world_T_base is None else np.asarray(seq.world_T_base)
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    ties = ModelTies(bending, sigmas, correlations or (0.0,) * robot.n_segments)
    vectors = np.asarray(vectors, dtype=float)
    for f, x in enumerate(vectors):
        values.insert(frame_key(f), x)
        for j in range(robot.n_segments):
            values.insert(tip_key(f, j), gtsam.Pose3(simulation.world_T_tip[f, j]))
        for factor in ties.frame(f, x, base, None if f == 0 else (f - 1, vectors[f - 1], base)):
            graph.add(factor)
    if theta0_sigma is not None:
        graph.add(gtsam.PriorFactorVector(frame_key(0), np.asarray(vectors[0], dtype=float),
                                          gtsam.noiseModel.Isotropic.Sigma(bending.dim,
                                                                           theta0_sigma)))
    pixel = gtsam.noiseModel.Isotropic.Sigma(2, noise_px)
    weak = gtsam.noiseModel.Isotropic.Sigma(3, POINT_PRIOR_SIGMA)
    for cam in robot.camera_segments:
        camera = robot.cameras[cam]
        assert camera is not None
        K = gtsam.Cal3_S2(camera.fx, camera.fy, 0.0, camera.cx, camera.cy)
        body = gtsam.Pose3(camera.tip_T_cam)
        tracks = seq.tracks[cam]
        keep = ~simulation.outliers[cam]
        marks = simulation.landmarks[cam]
        ids, track = np.unique(tracks.track_ids, return_inverse=True)
        seen = np.bincount(track[keep], minlength=len(ids))
        for row in np.flatnonzero(keep & (seen[track] >= 2)).tolist():
            point = point_key(cam, int(track[row]))  # a point per track, as the estimators
            if not values.exists(point):
                values.insert(point, simulation.points_world[marks[row]])
                graph.add(gtsam.PriorFactorPoint3(point, simulation.points_world[marks[row]],
                                                  weak))
            graph.add(gtsam.GenericProjectionFactorCal3_S2(
                simulation.clean_uv[cam][row], pixel, tip_key(int(tracks.frames[row]), cam),
                point, K, body))
    return graph, values


def _information(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values
                 ) -> tuple[scipy.sparse.csc_matrix, dict[int, int], list[int]]:
    """The Fisher information ``J^T J`` of ``graph`` at ``values`` (sparse), the first column
    of each key, and the columns of the points."""
    keys = sorted(values.keys())  # gtsam's sparse Jacobian orders the keys so
    start, column = {}, 0
    for key in keys:
        start[key] = column
        column += {"l": 3, "t": 6}.get(kind(key)) or len(values.atVector(key))
    triplets = graph.linearize(values).sparseJacobian_()
    rows, cols, data = triplets[0] - 1, triplets[1] - 1, triplets[2]
    inside = cols < column  # the last column is the right-hand side
    J = scipy.sparse.csc_matrix((data[inside], (rows[inside].astype(np.int64),
                                                cols[inside].astype(np.int64))),
                                shape=(int(rows.max()) + 1, column))
    points = [c for key in keys if kind(key) == "l" for c in range(start[key], start[key] + 3)]
    return (J.T @ J).tocsc(), start, points


def _reduced(H: scipy.sparse.csc_matrix, points: list[int]
             ) -> tuple[scipy.sparse.csc_matrix, np.ndarray]:
    """The information of every variable but the points, the points eliminated (their blocks
    are 3 x 3 and independent), and the kept columns."""
    keep = np.setdiff1d(np.arange(H.shape[0]), points)
    if not points:
        return H, keep
    P = np.asarray(points).reshape(-1, 3)
    blocks = np.stack([H[p][:, p].toarray() for p in P])
    inverse = scipy.sparse.block_diag(list(np.linalg.inv(blocks)), format="csc")
    flat = P.ravel()
    H_xp = H[keep][:, flat]
    return (H[keep][:, keep] - H_xp @ inverse @ H_xp.T).tocsc(), keep


def model_noise_tip_bound(simulation: Simulation, vectors: FloatArray, bending: Bending,
                          sigmas: tuple[tuple[float, float], ...], noise_px: float,
                          theta0_sigma: float | None, step: int = 10,
                          correlations: tuple[float, ...] = ()) -> TipBound:
    """The bound of every segment end's position at frames ``0, step, 2 step, ...`` with the
    model's error as noise (module docstring).

    Args:
        simulation: the recording and its truth (a replay of real motion: the measured ends).
        vectors: ``(F, dim)`` the frame vectors of ``bending`` at which to linearise.
        bending: the parameterisation.
        sigmas: per segment, the model noise (position m, rotation rad).
        noise_px: the pixel noise (pixels).
        theta0_sigma: the start prior (radians), or ``None``.
        step: sample every ``step``-th frame.
        correlations: per segment, the model error's correlation length in bend (radians;
            empty: independent per frame).
    """
    if step < 1:
        raise ValueError(f"step = {step!r}: expected >= 1")
    graph, values = model_noise_graph(simulation, vectors, bending, sigmas, noise_px,
                                      theta0_sigma, correlations)
    frames = np.arange(0, simulation.sequence.n_frames, step, dtype=np.int64)
    S = simulation.sequence.n_segments
    H, start, points = _information(graph, values)
    reduced, keep = _reduced(H, points)
    where = np.full(H.shape[0], -1)
    where[keep] = np.arange(len(keep))
    wanted = [(i, j, where[start[tip_key(f, j)] + 3 + np.arange(3)])
              for i, f in enumerate(frames.tolist()) for j in range(S)]
    rhs = np.zeros((len(keep), 3 * len(wanted)))
    for n, (_, _, cols) in enumerate(wanted):
        rhs[cols, 3 * n + np.arange(3)] = 1.0
    out = np.full((len(frames), S), math.inf)
    try:
        solved = scipy.sparse.linalg.splu(reduced).solve(rhs)
    except RuntimeError:  # singular: some unknown is undetermined
        return TipBound(frames, out, None)
    for n, (i, j, cols) in enumerate(wanted):
        variance = float(np.trace(solved[cols, 3 * n:3 * n + 3]))
        out[i, j] = math.sqrt(variance) if math.isfinite(variance) and variance >= 0 else math.inf
    return TipBound(frames, out, None)
