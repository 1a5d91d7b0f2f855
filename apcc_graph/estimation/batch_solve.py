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

from apcc_graph.estimation.graph import (
    CameraTerms,
    calibration_factors,
    camera_chain,
    mount_factors,
    observed_cameras,
    prior_factors,
    thetas_from,
    values_from,
)
from apcc_graph.estimation.model_calibration import ModelCalibration
from apcc_graph.estimation.options import GraphOptions, Robustness
from apcc_graph.estimation.robust import gnc_start
from apcc_graph.factors.keys import frame_key
from apcc_graph.io.console import progress_bar
from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.parameterisation import Bending
from apcc_graph.model.sequence import Sequence


@dataclass(frozen=True)
class BatchReport:
    """What the batch did: stages, Levenberg-Marquardt iterations, outliers found."""

    stages: int
    iterations: int
    outliers: int
    observations: int


def build_terms(sequence: Sequence, options: GraphOptions, bending: Bending | None = None,
                calibrate: bool = False, mounts: bool = False) -> list[CameraTerms]:
    """The projection terms of every camera of the sequence that has tracks, over frame
    vectors of ``bending`` (default: the planar robot's fixed planes); with ``calibrate`` and
    ``mounts`` they also depend on the segment models and each camera's mounting. The
    sequence's ``psis`` are ground truth, which no estimator reads."""
    bending = Bending.fixed(sequence.robot.segments) if bending is None else bending
    return [CameraTerms(obs, camera_chain(sequence.robot, obs.camera, bending,
                                          sequence.world_T_base),
                        bending.dim, options.frames_per_chunk, calibrate, mounts)
            for obs in observed_cameras(sequence, options)]


def _values_and_ordering(thetas: FloatArray, frames: SequenceOf[int],
                         calibration: ModelCalibration | None
                         ) -> tuple[gtsam.Values, gtsam.Ordering]:
    """Values of the angles (and calibration); frames in time order (the graph is banded),
    then the calibration variables, which every camera's factors share."""
    values = values_from(thetas, frames)
    ordering = gtsam.Ordering()
    for f in frames:
        ordering.push_back(frame_key(f))
    if calibration is not None:
        calibration.insert(values)
        for key in calibration.keys():
            ordering.push_back(key)
    return values, ordering


def optimise(graph: gtsam.NonlinearFactorGraph, thetas: FloatArray, frames: SequenceOf[int],
             max_iterations: int, relative_tolerance: float = 1e-6,
             calibration: ModelCalibration | None = None
             ) -> tuple[FloatArray, int, ModelCalibration | None]:
    """Levenberg-Marquardt from ``thetas`` (and ``calibration``, when self-calibrating); the
    optimised angles, iterations and calibration."""
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(max_iterations)
    params.setRelativeErrorTol(relative_tolerance)
    params.setAbsoluteErrorTol(1e-9)
    values, ordering = _values_and_ordering(thetas, frames, calibration)
    params.setOrdering(ordering)
    optimizer = gtsam.LevenbergMarquardtOptimizer(graph, values, params)
    result = optimizer.optimize()
    cal = None if calibration is None else calibration.read(result)
    return thetas_from(result, frames), int(optimizer.iterations()), cal


def marginal_blocks(graph: gtsam.NonlinearFactorGraph, x: FloatArray,
                    frames: SequenceOf[int], width: int, dense_limit: int = 6000,
                    calibration: ModelCalibration | None = None
                    ) -> tuple[FloatArray, ModelCalibration | None]:
    """Marginal covariances at the solution: ``(F, S, w, w)`` of each segment's ``w =
    width`` components of the frame vectors ``x`` ``(F, w S)`` and, when self-calibrating,
    the standard deviations of the calibrated parameters (:class:`ModelCalibration`); NaN
    where the system is undetermined.

    Up to ``dense_limit`` unknowns, the information matrix of the graph linearised at ``x`` is
    inverted densely (far faster than gtsam's per-variable ``marginalCovariance`` on this
    banded graph); beyond, ``gtsam.Marginals``.
    """
    n_frames, P = x.shape
    shape = (n_frames, P // width, width, width)
    values, ordering = _values_and_ordering(x, frames, calibration)
    nan = (np.full(shape, np.nan), None if calibration is None
           else calibration.sigmas_from(np.full(calibration.size, np.nan)))
    if x.size <= dense_limit:
        info, _ = graph.linearize(values).hessian(ordering)
        try:
            L = np.linalg.cholesky(info)
        except np.linalg.LinAlgError:
            return nan
        L_inv = scipy.linalg.solve_triangular(L, np.eye(len(info)), lower=True,
                                              check_finite=False)
        cal = None
        if calibration is not None:
            tail = L_inv[:, x.size:]
            cal = calibration.sigmas_from(np.sqrt(np.einsum("ij,ij->j", tail, tail)))
        rows = L_inv[:, :x.size].reshape(len(info), *shape[:3])
        return np.einsum("nfsi,nfsj->fsij", rows, rows), cal
    try:
        found = gtsam.Marginals(graph, values)
    except RuntimeError:
        return nan
    out = np.empty(shape)
    for i, f in enumerate(frames):
        cov = found.marginalCovariance(frame_key(f))
        for s in range(shape[1]):
            out[i, s] = cov[width * s:width * (s + 1), width * s:width * (s + 1)]
    cal = (None if calibration is None else calibration.sigmas_from(np.concatenate([
        np.sqrt(np.maximum(np.diag(found.marginalCovariance(key)), 0.0))
        for key in calibration.keys()])))
    return out, cal


@dataclass(frozen=True)
class ProjectionSolution:
    """What :func:`projection_solve` found.

    Attributes:
        x: ``(F, dim)`` the frame vectors (radians).
        blocks: ``(F, S, w, w)`` the marginal covariance of each segment's ``w`` components
            (radians squared; NaN where undetermined or not asked for).
        inliers: ``(F, S)`` observations judged inliers per frame and camera.
        report: what the solver did.
        calibration: the self-calibrated model parameters, or ``None``.
        calibration_std: their marginal standard deviations, or ``None``.
    """

    x: FloatArray
    blocks: FloatArray
    inliers: NDArray[np.int64]
    report: BatchReport
    calibration: ModelCalibration | None = None
    calibration_std: ModelCalibration | None = None

    @property
    def sigmas(self) -> FloatArray:
        """``(F, dim)`` marginal standard deviations of the frame vectors' components."""
        diagonal = np.diagonal(self.blocks, axis1=-2, axis2=-1)
        return np.sqrt(np.maximum(diagonal, 0.0)).reshape(self.x.shape)


def projection_solve(sequence: Sequence, initial: FloatArray, theta0: FloatArray | None,
                     options: GraphOptions, robustness: Robustness | None = None,
                     max_iterations: int = 30, max_final_rounds: int = 4,
                     marginals: bool = True, progress: bool = False,
                     calibration_sigmas: tuple[float, float] | None = None,
                     bending: Bending | None = None,
                     mount_sigmas: tuple[float, float] | None = None,
                     start_sigmas: FloatArray | None = None) -> ProjectionSolution:
    """Frame vectors, covariances and inliers of the projection batch, started at
    ``initial``.

    Args:
        sequence: the sequence.
        initial: ``(F, dim)`` initial frame vectors of ``bending`` (radians).
        theta0: ``(dim,)`` start prior's mean, or ``None``.
        options: the measurement model.
        robustness: the outlier threshold and the GNC continuation (default
            :class:`~apcc_graph.estimation.options.Robustness`: the schedule
            :func:`~apcc_graph.estimation.robust.gnc_start` fits to the residuals at
            ``initial``).
        max_iterations: Levenberg-Marquardt iterations per stage.
        max_final_rounds: most repetitions of the last stage while decisions change.
        marginals: compute marginal sigmas (otherwise NaN).
        progress: show a progress bar over the stages.
        calibration_sigmas: estimate each segment's k and delta_max too, with priors of
            these standard deviations (k, radians) around the robot's values; ``None`` holds
            them.
        bending: the parameterisation (default: the planar robot's fixed planes).
        mount_sigmas: estimate each observed camera's mounting too, with priors of these
            standard deviations (radians, metres; :func:`mount_factors`) around the robot's;
            ``None`` holds the mounts.
        start_sigmas: ``(dim,)`` the start prior's sigma per component (radians; default
            ``options.theta0_sigma`` on each).
    """
    robustness = Robustness() if robustness is None else robustness
    inlier_sigmas = robustness.inlier_sigmas
    schedule = None if robustness.schedule is None else list(robustness.schedule)
    robot = sequence.robot
    bending = Bending.fixed(robot.segments) if bending is None else bending
    frames = range(sequence.n_frames)
    calibrate = calibration_sigmas is not None
    terms = build_terms(sequence, options, bending, calibrate, mount_sigmas is not None)
    cal: ModelCalibration | None = ModelCalibration.of(
        robot, calibrate, [t.camera for t in terms] if mount_sigmas is not None else [])
    cal = None if cal.empty else cal
    graph = _graph(sequence, terms, theta0, options, calibration_sigmas, bending,
                   mount_sigmas, start_sigmas)
    thetas = np.array(initial, dtype=float)
    # One bar over every long stage: triangulation, the outlier rounds, the marginals.
    bar = progress_bar(total=max_final_rounds + 2, desc="batch", progress=progress, leave=False)
    bar.set_postfix_str("triangulating the tracks")
    for t in terms:
        t.measure(thetas, robust=True)
    if schedule is None:
        schedule = gnc_start(np.concatenate([n for t in terms for n in t.norms] or [[]]),
                             inlier_sigmas)
    stages = schedule + [math.inf] * (max_final_rounds - 1)
    bar.total = len(stages) + 2
    bar.update()
    iterations = 0
    for stage, mu in enumerate(stages):
        bar.set_postfix_str(f"outlier round {stage + 1} of at most {len(stages)}")
        if stage > 0:
            segments = None if cal is None else cal.segment_models(robot)
            for t in terms:
                t.measure(thetas, segments=segments,
                          tip_T_cam=None if cal is None else cal.mount(t.camera))
        changed = sum(t.set_weights(inlier_sigmas, mu) for t in terms)
        if stage >= len(schedule) and changed == 0:
            break
        # Intermediate stages only lead the weights; the truncated quadratic is solved tightly.
        tolerance = 1e-6 if math.isinf(mu) else 1e-3
        thetas, its, cal = optimise(graph, thetas, frames, max_iterations, tolerance, cal)
        iterations += its
        bar.update()
    bar.n = len(stages) + 1
    bar.set_postfix_str("marginal sigmas")
    blocks, cal_std = _uncertainty(graph, thetas, frames, bending, cal, marginals)
    bar.update()
    bar.close()
    inliers = np.zeros((sequence.n_frames, sequence.n_segments), dtype=np.int64)
    for t in terms:
        inliers[:, t.camera] = t.inliers_per_frame(sequence.n_frames)
    report = BatchReport(stage + 1, iterations, sum(t.outlier_rows() for t in terms),
                         sum(len(c.obs) for t in terms for c in t.chunks))
    return ProjectionSolution(thetas, blocks, inliers, report, cal, cal_std)


def _uncertainty(graph: gtsam.NonlinearFactorGraph, x: FloatArray, frames: SequenceOf[int],
                 bending: Bending, cal: ModelCalibration | None, marginals: bool
                 ) -> tuple[FloatArray, ModelCalibration | None]:
    """:func:`marginal_blocks` at the solution, or NaN without ``marginals``."""
    if marginals:
        return marginal_blocks(graph, x, frames, bending.width, calibration=cal)
    w = bending.width
    return (np.full((len(x), bending.n_segments, w, w), np.nan),
            None if cal is None else cal.sigmas_from(np.full(cal.size, np.nan)))


def _graph(sequence: Sequence, terms: list[CameraTerms], theta0: FloatArray | None,
           options: GraphOptions, calibration_sigmas: tuple[float, float] | None,
           bending: Bending, mount_sigmas: tuple[float, float] | None = None,
           start_sigmas: FloatArray | None = None) -> gtsam.NonlinearFactorGraph:
    """The projection batch's graph: priors, calibration priors (when ``calibration_sigmas``
    are given), mount priors (when ``mount_sigmas`` are), then every camera's projection
    factors."""
    graph = gtsam.NonlinearFactorGraph()
    frames = range(sequence.n_frames)
    for factor in prior_factors(frames, sequence.timestamps, theta0, bending, options,
                                start_sigmas=start_sigmas):
        graph.add(factor)
    if calibration_sigmas is not None:
        for factor in calibration_factors(sequence.robot, calibration_sigmas):
            graph.add(factor)
    if mount_sigmas is not None:
        for factor in mount_factors(sequence.robot, [t.camera for t in terms], mount_sigmas):
            graph.add(factor)
    for t in terms:
        for factor in t.factors():
            graph.add(factor)
    return graph
