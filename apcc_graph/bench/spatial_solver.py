"""``apcc-graph bench spatial-solver``: the 2-point solver of a spatial segment, and its RANSAC
against OpenCV's 5-point RANSAC.

Three figures, all seeded:

- the minimal solver's true-root rate: noise-free random cases (segment length 0.1-0.5 m, k in
  (0.1, 0.4), delta_max within 15% of theta_max, theta_max 30-120 deg, frame a's bend within 80%
  of theta_max at any psi, a bending-vector step of 1-6 deg in any direction, a random mounting
  70% of the time and a random base motion half of the time, two points 0.3-4 m in front of the
  camera): how often the true bend is among the returned roots (to 1e-6 rad);
- the RANSAC: a tip camera (f = 500 px, 640x480) on a 0.5 m segment (k = 0.25, theta_max 60
  deg) bending 3-5 deg in any direction from anywhere within 45 deg, half of the trials on a
  moving base; 200 correspondences at 2-8 m, 0.5 px noise, 10% outliers. Timed on the same
  correspondences: :func:`~apcc_graph.frontend.two_point_ransac` (its compiled engine, after
  one warm-up call whose time, the numba compilation or the load from numba's cache, is
  reported apart; and its numpy reference engine, whose estimates must agree) and
  ``cv2.findEssentialMat`` (RANSAC, prob 0.999, threshold 1 px) followed by
  ``cv2.recoverPose``; OpenCV's rotation is turned into the segment's bending vector through
  the model (the tip's rotation at b is a turn by ``beta_b`` about ``(-sin psi_b, cos psi_b,
  0)``, i.e. the rotation vector ``(1 - delta_max / theta_max) (-v, u, 0)``). Also the share
  of the true inliers that ours keeps and of the outliers that it accepts;
- the minimal solver's median time per call (from the first figure's calls).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from apcc_graph.frontend import ransac_jit, two_point, two_point_ransac
from apcc_graph.frontend.geometry import SegmentTwoView
from apcc_graph.frontend.spatial_basis import bending_poses
from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.bending import bending_vector
from apcc_graph.model.camera import TipCamera
from apcc_graph.model.kinematics import apcc_transform
from apcc_graph.model.segment import Segment

BoolArray = NDArray[np.bool_]

GROSS = math.radians(5.0)
"""A bending-vector error above this (radians) is a gross failure (for OpenCV, mostly the
twisted pair: a rotation 180 degrees off, which a short baseline cannot tell apart)."""


@dataclass(frozen=True)
class SpatialCase:
    """One two-view trial of a spatial segment (bends in radians, bearings ``(N, 3)``)."""

    segment: Segment
    theta_a: float
    psi_a: float
    b_b: FloatArray
    tip_T_cam: FloatArray | None
    baseA_T_baseB: FloatArray | None
    f_a: FloatArray
    f_b: FloatArray
    uv_a: FloatArray
    uv_b: FloatArray
    outliers: BoolArray | None = None  # the correspondences replaced by random ones


@dataclass(frozen=True)
class SpatialSolverBenchmark:
    """Result of :func:`run_spatial_solver_benchmark` (times in seconds, errors in radians)."""

    cases: int
    found: int
    mean_roots: float
    solve_seconds: float
    trials: int
    ransac_seconds: float
    ransac_error: float
    ransac_failures: int
    opencv_seconds: float
    opencv_pose_seconds: float
    opencv_error: float
    opencv_failures: int
    ransac_gross: int  # trials more than GROSS off
    opencv_gross: int
    first_call_seconds: float  # the compiled engine's first call: compilation or cache load
    first_call: str  # "compiled", "loaded from numba's cache" or "already compiled"
    numpy_seconds: float  # the numpy reference engine on the same trials
    engine_gap: float  # largest bending-vector difference between the two engines (radians)
    inliers_kept: float  # mean share of the true inliers that ours marks inliers
    outliers_accepted: float  # mean share of the outliers that ours marks inliers


def _small_pose(rng: np.random.Generator, rot: float, trans: float) -> FloatArray:
    """A random 4x4 pose: rotation vector ~ N(0, rot) rad, translation ~ N(0, trans) m."""
    pose = np.eye(4)
    pose[:3, :3] = cv2.Rodrigues(rng.normal(0.0, rot, 3))[0]
    pose[:3, 3] = rng.normal(0.0, trans, 3)
    return pose


def _pose(theta_a: float, psi_a: float, segment: Segment, tip: FloatArray | None,
          base: FloatArray | None, b: FloatArray) -> FloatArray:
    view = SegmentTwoView.build(theta_a, segment, tip, base, psi_a)
    return bending_poses(view, b[:1], b[1:])[0]


def _step(rng: np.random.Generator, b_a: FloatArray, lo: float, hi: float) -> FloatArray:
    size, angle = math.radians(rng.uniform(lo, hi)), rng.uniform(0.0, 2.0 * math.pi)
    return b_a + size * np.array([math.cos(angle), math.sin(angle)])


def minimal_case(rng: np.random.Generator) -> SpatialCase:
    """A noise-free random case of the solver's figure (module docstring): two bearings."""
    theta_max = math.radians(rng.uniform(30.0, 120.0))
    segment = Segment(rng.uniform(0.1, 0.5), rng.uniform(0.1, 0.4),
                      rng.uniform(-0.15, 0.15) * theta_max, theta_max)
    while True:
        theta_a, psi_a = rng.uniform(-0.8, 0.8) * theta_max, rng.uniform(0.0, 2.0 * math.pi)
        b_b = _step(rng, np.array(bending_vector(theta_a, psi_a)), 1.0, 6.0)
        if np.hypot(*b_b) < theta_max:
            break
    tip = _small_pose(rng, 0.2, 0.02) if rng.random() < 0.7 else None
    base = _small_pose(rng, 0.03, 0.01) if rng.random() < 0.5 else None
    pose = _pose(theta_a, psi_a, segment, tip, base, b_b)
    while True:
        z = rng.uniform(0.3, 4.0, 2)
        P = np.column_stack([rng.uniform(-0.64, 0.64, 2) * z, rng.uniform(-0.48, 0.48, 2) * z, z])
        P_b = (P - pose[:3, 3]) @ pose[:3, :3]
        if np.all(P_b[:, 2] > 0.05):
            break
    f_a, f_b = (x / np.linalg.norm(x, axis=1, keepdims=True) for x in (P, P_b))
    return SpatialCase(segment, theta_a, psi_a, b_b, tip, base, f_a, f_b, np.zeros((2, 2)),
                       np.zeros((2, 2)))


def ransac_case(rng: np.random.Generator, camera: TipCamera, segment: Segment,
                n_points: int = 200, noise_px: float = 0.5,
                outlier_fraction: float = 0.1) -> SpatialCase:
    """A trial of the RANSAC figure (module docstring), seen by ``camera``."""
    theta_a, psi_a = rng.uniform(-1.0, 1.0) * math.radians(45.0), rng.uniform(0.0, 2.0 * math.pi)
    b_b = _step(rng, np.array(bending_vector(theta_a, psi_a)), 3.0, 5.0)
    base = _small_pose(rng, 0.02, 0.01) if rng.random() < 0.5 else None
    pose = _pose(theta_a, psi_a, segment, camera.tip_T_cam, base, b_b)
    K = camera.intrinsic_matrix
    points = np.zeros((0, 3))
    while len(points) < n_points:
        uv = rng.uniform([0, 0], [camera.width, camera.height], (2 * n_points, 2))
        rays = np.column_stack([(uv - K[:2, 2]) / [K[0, 0], K[1, 1]], np.ones(2 * n_points)])
        cand = rays * rng.uniform(2.0, 8.0, 2 * n_points)[:, None]
        in_b = (cand - pose[:3, 3]) @ pose[:3, :3]
        ok = in_b[:, 2] > 0.1
        ok[ok] &= camera.in_image(camera.project(in_b[ok]))
        points = np.vstack([points, cand[ok]])
    points = points[:n_points]
    uv_a = camera.project(points) + rng.normal(0.0, noise_px, (n_points, 2))
    uv_b = (camera.project((points - pose[:3, 3]) @ pose[:3, :3])
            + rng.normal(0.0, noise_px, (n_points, 2)))
    chosen = rng.choice(n_points, int(round(outlier_fraction * n_points)), replace=False)
    uv_b[chosen] = rng.uniform([0, 0], [camera.width, camera.height], (len(chosen), 2))
    outliers = np.zeros(n_points, dtype=bool)
    outliers[chosen] = True
    return SpatialCase(segment, theta_a, psi_a, b_b, None, base, camera.bearings(uv_a),
                       camera.bearings(uv_b), uv_a, uv_b, outliers)


def bending_from_rotation(camB_R_camA: FloatArray, case: SpatialCase,
                          camera: TipCamera) -> FloatArray:
    """Frame b's bending vector (radians) from an estimated rotation (OpenCV's convention)."""
    Rm = camera.tip_T_cam[:3, :3]
    Ra = apcc_transform(case.theta_a, case.segment, case.psi_a)[:3, :3]
    Rbase = np.eye(3) if case.baseA_T_baseB is None else case.baseA_T_baseB[:3, :3]
    Rb = Rbase.T @ Ra @ Rm @ camB_R_camA.T @ Rm.T  # base_R_tip at b
    omega = cv2.Rodrigues(Rb)[0].ravel()
    rate = 1.0 - case.segment.deviation_rate
    return np.array([omega[1], -omega[0]]) / rate


def _ours(case: SpatialCase, camera: TipCamera, engine: str = "numba"
          ) -> tuple[float, FloatArray, BoolArray]:
    """Seconds, bending vector and inlier mask of ``two_point_ransac`` on one trial (the call
    alone: its random generator is made before the clock starts, as a caller keeps one)."""
    rng = np.random.default_rng(0)
    start = time.perf_counter()
    bend, info = two_point_ransac(case.theta_a, case.psi_a, case.segment, camera.tip_T_cam,
                                  case.baseA_T_baseB, case.f_a, case.f_b,
                                  threshold=1.0 / camera.fx, confidence=0.999, rng=rng,
                                  engine=engine)
    seconds = time.perf_counter() - start
    return seconds, np.array(bending_vector(*bend)), info.inliers


def _warm_up(case: SpatialCase, camera: TipCamera) -> tuple[float, str]:
    """The compiled engine's first call in this process: its seconds, and what it did."""
    fresh = not ransac_jit.ransac.signatures
    hits = sum(ransac_jit.ransac.stats.cache_hits.values())
    seconds = _ours(case, camera)[0]
    if not fresh:
        return seconds, "already compiled"
    loaded = sum(ransac_jit.ransac.stats.cache_hits.values()) > hits
    return seconds, "loaded from numba's cache" if loaded else "compiled"


def _opencv(case: SpatialCase, camera: TipCamera) -> tuple[float, float, float]:
    """Seconds of ``findEssentialMat``, of it and ``recoverPose``, and the bending-vector error
    (NaN when OpenCV returned no matrix)."""
    K = camera.intrinsic_matrix
    start = time.perf_counter()
    E, mask = cv2.findEssentialMat(case.uv_a, case.uv_b, K, method=cv2.RANSAC, prob=0.999,
                                   threshold=1.0)
    seconds = time.perf_counter() - start
    if E is None or E.shape[0] < 3:
        return seconds, math.nan, math.nan
    _, R, _, _ = cv2.recoverPose(E[:3], case.uv_a, case.uv_b, K, mask=mask)
    return (seconds, time.perf_counter() - start,
            float(np.hypot(*(bending_from_rotation(R, case, camera) - case.b_b))))


def _ransac_trials(trials: int, rng: np.random.Generator) -> dict[str, list]:
    """Per trial: times, bending-vector errors and inlier shares of ours (both engines) and
    OpenCV's on the same correspondences; ``first`` holds the warm-up call."""
    segment = Segment(0.5, k=0.25, delta_max=0.0, theta_max=math.radians(60.0))
    camera = TipCamera(500.0, 500.0, 320.0, 240.0, 640, 480)
    rows: dict[str, list] = {key: [] for key in (
        "ours_t", "ours_e", "numpy_t", "gap", "kept", "accepted", "cv_t", "cv_pose_t", "cv_e")}
    for trial in range(trials):
        case = ransac_case(rng, camera, segment)
        if trial == 0:
            rows["first"] = list(_warm_up(case, camera))
        seconds, b, inliers = _ours(case, camera)
        numpy_seconds, b_numpy, _ = _ours(case, camera, "numpy")
        rows["ours_t"].append(seconds)
        rows["ours_e"].append(float(np.hypot(*(b - case.b_b))))
        rows["numpy_t"].append(numpy_seconds)
        rows["gap"].append(float(np.max(np.abs(b - b_numpy))) if np.all(np.isfinite(b))
                           else 0.0 if np.all(np.isnan(b_numpy)) else math.inf)
        rows["kept"].append(float(np.mean(inliers[~case.outliers])))
        rows["accepted"].append(float(np.mean(inliers[case.outliers])))
        for key, value in zip(("cv_t", "cv_pose_t", "cv_e"), _opencv(case, camera),
                              strict=True):
            rows[key].append(value)
    return rows


def _median(values: list[float]) -> float:
    finite = [v for v in values if math.isfinite(v)]
    return float(np.median(finite)) if finite else math.nan


def run_spatial_solver_benchmark(cases: int = 2000, trials: int = 100,
                                 seed: int = 0) -> SpatialSolverBenchmark:
    """Run the three figures (module docstring).

    Args:
        cases: noise-free random cases of the minimal solver.
        trials: RANSAC trials (200 correspondences each).
        seed: random seed of every scene.
    """
    rng = np.random.default_rng(seed)
    found, roots, times = 0, 0, []
    for _ in range(cases):
        case = minimal_case(rng)
        start = time.perf_counter()
        out = two_point(case.theta_a, case.psi_a, case.segment, case.tip_T_cam,
                        case.baseA_T_baseB, case.f_a, case.f_b)
        times.append(time.perf_counter() - start)
        roots += len(out)
        b = np.column_stack(bending_vector(out[:, 0], out[:, 1]))
        found += bool(len(b)) and float(np.min(np.hypot(*(b - case.b_b).T))) < 1e-6
    r = _ransac_trials(trials, rng)
    ours_e, cv_e = r["ours_e"], r["cv_e"]
    return SpatialSolverBenchmark(
        cases=cases, found=int(found), mean_roots=roots / max(cases, 1),
        solve_seconds=_median(times), trials=trials, ransac_seconds=_median(r["ours_t"]),
        ransac_error=_median(ours_e), ransac_failures=sum(not math.isfinite(e) for e in ours_e),
        opencv_seconds=_median(r["cv_t"]), opencv_pose_seconds=_median(r["cv_pose_t"]),
        opencv_error=_median(cv_e), opencv_failures=sum(not math.isfinite(e) for e in cv_e),
        ransac_gross=sum(e > GROSS for e in ours_e), opencv_gross=sum(e > GROSS for e in cv_e),
        first_call_seconds=r["first"][0], first_call=r["first"][1],
        numpy_seconds=_median(r["numpy_t"]), engine_gap=max(r["gap"]),
        inliers_kept=float(np.mean(r["kept"])), outliers_accepted=float(np.mean(r["accepted"])))
