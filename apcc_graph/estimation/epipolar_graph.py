"""The generalized epipolar graph over a whole sequence (``GraphOptions(vision="epipolar")``).

Kept for comparison with the projection model and as the front end's two-view geometry. It
pairs each frame with several earlier ones (``gaps``), so an observation enters up to
``2 len(gaps)`` pairs: it counts observations several times and uses only part of each track's
baseline (``docs/estimation.md`` explains why the projection model replaced it).

Variables: ``theta[f, i]`` (Vector1) for every frame and segment, key ``f * S + i``. Factors:

- a prior on frame 0 (the starting configuration, ``theta0_sigma``);
- a random-walk motion prior between consecutive frames of each segment (``motion_sigma``
  rad/sqrt(s); ``None`` to leave it out);
- soft joint limits;
- generalized epipolar factors (:mod:`apcc_graph.factors.epipolar`) for every camera between each
  frame and several earlier frames, ``gaps`` apart, when they share at least ``min_shared`` tracks.

Correspondences whose Sampson error at the current estimate exceeds ``gate_px`` are left out
(gross outliers); the rest enter with a robust loss per correspondence. The solve runs in rounds:
short baselines first, then every gap, re-gated at the previous round's solution, until the
angles stop moving.
"""

from __future__ import annotations

import math
from dataclasses import replace

import gtsam
import numpy as np

from apcc_graph.estimation.options import GraphOptions, loss_scale, reuse_factor
from apcc_graph.factors.epipolar import epipolar_frame_factor
from apcc_graph.factors.priors import angle_prior, joint_limit_factor, motion_prior
from apcc_graph.frontend.geometry import SegmentTwoView, epipolar_errors, slope_gate
from apcc_graph.model.sequence import Sequence


def angle_key(frame: int, segment: int, n_segments: int) -> int:
    """The graph key of ``theta[frame, segment]``."""
    return frame * n_segments + segment


def _world_T_base(sequence: Sequence, frame: int) -> np.ndarray:
    return np.eye(4) if sequence.world_T_base is None else sequence.world_T_base[frame]


def build_graph(
    sequence: Sequence,
    initial: np.ndarray,
    theta0: np.ndarray,
    options: GraphOptions,
    frames: range | None = None,
) -> gtsam.NonlinearFactorGraph:
    """The factor graph of frames ``frames`` (default all); see the module docstring."""
    o = options
    robot = sequence.robot
    n_seg = robot.n_segments
    frames = range(sequence.n_frames) if frames is None else frames
    graph = gtsam.NonlinearFactorGraph()
    first = frames.start
    for i in range(n_seg):
        graph.add(angle_prior(angle_key(first, i, n_seg), theta0[i], o.theta0_sigma))
    for f in frames:
        for i, seg in enumerate(robot.segments):
            graph.add(joint_limit_factor(angle_key(f, i, n_seg), seg.theta_max, o.limit_sigma))
            if o.motion_sigma is not None and f > first:
                dt = float(sequence.timestamps[f] - sequence.timestamps[f - 1])
                graph.add(motion_prior(angle_key(f - 1, i, n_seg), angle_key(f, i, n_seg),
                                       o.motion_sigma, dt))
    for i in robot.camera_segments:
        camera = robot.cameras[i]
        assert camera is not None
        sigma = o.threshold_px * reuse_factor(o) / camera.fx
        segs = robot.segments[: i + 1]
        for b in frames:
            pairs = []
            for gap in o.gaps:
                a = b - gap
                if a < first:
                    continue
                corr = sequence.correspondences(i, a, b)
                if len(corr) < o.min_shared:
                    continue
                keep = _gate(sequence, initial, i, a, b, corr.f_a, corr.f_b,
                             o.gate_px / camera.fx, o.min_baseline)
                if keep.sum() < o.min_shared:
                    continue
                pairs.append((a, corr.f_a[keep], corr.f_b[keep]))
            if not pairs:
                continue
            # One factor per camera and frame over all its pairs (one Python callback).
            graph.add(epipolar_frame_factor(
                [angle_key(b, j, n_seg) for j in range(i + 1)],
                [[angle_key(a, j, n_seg) for j in range(i + 1)] for a, _, _ in pairs],
                segs, camera.tip_T_cam, _world_T_base(sequence, b),
                [_world_T_base(sequence, a) for a, _, _ in pairs], [p[1] for p in pairs],
                [p[2] for p in pairs], sigma, o.loss, loss_scale(o)))
    return graph


def _gate(sequence: Sequence, initial: np.ndarray, cam: int, a: int, b: int,
          f_a: np.ndarray, f_b: np.ndarray, gate: float, min_baseline: float) -> np.ndarray:
    """Correspondences whose Sampson error at the initial estimate is under ``gate`` radians.

    None when the camera moved less than ``min_baseline`` metres between the frames: near zero
    motion the Sampson error is the ratio of two vanishing quantities, its slope grows like
    1 / |t| and the pair carries no parallax information (the motion prior carries it).
    """
    robot = sequence.robot
    # The segment's base motion from the initial angles of the segments below it.
    base_a, base_b = _world_T_base(sequence, a), _world_T_base(sequence, b)
    chain = robot.forward(np.stack([initial[a], initial[b]]), world_T_base=np.stack([base_a,
                                                                                    base_b]))
    seg_base_a = base_a if cam == 0 else chain[0, cam - 1]
    seg_base_b = base_b if cam == 0 else chain[1, cam - 1]
    view = SegmentTwoView.build(initial[a, cam], robot.segments[cam],
                                robot.cameras[cam].tip_T_cam,
                                np.linalg.inv(seg_base_a) @ seg_base_b)
    if np.linalg.norm(view.relative_pose(initial[b, cam])[:3, 3]) < min_baseline:
        return np.zeros(len(f_a), dtype=bool)
    e, de = epipolar_errors(f_a, f_b, view, initial[b, cam], derivative=True)
    # Near the epipole the Sampson slope explodes (no parallax information): leave those out.
    return (np.abs(e) < gate) & slope_gate(de)


def _values(thetas: np.ndarray) -> gtsam.Values:
    n_frames, n_seg = thetas.shape
    values = gtsam.Values()
    for f in range(n_frames):
        for i in range(n_seg):
            values.insert(angle_key(f, i, n_seg), np.array([thetas[f, i]]))
    return values


def _optimise(graph: gtsam.NonlinearFactorGraph, thetas: np.ndarray,
              max_iterations: int) -> np.ndarray:
    """Levenberg-Marquardt from ``thetas``; returns the optimised ``(F, S)`` angles."""
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(max_iterations)
    params.setRelativeErrorTol(1e-5)
    params.setAbsoluteErrorTol(1e-9)
    result = gtsam.LevenbergMarquardtOptimizer(graph, _values(thetas), params).optimize()
    n_frames, n_seg = thetas.shape
    return np.array([[result.atVector(angle_key(f, i, n_seg))[0] for i in range(n_seg)]
                     for f in range(n_frames)])


def _marginal_sigmas(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values,
                     shape: tuple[int, int], dense_limit: int = 6000) -> np.ndarray:
    """Marginal standard deviations of every angle.

    ``gtsam.Marginals`` (sparse Cholesky) first. When it reports a (nearly) indeterminate
    system, the dense information matrix of the linearised graph is inverted with a
    pseudo-inverse instead (up to ``dense_limit`` variables); beyond that the sigmas are NaN
    (the angles themselves are still valid).
    """
    n_frames, n_seg = shape
    try:
        marg = gtsam.Marginals(graph, values)
        return np.array([[math.sqrt(max(marg.marginalCovariance(angle_key(f, i, n_seg))[0, 0],
                                        0.0)) for i in range(n_seg)] for f in range(n_frames)])
    except RuntimeError:
        pass
    sigmas = np.full(shape, np.nan)
    if n_frames * n_seg > dense_limit:
        return sigmas
    ordering = gtsam.Ordering()
    for f in range(n_frames):
        for i in range(n_seg):
            ordering.push_back(angle_key(f, i, n_seg))
    info, _ = graph.linearize(values).hessian(ordering)
    cov = np.linalg.pinv(info, hermitian=True)
    return np.sqrt(np.maximum(np.diag(cov), 0.0)).reshape(n_frames, n_seg)


def epipolar_solve(sequence: Sequence, initial: np.ndarray, theta0: np.ndarray,
                   options: GraphOptions, max_iterations: int = 20, max_rounds: int = 6,
                   round_tolerance: float = math.radians(0.01), marginals: bool = True
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Angles ``(F, S)`` and marginal sigmas of the epipolar batch, started at ``initial``.

    Rounds: short baselines first (gated at the initial estimate), then every gap, re-gated at
    the previous round's solution; long baselines only enter once the estimate is good enough
    to tell their inliers from outliers.
    """
    short = tuple(g for g in options.gaps if g <= 2) or options.gaps[:1]
    thetas = initial
    graph = build_graph(sequence, thetas, theta0, replace(options, gaps=short))
    thetas = _optimise(graph, thetas, max_iterations)
    for _ in range(max_rounds):
        graph = build_graph(sequence, thetas, theta0, options)
        previous, thetas = thetas, _optimise(graph, thetas, max_iterations)
        if np.max(np.abs(thetas - previous)) < round_tolerance:
            break
    sigmas = np.full_like(thetas, np.nan)
    if marginals:
        sigmas = _marginal_sigmas(graph, _values(thetas), thetas.shape)
    return thetas, sigmas
