"""Batch estimation of a whole sequence: one factor graph, Levenberg-Marquardt (gtsam).

The graph (:mod:`apcc_graph.estimation.graph`): one vector per frame in the robot's
parameterisation (:mod:`apcc_graph.estimation.bends`: the angles of a planar robot, the bending
vectors of one that bends in 3-D), the start prior, a weak motion prior, soft joint limits, and
the measurement model's terms (:mod:`apcc_graph.estimation.terms`; ``docs/estimation.md``): by
default the exact model, every observation once, each track's 3-D point triangulated and
eliminated; with ``GraphOptions.model_sigma``, model error as noise.

Outliers are decided per observation against its own track's point, by graduated
non-convexity of a truncated quadratic (:mod:`apcc_graph.estimation.robust`): the first
decisions come from a robust triangulation of every track at the initial angles (with model
noise, from the images alone); then, for each ``mu`` of the continuation, Levenberg-Marquardt
solves the weighted problem and the weights are recomputed from the residuals at the new
solution. The last stage (the truncated quadratic itself) repeats until no observation changes
side. The solver is :mod:`apcc_graph.estimation.batch_solve`; this module finds its start.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from apcc_graph.estimation.batch_solve import BatchReport, ProjectionSolution, projection_solve
from apcc_graph.estimation.bends import bending_estimate, parameterisation, start_vector
from apcc_graph.estimation.chain import chain_vectors
from apcc_graph.estimation.model_calibration import MOUNT_SIGMAS
from apcc_graph.estimation.model_noise import approximate, segment_sigmas
from apcc_graph.estimation.options import INITS, GraphOptions, Robustness
from apcc_graph.estimation.result import Estimate
from apcc_graph.estimation.rotation_start import rotation_start
from apcc_graph.estimation.smoother_options import SmootherOptions, WindowOptions
from apcc_graph.estimation.smoother_runs import smoother_estimate
from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.parameterisation import Bending
from apcc_graph.model.sequence import Sequence


def _initial_vectors(sequence: Sequence, bending: Bending, x0: FloatArray,
                     start: tuple[ArrayLike | None, ArrayLike | None],
                     initial: ArrayLike | None, init: str, options: GraphOptions,
                     robustness: Robustness | None, progress: bool
                     ) -> tuple[FloatArray, NDArray[np.str_]]:
    """``(F, dim)`` initial frame vectors and the status of each (``initial`` given, or from
    ``init``: the chain or the fixed-lag smoother, started at ``start = (theta0, psi0)``)."""
    shape = (sequence.n_frames, bending.dim)
    if initial is None and init == "smoother":
        # The exact smoother: a quick, good start for either measurement model.
        first = smoother_estimate(sequence, theta0=start[0], psi0=start[1],
                                  options=replace(options, model_sigma=None),
                                  settings=SmootherOptions(window=WindowOptions(uncertainty=False)),
                                  robustness=robustness, progress=progress,
                                  spatial=bending.is_free)
        return bending.vector(first.thetas, first.psis), first.status
    if initial is None and init == "auto" and approximate(segment_sigmas(options.model_sigma,
                                                                        sequence.robot)):
        init = "rotations"  # the model is materially off
    if initial is None and init == "rotations":
        x = rotation_start(sequence, x0, bending, options)
        return x, np.full((sequence.n_frames, sequence.n_segments), "rotations", dtype="<U24")
    if initial is None:
        x, status, _ = chain_vectors(sequence, bending, x0, options.threshold_px,
                                     progress=progress)
        return x, status
    x = np.asarray(initial, dtype=float)
    if x.shape != shape:
        raise ValueError(f"initial has shape {x.shape}: expected {shape}, every frame's "
                         + ("bending vectors (u_1, v_1, u_2, ...)" if bending.is_free
                            else "angles") + " in radians")
    return x, np.full((sequence.n_frames, sequence.n_segments), "initial", dtype="<U24")


def batch_estimate(
    sequence: Sequence,
    theta0: ArrayLike | None = None,
    initial: ArrayLike | None = None,
    options: GraphOptions | None = None,
    max_iterations: int = 30,
    marginals: bool = True,
    progress: bool = False,
    init: str = "auto",
    robustness: Robustness | None = None,
    calibrate: bool = False,
    calibration_sigmas: tuple[float, float] | None = (0.05, math.radians(5.0)),
    psi0: ArrayLike | None = None,
    mount_sigmas: tuple[float, float] | None = MOUNT_SIGMAS,
    spatial: bool = False,
) -> Estimate:
    """Optimise all frames and segments jointly.

    Args:
        sequence: the sequence (ground truth, if any, is never read).
        theta0: ``(S,)`` starting configuration (radians; default straight), held by a prior
            of ``options.theta0_sigma`` (on each component of the start's frame vector).
        initial: ``(F, dim)`` initial frame vectors (angles, or bending vectors with
            ``spatial``); default from ``init``.
        options: how the graph is built (:class:`GraphOptions`); with its ``model_sigma`` the
            model's error is noise: tip poses are variables tied to the kinematics
            (:mod:`~apcc_graph.estimation.terms.noisy`).
        max_iterations: Levenberg-Marquardt iterations per stage.
        marginals: compute marginal standard deviations (otherwise NaN).
        progress: show progress bars.
        init: where the initial values come from when ``initial`` is not given:
            ``"auto"`` (default: ``"rotations"`` with a model noise of at least 0.25 mm or
            0.15 deg on some segment, else ``"chain"``), ``"chain"`` (the paper's chained
            estimate, fast; it drifts, and the graduated non-convexity of the outlier
            decisions brings the batch back from there), ``"smoother"`` (the fixed-lag
            smoother: closer, slower) or ``"rotations"``
            (:mod:`~apcc_graph.estimation.rotation_start`: the vectors whose tip rotations fit
            the cameras' own, chained without the model).
        robustness: how outliers are decided (:class:`Robustness`: the inlier threshold and
            the GNC continuation).
        calibrate: self-calibration: estimate each segment's k and
            delta_max jointly with the bends, with priors of ``calibration_sigmas``
            (k, delta_max in radians) around the robot's values (``None`` holds them). The
            estimate's ``robot`` then holds the calibrated segments and
            ``calibration_sigmas`` their marginal standard deviations. With ``mount_sigmas``
            (radians, metres) each observed camera's mounting ``tip_T_cam`` is estimated
            too, with a prior of those standard deviations on each axis around the robot's
            (``None`` holds the mounts); the estimate's ``robot`` holds them and
            ``mount_sigmas`` their standard deviations.
        psi0: ``(S,)`` the bending planes at frame 0 (radians; default 0); ``spatial`` only.
        spatial: the robot bends in 3-D: every frame's unknowns are its bending vectors,
            smooth through straight, and the estimate has ``psis`` and ``psi_sigmas``
            (``thetas`` are then the bends' magnitudes ``>= 0``).

    Returns:
        The estimate, ``method = "batch"``.

    Raises:
        ValueError: a bad ``init``, ``theta0``, ``psi0`` or ``initial``; ``calibrate`` with a
            ``model_sigma``, or with neither ``calibration_sigmas`` nor ``mount_sigmas``.
    """
    options = GraphOptions() if options is None else options
    if init not in INITS:
        raise ValueError(f"init = {init!r}: expected one of {INITS}")
    if calibrate and calibration_sigmas is None and mount_sigmas is None:
        raise ValueError("self-calibration (calibrate) with calibration_sigmas = None and "
                         "mount_sigmas = None calibrates nothing: give either")
    robot = sequence.robot
    bending = parameterisation(robot, spatial)
    x0 = start_vector(robot, bending, theta0, psi0)
    initial, status = _initial_vectors(sequence, bending, x0, (theta0, psi0), initial, init,
                                       options, robustness, progress)
    found = projection_solve(sequence, initial, x0, options, robustness, max_iterations,
                             marginals=marginals, progress=progress,
                             calibration_sigmas=calibration_sigmas if calibrate else None,
                             bending=bending, mount_sigmas=mount_sigmas if calibrate else None)
    cal, std = found.calibration, found.calibration_std
    status = np.where(np.char.startswith(status, "initial"), "initial", "ok").astype("<U24")
    return bending_estimate(
        "batch", sequence, bending, found.x, found.blocks, status, found.inliers,
        robot=robot if cal is None else cal.robot(robot),
        calibration_sigmas=None if std is None else std.segments,
        mount_sigmas=None if std is None else std.mount_table(robot.n_segments))


__all__ = ["BatchReport", "GraphOptions", "ProjectionSolution", "Robustness", "batch_estimate",
           "projection_solve"]
