"""The chained estimator of a spatial robot: frame by frame, segments from the base outward.

As the planar chain (:mod:`apcc_graph.estimation.chain`), with two unknowns per segment: for
frame f and segment i, the motion of the segment's base between frames f-1 and f comes from the
robot base poses and the bending vectors of segments 0..i-1 already estimated for both frames;
segment i's bend ``(theta, psi)`` at frame f then comes from its bend at frame f-1 by the
2-point RANSAC (:func:`~apcc_graph.frontend.spatial_ransac.two_point_ransac`) on camera i's
correspondences between the two frames. Errors pile up as in the planar chain: this initialises
the spatial batch, which removes them.

Outcomes per frame and segment are the planar chain's (``"ok"``, ``"no-motion"``,
``"no-consensus"``, ``"too-few-correspondences"``, ``"no-camera"``); where the RANSAC fails the
bend is carried over.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray
from tqdm import tqdm

from apcc_graph.estimation.result import Estimate
from apcc_graph.estimation.spatial_bends import bends_from, polar_from, start_bends
from apcc_graph.frontend.spatial_ransac import two_point_ransac
from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.bending import bending_transform, polar
from apcc_graph.model.sequence import Sequence


def spatial_chain_bends(sequence: Sequence, bend0: FloatArray, threshold_px: float = 1.0,
                        confidence: float = 0.999, seed: int = 0, progress: bool = False
                        ) -> tuple[FloatArray, NDArray[np.str_], NDArray[np.int64]]:
    """``(F, 2 S)`` bending vectors chained from ``bend0`` ``(2 S,)``, with the ``(F, S)``
    status and inlier counts (see the module docstring)."""
    robot = sequence.robot
    n_frames, n_seg = sequence.n_frames, robot.n_segments
    bends = np.zeros((n_frames, 2 * n_seg))
    bends[0] = bend0
    status = np.full((n_frames, n_seg), "initial", dtype="<U24")
    inliers = np.zeros((n_frames, n_seg), dtype=np.int64)
    rng = np.random.default_rng(seed)
    prev_bases = _segment_bases(sequence, 0, bends[0])
    for f in tqdm(range(1, n_frames), desc="spatial chain", disable=not progress):
        pose = _base_pose(sequence, f)
        bases = np.empty((n_seg, 4, 4))
        for i, seg in enumerate(robot.segments):
            bases[i] = pose
            bends[f, 2 * i:2 * i + 2] = bends[f - 1, 2 * i:2 * i + 2]
            camera = robot.cameras[i]
            if camera is None:
                status[f, i] = "no-camera"
            else:
                corr = sequence.correspondences(i, f - 1, f)
                theta_a, psi_a = polar(*bends[f - 1, 2 * i:2 * i + 2])
                bend, info = two_point_ransac(
                    float(theta_a), float(psi_a), seg, camera.tip_T_cam,
                    np.linalg.inv(prev_bases[i]) @ pose, corr.f_a, corr.f_b,
                    threshold=threshold_px / camera.fx, confidence=confidence, rng=rng)
                status[f, i] = info.status
                inliers[f, i] = info.n_inliers
                if info.success:
                    bends[f, 2 * i:2 * i + 2] = bends_from(bend[:1], bend[1:])
            pose = pose @ bending_transform(*bends[f, 2 * i:2 * i + 2], seg)
        prev_bases = bases
    return bends, status, inliers


def spatial_chain_estimate(sequence: Sequence, theta0: ArrayLike | None = None,
                           psi0: ArrayLike | None = None, threshold_px: float = 1.0,
                           confidence: float = 0.999, seed: int = 0,
                           progress: bool = False) -> Estimate:
    """Estimate every frame's bends ``(theta, psi)`` of a spatial robot by the chained 2-point
    method.

    Args:
        sequence: the sequence (ground truth is never read).
        theta0, psi0: ``(S,)`` bends at frame 0 (radians; default straight).
        threshold_px: RANSAC inlier threshold in pixels.
        confidence: RANSAC confidence.
        seed: random seed of the RANSAC sampling.
        progress: show a progress bar.

    Returns:
        The estimate (``method = "chain"``, with ``psis``; sigmas are NaN).
    """
    bend0 = start_bends(sequence.robot, theta0, psi0)
    bends, status, inliers = spatial_chain_bends(sequence, bend0, threshold_px, confidence,
                                                 seed, progress)
    thetas, psis = polar_from(bends)
    nan = np.full(thetas.shape, np.nan)
    return Estimate(method="chain", robot=sequence.robot,
                    timestamps=sequence.timestamps.copy(), thetas=thetas, sigmas=nan,
                    status=status, inliers=inliers, world_T_base=sequence.world_T_base,
                    psis=psis, psi_sigmas=nan.copy())


def _base_pose(sequence: Sequence, frame: int) -> FloatArray:
    return np.eye(4) if sequence.world_T_base is None else sequence.world_T_base[frame]


def _segment_bases(sequence: Sequence, frame: int, bend: FloatArray) -> FloatArray:
    """``(S, 4, 4)`` world pose of every segment's base at ``frame`` with bends ``bend``."""
    robot = sequence.robot
    pose = _base_pose(sequence, frame)
    bases = np.empty((robot.n_segments, 4, 4))
    for i, seg in enumerate(robot.segments):
        bases[i] = pose
        pose = pose @ bending_transform(*bend[2 * i:2 * i + 2], seg)
    return bases
