"""The batch with model error as noise: camera poses as variables, the kinematics as soft ties
(``docs/estimation.md``, "Model error as noise").

A real segment is only approximately an APCC segment: its tip misses the model's by millimetres
and degrees. Projecting every observation through the exact model turns that mismatch into
contradictions between cameras and frames. Here the graph says the model is approximate:

- variables: each frame's vector ``x_f`` (the robot's parameterisation), each segment tip's pose
  ``world_T_tip`` per frame and each track's 3-D point (keys:
  :mod:`apcc_graph.factors.keys`);
- each segment's tip is tied to its base (the previous tip, or the robot's base) through the
  segment's APCC transform at ``x_f`` by :func:`~apcc_graph.factors.kinematic.segment_tie_factor`
  with the model noise ``GraphOptions.model_sigma`` (position and rotation of the tip, in the
  tip's frame);
- the observations are gtsam's C++ projection factors on the tip pose (the camera mount as the
  sensor's offset) and the track's point, each whitened by its own pixel Jacobian; a weak prior
  keeps a point at the end of a short baseline in place;
- the start prior, the motion prior and the joint limits on ``x_f`` as in the exact batch.

Outliers are decided without the model first (:func:`~apcc_graph.frontend.rotation_pairs.
pair_inliers`), then by each observation's residual at the solution against its track's point
(truncated quadratic), until no decision changes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import gtsam
import numpy as np

from apcc_graph.estimation.batch_solve import BatchReport, ProjectionSolution
from apcc_graph.estimation.graph import observed_cameras, prior_factors
from apcc_graph.estimation.options import GraphOptions, Robustness
from apcc_graph.factors.keys import frame_key, point_key, tip_key
from apcc_graph.factors.kinematic import segment_tie_factor
from apcc_graph.factors.track_points import TrackObservations
from apcc_graph.factors.triangulation import robust_triangulate
from apcc_graph.frontend.rotation_pairs import pair_inliers
from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.parameterisation import Bending
from apcc_graph.model.sequence import Sequence

__all__ = ["POINT_PRIOR_SIGMA", "forward_tips", "pose_solve", "square_root_information"]

POINT_PRIOR_SIGMA = 10.0
"""Standard deviation (metres) of the weak prior on each track's point around its first
triangulation: it only holds a point whose rays are nearly parallel."""


def forward_tips(bending: Bending, x: FloatArray, bases: FloatArray) -> FloatArray:
    """``(F, S, 4, 4)`` every segment tip's ``world_T_tip`` at the frame vectors ``x``
    ``(F, dim)``, from the base poses ``bases`` ``(F, 4, 4)``."""
    out = np.empty((len(x), bending.n_segments, 4, 4))
    for f, (vector, base) in enumerate(zip(x, bases, strict=True)):
        T = base
        for j in range(bending.n_segments):
            T = T @ bending.transform(vector, j)
            out[f, j] = T
    return out


def square_root_information(W: FloatArray) -> FloatArray:
    """``(N, 2, 2)`` upper-triangular ``R`` with ``R^T R = W^T W`` (the same whitened norm as
    ``W``, in the form gtsam's ``SqrtInformation`` expects)."""
    return np.swapaxes(np.linalg.cholesky(np.swapaxes(W, -1, -2) @ W), -1, -2)


@dataclass
class _Camera:
    """One camera's observations, mount, decisions and points."""

    obs: TrackObservations
    mount: FloatArray
    root_information: FloatArray
    weights: FloatArray
    points: FloatArray | None = None

    def poses(self, tips: FloatArray) -> tuple[FloatArray, FloatArray]:
        """``(N, 3, 3)``, ``(N, 3)`` the camera pose of each row, from the tips."""
        cams = tips[self.obs.frames, self.obs.camera] @ self.mount
        return cams[:, :3, :3], cams[:, :3, 3]

    def counted_tracks(self) -> np.ndarray:
        """``(T,)`` the tracks with at least two inlier rows (in the graph)."""
        return np.bincount(self.obs.tracks, self.weights > 0.0, self.obs.n_tracks) >= 2


def _cameras(sequence: Sequence, options: GraphOptions) -> list[_Camera]:
    """Each observing camera with its first, model-free decisions."""
    out = []
    for obs in observed_cameras(sequence, options):
        bearings = np.column_stack([obs.xy, np.ones(len(obs))])
        weights = pair_inliers(obs.frames, obs.tracks, bearings).astype(float)
        camera = sequence.robot.cameras[obs.camera]
        assert camera is not None
        out.append(_Camera(obs, camera.tip_T_cam, square_root_information(obs.whiten),
                           weights))
    return out


def _kinematic_graph(sequence: Sequence, bending: Bending, bases: FloatArray,
                     theta0: FloatArray | None, options: GraphOptions
                     ) -> gtsam.NonlinearFactorGraph:
    """Priors on the frame vectors and the segment ties of every frame."""
    assert options.model_sigma is not None
    position, rotation = options.model_sigma
    noise = [rotation] * 3 + [position] * 3
    graph = gtsam.NonlinearFactorGraph()
    frames = range(sequence.n_frames)
    for factor in prior_factors(frames, sequence.timestamps, theta0, bending, options):
        graph.add(factor)
    for f in frames:
        for j in range(bending.n_segments):
            base = bases[f] if j == 0 else tip_key(f, j - 1)
            graph.add(segment_tie_factor(frame_key(f), tip_key(f, j), base, bending, j, noise))
    return graph


def _add_vision(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values,
                cameras: list[_Camera]) -> None:
    """Each camera's inlier observations (C++ projection factors) and its points."""
    K = gtsam.Cal3_S2(1.0, 1.0, 0.0, 0.0, 0.0)
    prior = gtsam.noiseModel.Isotropic.Sigma(3, POINT_PRIOR_SIGMA)
    for c in cameras:
        obs, body = c.obs, gtsam.Pose3(c.mount)
        keep = c.counted_tracks()
        rows = np.flatnonzero((c.weights > 0.0) & keep[obs.tracks])
        for k in rows.tolist():
            noise = gtsam.noiseModel.Gaussian.SqrtInformation(
                c.root_information[k] * math.sqrt(c.weights[k]), False)
            graph.add(gtsam.GenericProjectionFactorCal3_S2(
                obs.xy[k], noise, tip_key(int(obs.frames[k]), obs.camera),
                point_key(obs.camera, int(obs.tracks[k])), K, body))
        assert c.points is not None
        for t in np.flatnonzero(keep).tolist():
            key = point_key(obs.camera, t)
            graph.add(gtsam.PriorFactorPoint3(key, c.points[t], prior))
            values.insert(key, c.points[t])


def _measure(cameras: list[_Camera], tips: FloatArray, threshold: float | None) -> int:
    """Triangulate every track at the tips (robustly, from the last points); with
    ``threshold``, decide every row afresh by its residual norm; returns how many rows
    changed side."""
    changed = 0
    for c in cameras:
        R, o = c.poses(tips)
        # The first time from the model-free decisions; then every row, from the last points.
        weights = c.weights if c.points is None else np.ones(len(c.obs))
        c.points, norms = robust_triangulate(c.obs, R, o, weights, c.points)
        if threshold is not None:
            new = (norms <= threshold).astype(float)
            changed += int(np.sum((new > 0.0) != (c.weights > 0.0)))
            c.weights = new
    return changed


def _values(x: FloatArray, tips: FloatArray) -> gtsam.Values:
    values = gtsam.Values()
    for f, vector in enumerate(x):
        values.insert(frame_key(f), np.asarray(vector, dtype=float))
        for j, T in enumerate(tips[f]):
            values.insert(tip_key(f, j), gtsam.Pose3(T))
    return values


def _read(values: gtsam.Values, n_frames: int, n_segments: int
          ) -> tuple[FloatArray, FloatArray]:
    x = np.array([values.atVector(frame_key(f)) for f in range(n_frames)])
    tips = np.array([[values.atPose3(tip_key(f, j)).matrix() for j in range(n_segments)]
                     for f in range(n_frames)])
    return x, tips


def _marginal_blocks(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, n_frames: int,
                     bending: Bending) -> FloatArray:
    """``(F, S, w, w)`` marginal covariance of each segment's components; NaN when the
    system is singular."""
    w = bending.width
    out = np.full((n_frames, bending.n_segments, w, w), np.nan)
    try:
        marginals = gtsam.Marginals(graph, values)
    except RuntimeError:
        return out
    for f in range(n_frames):
        cov = marginals.marginalCovariance(frame_key(f))
        for j in range(bending.n_segments):
            out[f, j] = cov[w * j:w * (j + 1), w * j:w * (j + 1)]
    return out


def pose_solve(sequence: Sequence, initial: FloatArray, theta0: FloatArray | None,
               options: GraphOptions, robustness: Robustness | None = None,
               max_iterations: int = 30, max_final_rounds: int = 4,
               marginals: bool = True, bending: Bending | None = None) -> ProjectionSolution:
    """Frame vectors, covariances and inliers of the batch with model noise, started at
    ``initial`` (module docstring).

    Args:
        sequence: the sequence.
        initial: ``(F, dim)`` initial frame vectors of ``bending`` (radians); the tips start
            at the model's tips there.
        theta0: ``(dim,)`` start prior's mean, or ``None``.
        options: the measurement model; ``options.model_sigma`` must be set.
        robustness: the inlier threshold of the residual test (its GNC schedule is not used:
            the first decisions come from the images alone).
        max_iterations: Levenberg-Marquardt iterations per round.
        max_final_rounds: most rounds of residual decisions after the first solve.
        marginals: compute marginal covariances (otherwise NaN).
        bending: the parameterisation (default: the planar robot's fixed planes).

    Raises:
        ValueError: ``options.model_sigma`` is ``None`` (the exact model: use
            :func:`~apcc_graph.estimation.batch_solve.projection_solve`).
    """
    if options.model_sigma is None:
        raise ValueError("pose_solve needs GraphOptions.model_sigma (position m, rotation "
                         "rad); None is the exact model, solved by projection_solve")
    robustness = Robustness() if robustness is None else robustness
    robot = sequence.robot
    bending = Bending.fixed(robot.segments) if bending is None else bending
    F = sequence.n_frames
    bases = np.broadcast_to(np.eye(4) if sequence.world_T_base is None
                            else sequence.world_T_base, (F, 4, 4))
    x = np.array(initial, dtype=float)
    tips = forward_tips(bending, x, bases)
    kinematics = _kinematic_graph(sequence, bending, bases, theta0, options)
    cameras = _cameras(sequence, options)
    _measure(cameras, tips, None)
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(max_iterations)
    params.setRelativeErrorTol(1e-6)
    iterations = rounds = 0
    graph = kinematics
    while rounds <= max_final_rounds:
        rounds += 1
        graph = gtsam.NonlinearFactorGraph(kinematics)
        values = _values(x, tips)
        _add_vision(graph, values, cameras)
        optimizer = gtsam.LevenbergMarquardtOptimizer(graph, values, params)
        values = optimizer.optimize()
        iterations += optimizer.iterations()
        x, tips = _read(values, F, bending.n_segments)
        if _measure(cameras, tips, robustness.inlier_sigmas) == 0:
            break
    blocks = (_marginal_blocks(graph, values, F, bending) if marginals else
              np.full((F, bending.n_segments, bending.width, bending.width), np.nan))
    inliers = np.zeros((F, sequence.n_segments), dtype=np.int64)
    for c in cameras:
        inliers[:, c.obs.camera] = np.bincount(c.obs.frames[c.weights > 0.0], minlength=F)[:F]
    report = BatchReport(rounds, iterations, int(sum(np.sum(c.weights == 0.0) for c in cameras)),
                         int(sum(len(c.obs) for c in cameras)))
    return ProjectionSolution(x, blocks, inliers, report)
