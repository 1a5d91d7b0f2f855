"""The paper's chained estimator: frame by frame, segments from the base outward.

For frame f and segment i, the motion of the segment's base between frames f-1 and f comes from
the robot base poses (if any) and the angles of segments 0..i-1 already estimated for both frames;
theta_i(f) is then estimated from theta_i(f-1) by 1-point RANSAC on the correspondences of camera
i between the two frames. Errors pile up along the sequence and outward along the robot (the paper
says so; docs/estimation.md, "Two frames", says why): this is the baseline the factor-graph back end
must beat, and its initialiser.

Outcomes per frame and segment (``Estimate.status``): ``"ok"``; ``"no-motion"`` (the camera saw
no parallax: the angle is carried over, which is what the data say); ``"no-consensus"`` or
``"too-few-correspondences"`` (RANSAC failed: the angle is carried over and flagged);
``"no-camera"`` (the segment has no camera: carried over).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike
from tqdm import tqdm

from apcc_graph.estimation.result import Estimate
from apcc_graph.frontend.ransac import one_point_ransac
from apcc_graph.model.kinematics import apcc_transform
from apcc_graph.model.sequence import Sequence


def chain_estimate(
    sequence: Sequence,
    theta0: ArrayLike | None = None,
    threshold_px: float = 1.0,
    confidence: float = 0.999,
    seed: int = 0,
    progress: bool = False,
) -> Estimate:
    """Estimate every frame's angles by the paper's chained 1-point method.

    Args:
        sequence: the sequence (tracks per camera; base poses if the base moves).
        theta0: ``(S,)`` angles at frame 0 in radians (default straight, zeros).
        threshold_px: RANSAC inlier threshold in pixels (divided by each camera's focal length).
        confidence: RANSAC confidence.
        seed: random seed of the RANSAC sampling.
        progress: show a progress bar.

    Returns:
        The estimate (``sigmas`` are NaN: the chain gives no uncertainty).
    """
    robot = sequence.robot
    n_frames, n_seg = sequence.n_frames, robot.n_segments
    thetas = np.zeros((n_frames, n_seg))
    thetas[0] = robot.configuration(theta0)
    status = np.full((n_frames, n_seg), "initial", dtype="<U24")
    inliers = np.zeros((n_frames, n_seg), dtype=np.int64)
    rng = np.random.default_rng(seed)
    base = _base_pose(sequence, 0)
    prev_bases = np.empty((n_seg, 4, 4))
    for i, seg in enumerate(robot.segments):
        prev_bases[i] = base
        base = base @ apcc_transform(thetas[0, i], seg)
    for f in tqdm(range(1, n_frames), desc="chain", disable=not progress):
        prev_bases = _chain_frame(sequence, f, thetas, status, inliers, prev_bases,
                                  threshold_px, confidence, rng)
    return Estimate(
        method="chain", robot=robot, timestamps=sequence.timestamps.copy(), thetas=thetas,
        sigmas=np.full((n_frames, n_seg), np.nan), status=status, inliers=inliers,
        world_T_base=sequence.world_T_base,
    )


def _base_pose(sequence: Sequence, frame: int) -> np.ndarray:
    return np.eye(4) if sequence.world_T_base is None else sequence.world_T_base[frame]


def _chain_frame(sequence: Sequence, f: int, thetas: np.ndarray, status: np.ndarray,
                 inliers: np.ndarray, prev_bases: np.ndarray, threshold_px: float,
                 confidence: float, rng: np.random.Generator) -> np.ndarray:
    """Frame f's angles (``thetas[f]``, ``status[f]``, ``inliers[f]`` in place), segment by
    segment from the base; returns the world pose of every segment's base at frame f."""
    robot = sequence.robot
    pose = _base_pose(sequence, f)
    bases = np.empty((robot.n_segments, 4, 4))
    for i, seg in enumerate(robot.segments):
        bases[i] = pose
        camera = robot.cameras[i]
        thetas[f, i] = thetas[f - 1, i]
        if camera is None:
            status[f, i] = "no-camera"
        else:
            corr = sequence.correspondences(i, f - 1, f)
            base_motion = np.linalg.inv(prev_bases[i]) @ pose
            theta, info = one_point_ransac(
                corr.f_a, corr.f_b, thetas[f - 1, i], seg, camera.tip_T_cam, base_motion,
                threshold=threshold_px / camera.fx, confidence=confidence, rng=rng,
            )
            status[f, i] = info.status
            inliers[f, i] = info.n_inliers
            if info.success:
                thetas[f, i] = theta
        pose = pose @ apcc_transform(thetas[f, i], seg)
    return bases
