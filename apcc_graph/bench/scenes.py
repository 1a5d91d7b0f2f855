"""Two-view test scenes for the solver benchmarks: a tip camera on one segment, random points."""

from __future__ import annotations

import math
from dataclasses import dataclass

import gtsam
import numpy as np
from numpy.typing import NDArray

from apcc_graph.frontend.geometry import relative_camera_pose
from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.camera import TipCamera
from apcc_graph.model.segment import Segment


@dataclass(frozen=True)
class TwoViewCase:
    """One trial: true angles, base motion, pixels and bearings (``clean_*``: noise-free)."""

    theta_a: float
    theta_b: float
    base_motion: FloatArray | None
    uv_a: FloatArray
    uv_b: FloatArray
    f_a: FloatArray
    f_b: FloatArray
    clean_f_a: FloatArray
    clean_f_b: FloatArray
    outliers: NDArray[np.bool_]


def pivot_base_motion(alpha: float, pivot: float = 1.0) -> FloatArray:
    """Base rotation by ``alpha`` about y around a pivot ``pivot`` metres below the base.

    With |alpha| <= 5 degrees and a 1 m pivot the base moves less than 0.1 m (the paper's
    "moved root" case).
    """
    rot = gtsam.Rot3.Ry(alpha).matrix()
    p = np.array([0.0, 0.0, -pivot])
    pose = np.eye(4)
    pose[:3, :3] = rot
    pose[:3, 3] = p - rot @ p
    return pose


def make_case(
    rng: np.random.Generator,
    segment: Segment,
    camera: TipCamera,
    n_points: int,
    noise_px: float,
    outlier_fraction: float = 0.0,
    theta_range: float = math.radians(50.0),
    step_range: tuple[float, float] = (math.radians(1.0), math.radians(5.0)),
    base_alpha: float | None = None,
    depth: tuple[float, float] = (1.0, 5.0),
) -> TwoViewCase:
    """A random two-view trial seen by ``camera`` (mounted by its ``tip_T_cam``).

    Points are drawn in camera a's view at the given depths and kept if camera b sees them too.
    """
    lim = min(theta_range, segment.theta_max)
    theta_a = rng.uniform(-lim, lim)
    step = rng.uniform(*step_range) * rng.choice([-1.0, 1.0])
    theta_b = float(np.clip(theta_a + step, -segment.theta_max, segment.theta_max))
    base = None if base_alpha is None else pivot_base_motion(rng.uniform(-base_alpha,
                                                                          base_alpha))
    pose = relative_camera_pose(theta_a, theta_b, segment, camera.tip_T_cam, base)
    K = camera.intrinsic_matrix
    points = np.zeros((0, 3))
    while len(points) < n_points:
        m = 2 * n_points
        uv = rng.uniform([0, 0], [camera.width, camera.height], (m, 2))
        rays = np.column_stack([(uv - K[:2, 2]) / [K[0, 0], K[1, 1]], np.ones(m)])
        cand = rays * rng.uniform(*depth, m)[:, None]
        in_b = (cand - pose[:3, 3]) @ pose[:3, :3]
        ok = in_b[:, 2] > 0.1
        ok[ok] &= camera.in_image(camera.project(in_b[ok]))
        points = np.vstack([points, cand[ok]])
    points = points[:n_points]
    in_b = (points - pose[:3, 3]) @ pose[:3, :3]
    clean_a, clean_b = camera.project(points), camera.project(in_b)
    uv_a = clean_a + rng.normal(0.0, noise_px, clean_a.shape)
    uv_b = clean_b + rng.normal(0.0, noise_px, clean_b.shape)
    outliers = np.zeros(n_points, dtype=bool)
    n_out = int(round(outlier_fraction * n_points))
    if n_out:
        chosen = rng.choice(n_points, n_out, replace=False)
        outliers[chosen] = True
        uv_b[chosen] = rng.uniform([0, 0], [camera.width, camera.height], (n_out, 2))
    return TwoViewCase(
        theta_a=float(theta_a), theta_b=theta_b, base_motion=base, uv_a=uv_a, uv_b=uv_b,
        f_a=camera.bearings(uv_a), f_b=camera.bearings(uv_b),
        clean_f_a=camera.bearings(clean_a), clean_f_b=camera.bearings(clean_b),
        outliers=outliers,
    )
