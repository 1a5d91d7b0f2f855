"""The two-frame front end: a frame's bends from the previous frame's, segment by segment.

For each segment from the base outward, the motion of its base between the two frames comes
from the robot's base poses and the values of the segments below it (the previous frame's
estimate, the new frame's just found); the segment's own value then comes from its camera's
correspondences between the two frames by RANSAC on the generalized epipolar constraint:

- fixed bending planes: the 1-point solver, one angle
  (:func:`apcc_graph.frontend.ransac.one_point_ransac`, in the segment's plane);
- free bending planes: the 2-point solver, one bending vector
  (:func:`apcc_graph.frontend.spatial_ransac.two_point_ransac`).

:func:`chained_guess` is that loop for one frame; the paper's chained estimator
(:mod:`apcc_graph.estimation.chain`) runs it over a recording, and the fixed-lag smoother uses
it to start a frame where it knows too few points (:func:`front_end_guess`). Frame vectors are
the parameterisation's (:class:`~apcc_graph.model.parameterisation.Bending`), radians.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from apcc_graph.estimation.rotation_gate import bearings
from apcc_graph.frontend.ransac import RansacInfo, one_point_ransac
from apcc_graph.frontend.spatial_ransac import two_point_ransac
from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.bending import bending_vector, polar
from apcc_graph.model.parameterisation import Bending
from apcc_graph.model.robot import Robot

Rows = Mapping[int, tuple[NDArray[np.int64], FloatArray, FloatArray]]
"""A frame's observations: camera -> (track ids, normalised points, whitening)."""


@dataclass(frozen=True)
class FramePairs:
    """One camera's correspondences between the previous and the new frame."""

    camera: int
    f_a: FloatArray  # (n, 3) unit bearings in the previous frame
    f_b: FloatArray  # (n, 3) unit bearings in the new frame
    rows: NDArray[np.int64]  # (n,) their rows among the new frame's observations


def frame_pairs(previous: Rows, rows: Rows) -> list[FramePairs]:
    """Each camera's correspondences between the previous frame and the new one, from their
    observations ``camera -> (track ids, normalised points, whitening)``."""
    out = []
    for cam, (ids, xy, _) in rows.items():
        before = previous.get(cam)
        if before is None:
            continue
        common, now, then = np.intersect1d(ids, before[0], return_indices=True)
        if len(common) == 0:
            continue
        out.append(FramePairs(cam, bearings(before[1][then]), bearings(xy[now]), now))
    return out


def segment_bases(x: FloatArray, bending: Bending, world_T_base: FloatArray | None
                  ) -> list[FloatArray]:
    """``world_T_base`` of every segment for one frame's vector ``x`` (``world_T_base``
    ``None``: identity)."""
    pose = np.eye(4) if world_T_base is None else np.asarray(world_T_base, dtype=float)
    out = []
    for j in range(bending.n_segments):
        out.append(pose)
        pose = pose @ bending.transform(x, j)
    return out


def solve_segment(bending: Bending, i: int, tip_T_cam: FloatArray, before: FloatArray,
                  motion: FloatArray, pairs: FramePairs, threshold: float,
                  confidence: float, rng: np.random.Generator
                  ) -> tuple[FloatArray | None, RansacInfo]:
    """Segment i's new value (its components of the frame vector; ``None`` where the RANSAC
    failed) from its previous value ``before``, its base motion ``motion`` (``base_prev_T_
    base_now``) and its camera's correspondences; ``threshold`` in radians."""
    segment = bending.segments[i]
    if bending.planes is None:
        theta_a, psi_a = polar(before[0], before[1])
        bend, info = two_point_ransac(float(theta_a), float(psi_a), segment, tip_T_cam,
                                      motion, pairs.f_a, pairs.f_b, threshold=threshold,
                                      confidence=confidence, rng=rng)
        if not info.success:
            return None, info
        return np.array(bending_vector(bend[0], bend[1])), info
    theta, info = one_point_ransac(pairs.f_a, pairs.f_b, float(before[0]), segment, tip_T_cam,
                                   motion, threshold=threshold, confidence=confidence, rng=rng,
                                   psi=float(bending.planes[i]))
    return (np.array([theta]) if info.success else None), info


def chained_guess(previous: FloatArray, prediction: FloatArray, robot: Robot, bending: Bending,
                  base_previous: FloatArray | None, base_now: FloatArray | None,
                  pairs: list[FramePairs], threshold_px: float,
                  rng: np.random.Generator | None = None, confidence: float = 0.999,
                  min_pairs: int = 5) -> tuple[FloatArray, dict[int, RansacInfo]]:
    """The new frame's vector by the front end, from the previous frame's (module docstring).

    Args:
        previous: the previous frame's vector (radians).
        prediction: the fallback of a segment whose RANSAC fails, that has no camera or whose
            camera has fewer than ``min_pairs`` correspondences (it keeps the prediction).
        robot: the robot (its cameras).
        bending: the parameterisation of ``previous`` and the result.
        base_previous, base_now: the two frames' base poses (``None``: identity).
        pairs: per camera, its correspondences between the two frames.
        threshold_px: inlier threshold (pixels, divided by the camera's focal length).
        rng: RANSAC sampling (default seeded, deterministic).
        confidence: RANSAC confidence.
        min_pairs: cameras with fewer correspondences are not tried.

    Returns:
        The new vector, and per camera tried its RANSAC's outcome (``info.success``,
        ``info.inliers`` over its pairs, ``info.status``).
    """
    rng = np.random.default_rng(0) if rng is None else rng
    x = np.array(prediction, dtype=float)
    by_camera = {p.camera: p for p in pairs}
    before = segment_bases(previous, bending, base_previous)
    infos: dict[int, RansacInfo] = {}
    for i in range(robot.n_segments):
        camera = robot.cameras[i]
        found = by_camera.get(i)
        if camera is None or found is None or len(found.f_a) < min_pairs:
            continue
        motion = np.linalg.inv(before[i]) @ segment_bases(x, bending, base_now)[i]
        cols = bending.columns(i)
        value, infos[i] = solve_segment(bending, i, camera.tip_T_cam, previous[cols], motion,
                                        found, threshold_px / camera.fx, confidence, rng)
        if value is not None:
            x[cols] = value
    return x, infos


def front_end_guess(previous: FloatArray, prediction: FloatArray, robot: Robot,
                    bending: Bending, base_previous: FloatArray | None,
                    base_now: FloatArray | None, previous_rows: Rows, rows: Rows,
                    threshold_px: float, rng: np.random.Generator | None = None
                    ) -> tuple[FloatArray, dict[int, NDArray[np.int64]]]:
    """The new frame's vector by :func:`chained_guess` over the two frames' observations
    ``camera -> (track ids, normalised points, whitening)``, and per camera whose RANSAC
    succeeded the ids of the tracks it accepted as inliers of its consensus."""
    pairs = frame_pairs(previous_rows, rows)
    guess, infos = chained_guess(previous, prediction, robot, bending, base_previous,
                                 base_now, pairs, threshold_px, rng)
    return guess, {p.camera: rows[p.camera][0][p.rows[infos[p.camera].inliers]]
                   for p in pairs if p.camera in infos and infos[p.camera].success}
