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
- the factors: the start prior on frame 0's vector, the segment ties with the model noise, a
  projection factor per observation that is not an outlier (the truth knows), a point per track
  seen twice or more (as the estimators keep them, a landmark tracked twice is two points) and
  the weak prior of each point that the estimators have too; no motion prior (as
  :mod:`~apcc_graph.evaluation.tip_bound`);
- the cameras as pinholes in pixels (``fx, fy, cx, cy``) with the pixel noise; their distortion
  is left out (the replays have none).

The measurement values do not enter (the Jacobians are taken at the values), so the
observations' noise does not matter. Units: metres.
"""

from __future__ import annotations

import math

import gtsam
import numpy as np

from apcc_graph.estimation.model_noise import tie_sigmas
from apcc_graph.estimation.terms.noisy import POINT_PRIOR_SIGMA
from apcc_graph.evaluation.tip_bound import TipBound
from apcc_graph.factors.keys import frame_key, point_key, tip_key
from apcc_graph.factors.kinematic import segment_tie_factor
from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.parameterisation import Bending
from apcc_graph.simulation.simulator import Simulation


def model_noise_graph(simulation: Simulation, vectors: FloatArray, bending: Bending,
                      sigmas: tuple[tuple[float, float], ...], noise_px: float,
                      theta0_sigma: float | None) -> tuple[gtsam.NonlinearFactorGraph,
                                                           gtsam.Values]:
    """The model-noise graph at the truth (module docstring): ``vectors`` ``(F, dim)`` the
    frame vectors, ``sigmas`` per segment (position m, rotation rad)."""
    seq = simulation.sequence
    robot = seq.robot
    base = np.eye(4) if seq.world_T_base is None else np.asarray(seq.world_T_base)
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    for f, x in enumerate(np.asarray(vectors, dtype=float)):
        values.insert(frame_key(f), x)
        for j in range(robot.n_segments):
            values.insert(tip_key(f, j), gtsam.Pose3(simulation.world_T_tip[f, j]))
            graph.add(segment_tie_factor(frame_key(f), tip_key(f, j),
                                         base if j == 0 else tip_key(f, j - 1), bending, j,
                                         tie_sigmas(sigmas, j)))
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


def model_noise_tip_bound(simulation: Simulation, vectors: FloatArray, bending: Bending,
                          sigmas: tuple[tuple[float, float], ...], noise_px: float,
                          theta0_sigma: float | None, step: int = 10) -> TipBound:
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
    """
    if step < 1:
        raise ValueError(f"step = {step!r}: expected >= 1")
    graph, values = model_noise_graph(simulation, vectors, bending, sigmas, noise_px,
                                      theta0_sigma)
    frames = np.arange(0, simulation.sequence.n_frames, step, dtype=np.int64)
    S = simulation.sequence.n_segments
    out = np.full((len(frames), S), math.inf)
    try:
        marginals = gtsam.Marginals(graph, values)
    except RuntimeError:
        return TipBound(frames, out, None)  # some unknown is undetermined: inf
    for i, f in enumerate(frames.tolist()):
        for j in range(S):
            C = marginals.marginalCovariance(tip_key(f, j))
            out[i, j] = math.sqrt(max(float(np.trace(C[3:, 3:])), 0.0))
    return TipBound(frames, out, None)
