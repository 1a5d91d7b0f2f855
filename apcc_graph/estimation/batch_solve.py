"""The projection batch's solver: one factor graph over a whole sequence, Levenberg-Marquardt
(gtsam) with graduated non-convexity of the outlier decisions, and the marginals.

:func:`projection_solve` starts from given angles;
:func:`apcc_graph.estimation.batch.batch_estimate` finds them (the chain or the smoother) and
calls it, and so does the smoother when it re-acquires the angles after a blackout
(:mod:`apcc_graph.estimation.blackout`). See :mod:`apcc_graph.estimation.batch` for the method.
"""

from __future__ import annotations

import math
from collections.abc import Sequence as SequenceOf
from dataclasses import dataclass

import gtsam
import numpy as np
import scipy.linalg
from numpy.typing import NDArray
from tqdm import tqdm

from apcc_graph.estimation.graph import (
    CameraTerms,
    calibration_factors,
    camera_chain,
    camera_observations,
    frame_key,
    prior_factors,
    thetas_from,
    values_from,
)
from apcc_graph.estimation.options import GraphOptions
from apcc_graph.estimation.robust import gnc_start
from apcc_graph.factors.projection import calibrated, calibration_key
from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.robot import Robot
from apcc_graph.model.segment import Segment
from apcc_graph.model.sequence import Sequence


@dataclass(frozen=True)
class BatchReport:
    """What the batch did: stages, Levenberg-Marquardt iterations, outliers found."""

    stages: int
    iterations: int
    outliers: int
    observations: int


def build_terms(sequence: Sequence, options: GraphOptions,
                calibrate: bool = False, spatial: bool = False) -> list[CameraTerms]:
    """The projection terms of every camera of the sequence that has tracks (with
    ``spatial``, over the frames' bending vectors)."""
    terms = []
    dim = (2 if spatial else 1) * sequence.n_segments
    for cam in sequence.robot.camera_segments:
        obs = camera_observations(sequence, cam, options.threshold_px, options.min_track_rows,
                                  max_track_frames=options.max_track_frames)
        if obs is None:
            continue
        # A planar robot bends in the plane psi = 0; the sequence's psis are ground truth,
        # which no estimator reads.
        chain = camera_chain(sequence.robot, cam, sequence.world_T_base, None, spatial)
        terms.append(CameraTerms(obs, chain, dim, options.frames_per_chunk, calibrate))
    return terms


def _values_and_ordering(thetas: FloatArray, frames: SequenceOf[int],
                         calibration: FloatArray | None
                         ) -> tuple[gtsam.Values, gtsam.Ordering]:
    """Values of the angles (and calibration); frames in time order (the graph is banded),
    then the calibration variables, which every camera's factors share."""
    values = values_from(thetas, frames)
    ordering = gtsam.Ordering()
    for f in frames:
        ordering.push_back(frame_key(f))
    if calibration is not None:
        for j, kd in enumerate(calibration):
            values.insert(calibration_key(j), np.asarray(kd, dtype=float))
            ordering.push_back(calibration_key(j))
    return values, ordering


def optimise(graph: gtsam.NonlinearFactorGraph, thetas: FloatArray, frames: SequenceOf[int],
             max_iterations: int, relative_tolerance: float = 1e-6,
             calibration: FloatArray | None = None
             ) -> tuple[FloatArray, int, FloatArray | None]:
    """Levenberg-Marquardt from ``thetas`` (and ``calibration``, ``(S, 2)`` k and delta_max,
    when self-calibrating); the optimised angles, iterations and calibration."""
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(max_iterations)
    params.setRelativeErrorTol(relative_tolerance)
    params.setAbsoluteErrorTol(1e-9)
    values, ordering = _values_and_ordering(thetas, frames, calibration)
    params.setOrdering(ordering)
    optimizer = gtsam.LevenbergMarquardtOptimizer(graph, values, params)
    result = optimizer.optimize()
    cal = (None if calibration is None else
           np.array([result.atVector(calibration_key(j)) for j in range(len(calibration))]))
    return thetas_from(result, frames), int(optimizer.iterations()), cal


def marginal_sigmas(graph: gtsam.NonlinearFactorGraph, thetas: FloatArray,
                    frames: SequenceOf[int], dense_limit: int = 6000,
                    calibration: FloatArray | None = None) -> FloatArray:
    """``(F, S)`` marginal standard deviations of the angles at ``thetas`` (NaN where
    undetermined); see :func:`marginal_deviations`."""
    return marginal_deviations(graph, thetas, frames, dense_limit, calibration)[0]


def marginal_deviations(graph: gtsam.NonlinearFactorGraph, thetas: FloatArray,
                        frames: SequenceOf[int], dense_limit: int = 6000,
                        calibration: FloatArray | None = None
                        ) -> tuple[FloatArray, FloatArray | None]:
    """Marginal standard deviations at the solution: ``(F, S)`` angles and, when
    self-calibrating, ``(S, 2)`` of each segment's k and delta_max (NaN where undetermined).

    Up to ``dense_limit`` angles, the information matrix of the graph linearised at
    ``thetas`` is inverted densely (far faster than gtsam's per-variable
    ``marginalCovariance`` on this banded graph); beyond, ``gtsam.Marginals``.
    """
    values, ordering = _values_and_ordering(thetas, frames, calibration)
    n_cal = 0 if calibration is None else calibration.size
    nan = (np.full(thetas.shape, np.nan),
           None if calibration is None else np.full(calibration.shape, np.nan))
    if thetas.size <= dense_limit:
        info, _ = graph.linearize(values).hessian(ordering)
        try:
            L = np.linalg.cholesky(info)
        except np.linalg.LinAlgError:
            return nan
        L_inv = scipy.linalg.solve_triangular(L, np.eye(len(info)), lower=True,
                                              check_finite=False)
        sig = np.sqrt(np.einsum("ij,ij->j", L_inv, L_inv))
        cal = None if calibration is None else sig[thetas.size:].reshape(calibration.shape)
        return sig[:thetas.size].reshape(thetas.shape), cal
    try:
        found = gtsam.Marginals(graph, values)
    except RuntimeError:
        return nan

    def sigma(key: int) -> FloatArray:
        return np.sqrt(np.maximum(np.diag(found.marginalCovariance(key)), 0.0))

    cal = (None if n_cal == 0 else
           np.array([sigma(calibration_key(j)) for j in range(len(calibration))]))
    return np.array([sigma(frame_key(f)) for f in frames]), cal


def marginal_blocks(graph: gtsam.NonlinearFactorGraph, x: FloatArray, frames: SequenceOf[int],
                    block: int, dense_limit: int = 6000) -> FloatArray:
    """``(F, P / block, block, block)`` marginal covariances of consecutive ``block``-sized
    groups of each frame's ``P`` components at ``x`` ``(F, P)`` (a spatial robot's bending
    vectors with ``block = 2``); NaN where the system is undetermined. Dense inversion up to
    ``dense_limit`` unknowns, ``gtsam.Marginals`` beyond, as :func:`marginal_deviations`."""
    n_frames, P = x.shape
    shape = (n_frames, P // block, block, block)
    values, ordering = _values_and_ordering(x, frames, None)
    if x.size <= dense_limit:
        info, _ = graph.linearize(values).hessian(ordering)
        try:
            L = np.linalg.cholesky(info)
        except np.linalg.LinAlgError:
            return np.full(shape, np.nan)
        L_inv = scipy.linalg.solve_triangular(L, np.eye(len(info)), lower=True,
                                              check_finite=False).reshape(len(info), *shape[:3])
        return np.einsum("nfsi,nfsj->fsij", L_inv, L_inv)
    try:
        found = gtsam.Marginals(graph, values)
    except RuntimeError:
        return np.full(shape, np.nan)
    out = np.empty(shape)
    for i, f in enumerate(frames):
        cov = found.marginalCovariance(frame_key(f))
        for s in range(shape[1]):
            out[i, s] = cov[block * s:block * (s + 1), block * s:block * (s + 1)]
    return out


@dataclass(frozen=True)
class ProjectionSolution:
    """What :func:`projection_solve` found.

    Attributes:
        thetas, sigmas: ``(F, S)`` angles and marginal standard deviations (radians).
        inliers: ``(F, S)`` observations judged inliers per frame and camera.
        report: what the solver did.
        segments: the self-calibrated segment models, or ``None``.
        calibration_sigmas: ``(S, 2)`` marginal standard deviations of k and delta_max
            (radians), or ``None``.
        covariances: spatial only, ``(F, S, 2, 2)`` the marginal covariance of each bending
            vector (radians squared; NaN where undetermined), or ``None``.

    With ``spatial``, ``thetas`` and ``sigmas`` are ``(F, 2 S)``: bending vectors and the
    standard deviations of their components.
    """

    thetas: FloatArray
    sigmas: FloatArray
    inliers: NDArray[np.int64]
    report: BatchReport
    segments: tuple[Segment, ...] | None = None
    calibration_sigmas: FloatArray | None = None
    covariances: FloatArray | None = None


def projection_solve(sequence: Sequence, initial: FloatArray, theta0: FloatArray,
                     options: GraphOptions, schedule: SequenceOf[float] | None = None,
                     max_iterations: int = 30, max_final_rounds: int = 4,
                     marginals: bool = True, progress: bool = False,
                     calibrate: bool = False,
                     calibration_sigmas: tuple[float, float] = (0.05, math.radians(5.0)),
                     spatial: bool = False) -> ProjectionSolution:
    """Angles, sigmas and inliers per frame of the projection batch, started at ``initial``.

    Args:
        sequence: the sequence.
        initial: ``(F, S)`` initial angles (radians); ``(F, 2 S)`` bending vectors with
            ``spatial``.
        theta0: ``(S,)`` start prior's mean (``(2 S,)`` with ``spatial``), or ``None``.
        options: graph options.
        schedule: the GNC continuation (values of ``mu`` ending with ``inf``); default
            :func:`~apcc_graph.estimation.robust.gnc_start`, fitted to the residuals at
            ``initial``.
        max_iterations: Levenberg-Marquardt iterations per stage.
        max_final_rounds: most repetitions of the last stage while decisions change.
        marginals: compute marginal sigmas (otherwise NaN).
        progress: show a progress bar over the stages.
        calibrate: estimate each segment's k and delta_max too, with priors of
            ``calibration_sigmas`` (k, radians) around the robot's values.
        spatial: the robot bends in 3-D: every frame's variable is its bending vectors
            (:mod:`apcc_graph.model.bending`); not with ``calibrate``.
    """
    if spatial and calibrate:
        raise ValueError("calibrate=True: self-calibration of a spatial robot is not supported")
    if schedule is not None:
        schedule = list(schedule)
        if not schedule or not math.isinf(schedule[-1]):
            raise ValueError(f"schedule = {schedule!r}: expected values ending with inf")
    robot = sequence.robot
    frames = range(sequence.n_frames)
    terms = build_terms(sequence, options, calibrate, spatial)
    graph = _graph(sequence, terms, theta0, options,
                   calibration_sigmas if calibrate else None, spatial)
    thetas = np.array(initial, dtype=float)
    cal = (np.array([[s.k, s.delta_max] for s in robot.segments]) if calibrate else None)
    # One bar over every long stage: triangulation, the outlier rounds, the marginals.
    bar = tqdm(total=max_final_rounds + 2, desc="batch", disable=not progress, leave=False)
    bar.set_postfix_str("triangulating the tracks")
    for t in terms:
        t.measure(thetas, robust=True)
    if schedule is None:
        schedule = gnc_start(np.concatenate([n for t in terms for n in t.norms] or [[]]),
                             options.inlier_sigmas)
    stages = schedule + [math.inf] * (max_final_rounds - 1)
    bar.total = len(stages) + 2
    bar.update()
    iterations = 0
    for stage, mu in enumerate(stages):
        bar.set_postfix_str(f"outlier round {stage + 1} of at most {len(stages)}")
        if stage > 0:
            segments = None if cal is None else _segments(robot, cal)
            for t in terms:
                t.measure(thetas, segments=segments)
        changed = sum(t.set_weights(options.inlier_sigmas, mu) for t in terms)
        if stage >= len(schedule) and changed == 0:
            break
        # Intermediate stages only lead the weights; the truncated quadratic is solved tightly.
        tolerance = 1e-6 if math.isinf(mu) else 1e-3
        thetas, its, cal = optimise(graph, thetas, frames, max_iterations, tolerance, cal)
        iterations += its
        bar.update()
    bar.n = len(stages) + 1
    bar.set_postfix_str("marginal sigmas")
    sigmas, cal_sigmas, covariances = _uncertainty(graph, thetas, frames, cal, marginals,
                                                   spatial)
    bar.update()
    bar.close()
    inliers = np.zeros((sequence.n_frames, sequence.n_segments), dtype=np.int64)
    for t in terms:
        inliers[:, t.camera] = t.inliers_per_frame(sequence.n_frames)
    report = BatchReport(stage + 1, iterations, sum(t.outlier_rows() for t in terms),
                         sum(len(c.obs) for t in terms for c in t.chunks))
    segments = None if cal is None else _segments(robot, cal)
    return ProjectionSolution(thetas, sigmas, inliers, report, segments, cal_sigmas,
                              covariances)


def _uncertainty(graph: gtsam.NonlinearFactorGraph, x: FloatArray, frames: SequenceOf[int],
                 cal: FloatArray | None, marginals: bool, spatial: bool
                 ) -> tuple[FloatArray, FloatArray | None, FloatArray | None]:
    """Marginal sigmas of ``x``, of the calibration and, for a spatial robot, the ``2 x 2``
    covariances of the bending vectors; NaN without ``marginals``."""
    if marginals and spatial:
        covariances = marginal_blocks(graph, x, frames, 2)
        return np.sqrt(np.diagonal(covariances, axis1=-2, axis2=-1)).reshape(x.shape), None, \
            covariances
    if marginals:
        sigmas, cal_sigmas = marginal_deviations(graph, x, frames, calibration=cal)
        return sigmas, cal_sigmas, None
    return (np.full(x.shape, np.nan), None if cal is None else np.full(cal.shape, np.nan),
            None)


def _graph(sequence: Sequence, terms: list[CameraTerms], theta0: FloatArray,
           options: GraphOptions, calibration_sigmas: tuple[float, float] | None,
           spatial: bool = False) -> gtsam.NonlinearFactorGraph:
    """The projection batch's graph: priors, calibration priors (when ``calibration_sigmas``
    are given), then every camera's projection factors."""
    graph = gtsam.NonlinearFactorGraph()
    frames = range(sequence.n_frames)
    for factor in prior_factors(frames, sequence.timestamps, theta0, sequence.robot, options,
                                spatial=spatial):
        graph.add(factor)
    if calibration_sigmas is not None:
        for factor in calibration_factors(sequence.robot, calibration_sigmas):
            graph.add(factor)
    for t in terms:
        for factor in t.factors():
            graph.add(factor)
    return graph


def _segments(robot: Robot, cal: FloatArray) -> tuple[Segment, ...]:
    return tuple(calibrated(s, k, d) for s, (k, d) in zip(robot.segments, cal, strict=True))
