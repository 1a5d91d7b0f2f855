"""The paper's chained estimator: frame by frame, segments from the base outward.

For frame f and segment i, the motion of the segment's base between frames f-1 and f comes from
the robot base poses (if any) and the values of segments 0..i-1 already estimated for both
frames; segment i's value at frame f is then estimated from its value at f-1 by RANSAC on the
correspondences of camera i between the two frames: the paper's 1-point solver for a planar
robot (an angle in a fixed plane), the 2-point solver for a robot that bends in 3-D (a bending
vector); :mod:`apcc_graph.estimation.front_end` holds that loop. Errors pile up along the
sequence and outward along the robot (the paper says so; docs/estimation.md, "Two frames", says
why): this is the baseline the factor-graph back end must beat, and its initialiser.

A camera whose RANSAC keeps fewer than a handful of correspondences per frame pair is warned
about (``ObservationWarning``).

Outcomes per frame and segment (``Estimate.status``): ``"ok"``; ``"no-motion"`` (the camera saw
no parallax: the angle is carried over, which is what the data say); ``"no-consensus"`` or
``"too-few-correspondences"`` (RANSAC failed: the angle is carried over and flagged);
``"no-camera"`` (the segment has no camera: carried over).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from apcc_graph.estimation.bends import bending_estimate, parameterisation, start_vector
from apcc_graph.estimation.front_end import FramePairs, chained_guess
from apcc_graph.estimation.observation_checks import warn_few_inliers
from apcc_graph.estimation.result import Estimate
from apcc_graph.io.console import progress_bar
from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.parameterisation import Bending
from apcc_graph.model.sequence import Sequence


def chain_vectors(sequence: Sequence, bending: Bending, x0: FloatArray,
                  threshold_px: float = 1.0, confidence: float = 0.999, seed: int = 0,
                  progress: bool = False
                  ) -> tuple[FloatArray, NDArray[np.str_], NDArray[np.int64]]:
    """``(F, dim)`` frame vectors of ``bending`` chained from ``x0`` ``(dim,)``, with the
    ``(F, S)`` status and inlier counts (module docstring)."""
    robot = sequence.robot
    n_frames, n_seg = sequence.n_frames, robot.n_segments
    x = np.zeros((n_frames, bending.dim))
    x[0] = x0
    status = np.full((n_frames, n_seg), "initial", dtype="<U24")
    inliers = np.zeros((n_frames, n_seg), dtype=np.int64)
    rng = np.random.default_rng(seed)
    cameras = [i for i in range(n_seg) if robot.cameras[i] is not None]
    for f in progress_bar(range(1, n_frames), desc="chain", progress=progress):
        pairs = []
        for i in cameras:
            corr = sequence.correspondences(i, f - 1, f)
            pairs.append(FramePairs(i, corr.f_a, corr.f_b, np.arange(len(corr.f_a))))
        x[f], infos = chained_guess(x[f - 1], x[f - 1], robot, bending, _base(sequence, f - 1),
                                    _base(sequence, f), pairs, threshold_px, rng, confidence,
                                    min_pairs=0)
        status[f] = "no-camera"
        for i, info in infos.items():
            status[f, i] = info.status
            inliers[f, i] = info.n_inliers
    return x, status, inliers


def chain_estimate(
    sequence: Sequence,
    theta0: ArrayLike | None = None,
    threshold_px: float = 1.0,
    confidence: float = 0.999,
    seed: int = 0,
    progress: bool = False,
    psi0: ArrayLike | None = None,
    spatial: bool = False,
) -> Estimate:
    """Estimate every frame's bends by the paper's chained method.

    Args:
        sequence: the sequence (tracks per camera; base poses if the base moves; ground truth
            is never read).
        theta0: ``(S,)`` angles at frame 0 in radians (default straight, zeros).
        threshold_px: RANSAC inlier threshold in pixels (divided by each camera's focal length).
        confidence: RANSAC confidence.
        seed: random seed of the RANSAC sampling.
        progress: show a progress bar.
        psi0: ``(S,)`` bending planes at frame 0 (radians; default 0); ``spatial`` only.
        spatial: the robot bends in 3-D: every segment's bending plane is estimated too (the
            2-point solver), and the estimate has ``psis``.

    Returns:
        The estimate (``sigmas`` are NaN: the chain gives no uncertainty).
    """
    bending = parameterisation(sequence.robot, spatial)
    x0 = start_vector(sequence.robot, bending, theta0, psi0)
    x, status, inliers = chain_vectors(sequence, bending, x0, threshold_px, confidence, seed,
                                       progress)
    warn_few_inliers(sequence, inliers, status)
    return bending_estimate("chain", sequence, bending, x, None, status, inliers)


def _base(sequence: Sequence, frame: int) -> FloatArray | None:
    return None if sequence.world_T_base is None else sequence.world_T_base[frame]
