"""The batch's solver: one factor graph over a whole sequence, Levenberg-Marquardt (gtsam) in
stages of outlier decisions, and the marginals, over either measurement model
(:mod:`apcc_graph.estimation.terms`); :mod:`apcc_graph.estimation.batch` finds its start, and
the smoother calls it to re-acquire the angles after a blackout.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import gtsam
import numpy as np
import scipy.linalg
from numpy.typing import NDArray

from apcc_graph.estimation.graph import prior_factors, thetas_from
from apcc_graph.estimation.model_calibration import ModelCalibration
from apcc_graph.estimation.noise_information import marginal_columns
from apcc_graph.estimation.options import GraphOptions, Robustness
from apcc_graph.estimation.terms import measurement_model
from apcc_graph.estimation.terms.exact import build_terms as build_terms  # the start search's
from apcc_graph.factors.keys import frame_key
from apcc_graph.io.console import progress_bar
from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.parameterisation import Bending
from apcc_graph.model.sequence import Sequence

MAX_FINAL_ROUNDS = 4
"""Most rounds of the truncated quadratic decided by the residuals at the last solution."""


@dataclass(frozen=True)
class BatchReport:
    """What the batch did: stages, Levenberg-Marquardt iterations, outliers found."""

    stages: int
    iterations: int
    outliers: int
    observations: int


def optimise(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, max_iterations: int,
             relative_tolerance: float = 1e-6, ordering: gtsam.Ordering | None = None,
             diagonal_damping: bool = False) -> tuple[gtsam.Values, int]:
    """Levenberg-Marquardt from ``values`` (``ordering``, else gtsam's; ``diagonal_damping``:
    damping scaled by the information's diagonal); solution, iterations."""
    params = gtsam.LevenbergMarquardtParams()
    params.setDiagonalDamping(diagonal_damping)
    params.setMaxIterations(max_iterations)
    params.setRelativeErrorTol(relative_tolerance)
    params.setAbsoluteErrorTol(1e-9)
    if ordering is not None:
        params.setOrdering(ordering)
    optimizer = gtsam.LevenbergMarquardtOptimizer(graph, values, params)
    return optimizer.optimize(), int(optimizer.iterations())


def marginal_blocks(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, n_frames: int,
                    width: int, ordering: gtsam.Ordering | None = None,
                    calibration: ModelCalibration | None = None, dense_limit: int = 6000,
                    wanted: bool = True) -> tuple[FloatArray, ModelCalibration | None]:
    """Marginal covariances at the solution ``values``: ``(F, S, w, w)`` of each segment's
    ``w = width`` frame-vector components and the ``calibration`` parameters' standard
    deviations; NaN where undetermined, or everywhere unless ``wanted``. Given an ``ordering``
    of every variable (frame vectors first) and up to ``dense_limit`` frame-vector components,
    the information matrix is inverted densely (far faster than gtsam's per-variable
    ``marginalCovariance`` on a banded graph); otherwise ``gtsam.Marginals``."""
    x = thetas_from(values, range(n_frames))
    shape = (n_frames, x.shape[1] // width, width, width)
    nan = (np.full(shape, np.nan), None if calibration is None
           else calibration.sigmas_from(np.full(calibration.size, np.nan)))
    if not wanted:
        return nan
    found = _gtsam_blocks(graph, values, x, shape, ordering, calibration, dense_limit, nan)
    if calibration is None and not np.any(np.isfinite(found[0])):
        return _eliminated_blocks(graph, values, shape), None
    return found


def _eliminated_blocks(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values,
                       shape: tuple[int, int, int, int]) -> FloatArray:
    """``shape`` frame-vector covariance blocks with each point's block eliminated first
    (:func:`~apcc_graph.estimation.noise_information.marginal_columns`): the model-noise
    graph of a robot at rest, whose points are seen from nearly one place, is refused as
    indeterminate by gtsam's marginals and by a dense Cholesky (on the real robot's replayed
    resting stretch, every sigma came back NaN). NaN where still singular."""
    n_frames, n_segments, width = shape[0], shape[1], shape[2]
    dim = n_segments * width
    found = marginal_columns(graph, values, [(frame_key(f), np.arange(dim))
                                             for f in range(n_frames)])
    out = np.full(shape, np.nan)
    for f, cov in enumerate(found or ()):
        for s in range(n_segments):
            out[f, s] = cov[width * s:width * (s + 1), width * s:width * (s + 1)]
    return out


def _gtsam_blocks(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, x: FloatArray,
                  shape: tuple[int, int, int, int], ordering: gtsam.Ordering | None,
                  calibration: ModelCalibration | None, dense_limit: int,
                  nan: tuple[FloatArray, ModelCalibration | None]
                  ) -> tuple[FloatArray, ModelCalibration | None]:
    """:func:`marginal_blocks` by a dense inverse or gtsam's marginals (``nan`` on failure)."""
    n_frames, width = shape[0], shape[2]
    if ordering is not None and x.size <= dense_limit:
        info, _ = graph.linearize(values).hessian(ordering)
        try:
            L = np.linalg.cholesky(info)
        except np.linalg.LinAlgError:
            return nan
        L_inv = scipy.linalg.solve_triangular(L, np.eye(len(info)), lower=True,
                                              check_finite=False)
        cal = None
        if calibration is not None:
            tail = L_inv[:, x.size:x.size + calibration.size]
            cal = calibration.sigmas_from(np.sqrt(np.einsum("ij,ij->j", tail, tail)))
        rows = L_inv[:, :x.size].reshape(len(info), *shape[:3])
        return np.einsum("nfsi,nfsj->fsij", rows, rows), cal
    try:
        found = gtsam.Marginals(graph, values)
    except RuntimeError:
        return nan
    out = np.empty(shape)
    for f in range(n_frames):
        cov = found.marginalCovariance(frame_key(f))
        for s in range(shape[1]):
            out[f, s] = cov[width * s:width * (s + 1), width * s:width * (s + 1)]
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
                     max_iterations: int = 30, marginals: bool = True, progress: bool = False,
                     calibration_sigmas: tuple[float, float] | None = None,
                     bending: Bending | None = None,
                     mount_sigmas: tuple[float, float] | None = None,
                     start_sigmas: FloatArray | None = None) -> ProjectionSolution:
    """Frame vectors, covariances and inliers of the batch, started at ``initial``, over the
    measurement model ``options`` choose (:func:`~.terms.measurement_model`).

    Each stage sets the outlier decisions and solves the priors on the frame vectors and the
    model's terms by Levenberg-Marquardt: the model's leading stages first (the exact model's
    graduated non-convexity, the noisy model's decisions from the images alone), then rounds
    of the truncated quadratic decided by the residuals at the last solution, until a round
    after a truncated stage changes no decision.

    Args:
        sequence: the sequence.
        initial: ``(F, dim)`` initial frame vectors of ``bending`` (radians).
        theta0: ``(dim,)`` start prior's mean, or ``None``.
        options: the measurement model (exact, or with ``model_sigma`` model error as noise).
        robustness: the outlier threshold and the exact model's GNC schedule (default
            :class:`~apcc_graph.estimation.options.Robustness`: fitted to the residuals at
            ``initial`` by :func:`~apcc_graph.estimation.robust.gnc_start`).
        max_iterations: Levenberg-Marquardt iterations per stage (the model's
            ``stage_iterations`` where fewer).
        marginals: compute marginal sigmas (otherwise NaN).
        progress: show a progress bar over the stages.
        calibration_sigmas, mount_sigmas: self-calibration (the exact model only): estimate
            each segment's k and delta_max, and each observed camera's mounting, with priors of
            these standard deviations (k, radians; radians, metres) around the robot's values;
            ``None`` holds them.
        bending: the parameterisation (default: the planar robot's fixed planes).
        start_sigmas: ``(dim,)`` the start prior's sigma per component (radians; default
            ``options.theta0_sigma`` on each).

    Raises:
        ValueError: self-calibration with ``options.model_sigma``.
    """
    robustness = Robustness() if robustness is None else robustness
    bending = Bending.fixed(sequence.robot.segments) if bending is None else bending
    model = measurement_model(sequence.robot, options, bending, calibration_sigmas, mount_sigmas)
    frames = range(sequence.n_frames)
    priors = prior_factors(frames, sequence.timestamps, theta0, bending, options,
                           start_sigmas=start_sigmas)
    # One bar over every long stage: triangulation, the outlier rounds, the marginals.
    bar = progress_bar(total=MAX_FINAL_ROUNDS + 2, desc="batch", progress=progress, leave=False)
    bar.set_postfix_str("triangulating the tracks")
    x = np.array(initial, dtype=float)
    stages = model.start(sequence, x, robustness) + [math.inf] * MAX_FINAL_ROUNDS
    bar.total = len(stages) + 2
    bar.update()
    iterations = 0
    cap = min(max_iterations, model.stage_iterations or max_iterations)
    for stage, mu in enumerate(stages):
        bar.set_postfix_str(f"outlier round {stage + 1} of at most {len(stages)}")
        if stage > 0:  # a truncated stage whose residuals change no decision ends it
            changed = model.set_weights(robustness.inlier_sigmas, mu)
            if changed == 0 and math.isinf(stages[stage - 1]):
                break
        graph = gtsam.NonlinearFactorGraph()
        for factor in priors + model.factors():
            graph.add(factor)
        # Intermediate stages only lead the weights; the truncated quadratic is solved tightly.
        values, ordering = model.values(x)
        values, its = optimise(graph, values, cap, 1e-6 if math.isinf(mu) else 1e-3,
                               ordering, model.diagonal_damping)
        x = thetas_from(values, frames)
        model.measure(values)
        iterations += its
        bar.update()
    bar.n = len(stages) + 1
    bar.set_postfix_str("marginal sigmas")
    cal = model.calibration
    blocks, cal_std = marginal_blocks(graph, values, len(x), bending.width, ordering, cal,
                                      wanted=marginals)
    bar.update()
    bar.close()
    inliers, outliers, observations = model.decisions()
    report = BatchReport(stage + 1, iterations, outliers, observations)
    return ProjectionSolution(x, blocks, inliers, report, cal, cal_std)
