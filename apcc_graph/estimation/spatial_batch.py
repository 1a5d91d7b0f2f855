"""Batch estimation of a spatial robot: every frame's bending vectors in one factor graph.

The projection batch (:mod:`apcc_graph.estimation.batch`) with one ``Vector(2 S)`` per frame,
the bending vectors ``(u_0, v_0, u_1, v_1, ...)`` (:mod:`apcc_graph.estimation.spatial_bends`),
smooth through straight: the start prior and the random-walk motion prior act on them, the soft
joint limits on their lengths, and every camera's projection factors on its segments' bending
vectors (:class:`apcc_graph.factors.camera_chain.CameraChain` with ``spatial=True``). Outliers by
graduated non-convexity as in the planar batch; marginal ``2 x 2`` covariances of every bending
vector at the solution give ``sigma_theta`` and ``sigma_psi``. The starting values are the chained
2-point estimate (:mod:`apcc_graph.estimation.spatial_chain`).
"""

from __future__ import annotations

from collections.abc import Sequence as SequenceOf

import numpy as np
from numpy.typing import ArrayLike

from apcc_graph.estimation.batch_solve import projection_solve
from apcc_graph.estimation.options import GraphOptions
from apcc_graph.estimation.result import Estimate
from apcc_graph.estimation.spatial_bends import polar_from, polar_sigmas, start_bends
from apcc_graph.estimation.spatial_chain import spatial_chain_bends
from apcc_graph.model.sequence import Sequence


def spatial_batch_estimate(
    sequence: Sequence,
    theta0: ArrayLike | None = None,
    psi0: ArrayLike | None = None,
    initial: ArrayLike | None = None,
    options: GraphOptions | None = None,
    max_iterations: int = 30,
    marginals: bool = True,
    progress: bool = False,
    schedule: SequenceOf[float] | None = None,
) -> Estimate:
    """Optimise the bends ``(theta, psi)`` of every frame and segment of a spatial robot jointly.

    Args:
        sequence: the sequence (ground truth, if any, is never read).
        theta0, psi0: ``(S,)`` the bends at frame 0 (radians; default straight), held by an
            isotropic prior of ``options.theta0_sigma`` on each bending vector's components.
        initial: ``(F, 2 S)`` initial bending vectors; default the chained 2-point estimate.
        options: how the graph is built (:class:`GraphOptions`; projection model only).
        max_iterations: Levenberg-Marquardt iterations per stage.
        marginals: compute marginal standard deviations (otherwise NaN).
        progress: show progress bars.
        schedule: the GNC continuation of the outlier decisions.

    Returns:
        The estimate, ``method = "batch"``, with ``psis`` and ``psi_sigmas``; ``thetas`` are the
        bends' magnitudes ``>= 0``.

    Raises:
        ValueError: a bad ``theta0``, ``psi0`` or ``initial``.
    """
    options = GraphOptions() if options is None else options
    robot = sequence.robot
    bend0 = start_bends(robot, theta0, psi0)
    shape = (sequence.n_frames, 2 * robot.n_segments)
    if initial is None:
        bends, status, _ = spatial_chain_bends(sequence, bend0, options.threshold_px,
                                               progress=progress)
    else:
        bends = np.asarray(initial, dtype=float)
        if bends.shape != shape:
            raise ValueError(f"initial has shape {bends.shape}: expected {shape}, the bending "
                             "vectors (u_1, v_1, u_2, ...) of every frame in radians")
        status = np.full((sequence.n_frames, robot.n_segments), "initial", dtype="<U24")
    found = projection_solve(sequence, bends, bend0, options, schedule, max_iterations,
                             marginals=marginals, progress=progress, spatial=True)
    thetas, psis = polar_from(found.thetas)
    if found.covariances is None:
        sigmas = psi_sigmas = np.full(thetas.shape, np.nan)
    else:
        sigmas, psi_sigmas = polar_sigmas(found.thetas, found.covariances)
    status = np.where(np.char.startswith(status, "initial"), "initial", "ok").astype("<U24")
    return Estimate(method="batch", robot=robot, timestamps=sequence.timestamps.copy(),
                    thetas=thetas, sigmas=sigmas, status=status, inliers=found.inliers,
                    world_T_base=sequence.world_T_base, psis=psis, psi_sigmas=psi_sigmas)
