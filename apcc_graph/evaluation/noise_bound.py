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
tips is factored once (LU) and solved for the sampled tips' translation columns
(:mod:`apcc_graph.estimation.noise_information`, which the unknown-start search shares).
"""

from __future__ import annotations

import math

import gtsam
import numpy as np

from apcc_graph.estimation.noise_information import POSE_SIZE, marginal_columns, noise_graph
from apcc_graph.evaluation.tip_bound import TipBound
from apcc_graph.factors.keys import tip_key
from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.parameterisation import Bending
from apcc_graph.simulation.simulator import Simulation


def model_noise_graph(simulation: Simulation, vectors: FloatArray, bending: Bending,
                      sigmas: tuple[tuple[float, float], ...], noise_px: float,
                      theta0_sigma: float | None, correlations: tuple[float, ...] = (),
                      last_frame: int | None = None
                      ) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values]:
    """The model-noise graph at the truth (module docstring;
    :func:`~apcc_graph.estimation.noise_information.noise_graph`): ``vectors`` ``(F, dim)``
    the frame vectors, ``sigmas`` per segment (position m, rotation rad), ``correlations`` per
    segment the model error's correlation length in bend (radians; empty or 0: independent
    per frame). ``last_frame``: the frames up to it only (what a smoother has seen
    when it lets a frame go)."""
    seq = simulation.sequence
    robot = seq.robot
    end = seq.n_frames if last_frame is None else last_frame + 1
    rows = {}
    for cam in robot.camera_segments:
        tracks = seq.tracks[cam]
        keep = ~simulation.outliers[cam] & (tracks.frames < end)
        ids, track = np.unique(tracks.track_ids, return_inverse=True)
        seen = np.bincount(track[keep], minlength=len(ids))
        kept = keep & (seen[track] >= 2)  # a point per track, as the estimators keep them
        rows[cam] = (tracks.frames[kept], track[kept],
                     simulation.points_world[simulation.landmarks[cam][kept]])
    bases = None if seq.world_T_base is None else seq.world_T_base[:end]
    return noise_graph(robot, bases, vectors[:end], simulation.world_T_tip[:end], bending,
                       sigmas, noise_px, theta0_sigma,
                       correlations or (0.0,) * robot.n_segments, rows)


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
    return TipBound(frames, _tip_sigmas(graph, values, frames, simulation.sequence.n_segments),
                    None)


def model_noise_lag_bound(simulation: Simulation, vectors: FloatArray, bending: Bending,
                          sigmas: tuple[tuple[float, float], ...], noise_px: float,
                          theta0_sigma: float | None, lag_frames: int, step: int = 10,
                          correlations: tuple[float, ...] = ()) -> TipBound:
    """The bound of :func:`model_noise_tip_bound` for a fixed-lag smoother that lets frame
    ``f`` go ``lag_frames`` frames later: at each sampled frame, from the frames up to
    ``f + lag_frames`` only (one graph and one factorisation per sample)."""
    if step < 1 or lag_frames < 0:
        raise ValueError(f"step = {step!r}, lag_frames = {lag_frames!r}: expected step >= 1 "
                         "and lag_frames >= 0")
    n_frames, S = simulation.sequence.n_frames, simulation.sequence.n_segments
    frames = np.arange(0, n_frames, step, dtype=np.int64)
    out = np.full((len(frames), S), math.inf)
    for n, f in enumerate(frames.tolist()):
        graph, values = model_noise_graph(simulation, vectors, bending, sigmas, noise_px,
                                          theta0_sigma, correlations,
                                          last_frame=min(f + lag_frames, n_frames - 1))
        out[n] = _tip_sigmas(graph, values, np.array([f]), S)[0]
    return TipBound(frames, out, None)


def _tip_sigmas(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, frames: FloatArray,
                S: int) -> FloatArray:
    """``(len(frames), S)`` the bound of each segment end's position at ``frames`` (inf where
    undetermined)."""
    out = np.full((len(frames), S), math.inf)
    translation = POSE_SIZE // 2 + np.arange(3)  # a pose's tangent: rotation, then translation
    found = marginal_columns(graph, values, [(tip_key(int(f), j), translation)
                                             for f in frames for j in range(S)])
    if found is None:  # singular: some unknown is undetermined
        return out
    for n, block in enumerate(found):
        variance = float(np.trace(block))
        out[n // S, n % S] = (math.sqrt(variance) if math.isfinite(variance) and variance >= 0
                              else math.inf)
    return out
