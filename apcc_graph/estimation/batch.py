"""Batch estimation of a whole sequence: one factor graph, Levenberg-Marquardt (gtsam).

Variables: ``theta[f, i]`` (Vector1) for every frame and segment, key ``f * S + i``. Factors:

- a prior on frame 0 (the starting configuration, ``theta0_sigma``);
- a random-walk motion prior between consecutive frames of each segment (``motion_sigma``
  rad/sqrt(s); ``None`` to leave it out);
- soft joint limits;
- generalized epipolar factors (:mod:`factors.epipolar`) for every camera between each frame and
  several earlier frames, ``gaps`` apart (default 1, 2, 5, 10, 20), when they share at least
  ``min_shared`` tracks. Long baselines between frames that share tracks are what bounds drift
  (NOTES.md section 5); the gaps keep the graph sparse (a few factors per frame and camera).

Correspondences whose Sampson error at the current estimate exceeds ``gate_px`` are left out
(gross outliers); the rest enter with a robust loss per correspondence. The solve runs in rounds:
short baselines first, gated at the chain's estimate; then every gap, re-gated at the previous
round's solution, until the angles stop moving. Long baselines only enter once the estimate is
good enough to tell their inliers from their outliers. The initial estimate is the fixed-lag
smoother's (:mod:`apcc_graph.estimation.smoother`, started by the 1-point front end) or, with
``init="chain"``, the paper's chain (:func:`apcc_graph.estimation.chain.chain_estimate`).
Marginal standard deviations come from ``gtsam.Marginals``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import gtsam
import numpy as np
from numpy.typing import ArrayLike

from apcc_graph.estimation.chain import chain_estimate
from apcc_graph.estimation.result import Estimate
from apcc_graph.geometry import SegmentTwoView, epipolar_errors
from apcc_graph.sequence import Sequence
from factors.epipolar import ROBUST_LOSSES, SLOPE_OUTLIER, epipolar_frame_factor
from factors.priors import angle_prior, joint_limit_factor, motion_prior

DEFAULT_GAPS = (1, 2, 5, 10, 20)


@dataclass(frozen=True)
class GraphOptions:
    """How the factor graph is built (shared by the batch optimiser and the smoother).

    Attributes:
        gaps: frame gaps between which epipolar factors are built.
        min_shared: fewest shared (and gated) tracks for a factor.
        threshold_px: pixel noise scale of the epipolar residuals (sigma, pixels).
        gate_px: correspondences with a larger Sampson error at the current estimate are left
            out (pixels).
        motion_sigma: random-walk prior strength (rad/sqrt(s)); ``None``: no motion prior.
        theta0_sigma: prior standard deviation of the starting configuration (radians).
        limit_sigma: softness of the joint limits (radians).
        loss: robust loss per correspondence (``"huber"``, ``"cauchy"``, ``"none"``).
        loss_sigmas: the robust loss's threshold in pixel-noise sigmas (``threshold_px``).
        min_baseline: pairs whose camera moved less (metres) are left out (no parallax).
        reuse_inflation: each observation enters about ``2 * len(gaps)`` frame pairs, whose
            residuals share its pixel noise; treating them as independent overcounts the
            evidence that many times. With this on (default) each pair's sigma is inflated by
            ``sqrt(2 * len(gaps))`` (a composite-likelihood weight: every observation counts
            once overall), which also keeps the marginal sigmas honest.
    """

    gaps: tuple[int, ...] = DEFAULT_GAPS
    min_shared: int = 15
    threshold_px: float = 1.0
    gate_px: float = 5.0
    motion_sigma: float | None = 0.5
    theta0_sigma: float = math.radians(1.0)
    limit_sigma: float = math.radians(1.0)
    loss: str = "huber"
    loss_sigmas: float = 1.345
    min_baseline: float = 0.002
    reuse_inflation: bool = True

    def __post_init__(self) -> None:
        if self.loss not in ROBUST_LOSSES:
            raise ValueError(f"robust loss {self.loss!r}: expected one of {ROBUST_LOSSES}")
        if not self.gaps or min(self.gaps) < 1:
            raise ValueError(f"gaps = {self.gaps!r}: expected positive frame gaps")


def reuse_factor(options: GraphOptions) -> float:
    """The pair-sigma inflation ``sqrt(2 * len(gaps))`` (1 without ``reuse_inflation``)."""
    return math.sqrt(2.0 * len(options.gaps)) if options.reuse_inflation else 1.0


def loss_scale(options: GraphOptions) -> float:
    """The robust loss threshold in whitened units: ``options.loss_sigmas`` pixel-noise sigmas
    (``threshold_px``), whatever the pair-sigma inflation: the m-estimator judges a
    correspondence against the pixel noise, not against the inflated pair sigma."""
    return options.loss_sigmas / reuse_factor(options)


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
    # Near the epipole the Sampson error's denominator vanishes and its slope explodes: such a
    # correspondence carries no parallax information, only ill-conditioning. Leave it out.
    slope = np.abs(de)
    sane = slope < SLOPE_OUTLIER * max(float(np.median(slope)), 1e-12)
    return (np.abs(e) < gate) & sane


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


def batch_estimate(
    sequence: Sequence,
    theta0: ArrayLike | None = None,
    initial: ArrayLike | None = None,
    options: GraphOptions | None = None,
    max_iterations: int = 20,
    max_rounds: int = 6,
    round_tolerance: float = math.radians(0.01),
    marginals: bool = True,
    progress: bool = False,
    init: str = "smoother",
) -> Estimate:
    """Optimise all frames and segments jointly.

    Args:
        sequence: the sequence (ground truth, if any, is never read).
        theta0: ``(S,)`` starting configuration (radians; default straight).
        initial: ``(F, S)`` initial angles; default from ``init``.
        init: where the initial angles come from when ``initial`` is not given:
            ``"smoother"`` (default; the fixed-lag smoother, itself started by the 1-point
            front end) or ``"chain"`` (the paper's chained 1-point estimate). The chain drifts
            by degrees on long sequences (``apcc-graph bench smoother``) and the batch, which
            gates correspondences at its initial estimate, then converges to a wrong
            configuration; the smoother's start avoids that.
        options: how the graph is built (:class:`GraphOptions`).
        max_iterations: Levenberg-Marquardt iterations per round.
        max_rounds: re-gating rounds with every gap (each starts from the previous solution
            and re-selects the correspondences at it), until the angles move less than
            ``round_tolerance`` (radians).
        round_tolerance: convergence of the rounds (radians).
        marginals: compute marginal standard deviations (otherwise NaN).
        progress: show progress bars.

    Returns:
        The estimate, ``method = "batch"``.
    """
    options = GraphOptions() if options is None else options
    if init not in ("smoother", "chain"):
        raise ValueError(f"init = {init!r}: expected 'smoother' or 'chain'")
    n_seg = sequence.n_segments
    theta0 = np.zeros(n_seg) if theta0 is None else np.asarray(theta0, dtype=float)
    if initial is None and init == "smoother":
        from apcc_graph.estimation.smoother import smoother_estimate

        first = smoother_estimate(sequence, theta0=theta0, options=options, uncertainty=False,
                                  progress=progress)
        initial, status = first.thetas, first.status
    elif initial is None:
        chain = chain_estimate(sequence, theta0=theta0, threshold_px=options.threshold_px,
                               progress=progress)
        initial, status = chain.thetas, chain.status
    else:
        initial = np.asarray(initial, dtype=float)
        status = np.full((sequence.n_frames, n_seg), "initial", dtype="<U24")
    # Rounds: short baselines first (gated at the chain's estimate), then every gap, re-gated
    # at the previous round's solution; long baselines only enter once the estimate is good
    # enough to tell their inliers from outliers.
    short = tuple(g for g in options.gaps if g <= 2) or options.gaps[:1]
    thetas = initial
    graph = build_graph(sequence, thetas, theta0, replace(options, gaps=short))
    thetas = _optimise(graph, thetas, max_iterations)
    for _ in range(max_rounds):
        graph = build_graph(sequence, thetas, theta0, options)
        previous, thetas = thetas, _optimise(graph, thetas, max_iterations)
        if np.max(np.abs(thetas - previous)) < round_tolerance:
            break
    result = _values(thetas)
    sigmas = np.full_like(thetas, np.nan)
    if marginals:
        sigmas = _marginal_sigmas(graph, result, thetas.shape)
    status = np.where(np.char.startswith(status, "initial"), "initial", "ok").astype("<U24")
    return Estimate(method="batch", robot=sequence.robot, timestamps=sequence.timestamps.copy(),
                    thetas=thetas, sigmas=sigmas, status=status,
                    inliers=np.zeros((sequence.n_frames, n_seg), dtype=np.int64),
                    world_T_base=sequence.world_T_base)
