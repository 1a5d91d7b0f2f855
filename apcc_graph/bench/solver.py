"""``apcc-graph bench solver``: 1-point RANSAC against essential-matrix RANSAC peers.

One run, the same correspondences for every method: a tip camera (f = 500 px, 640x480) on a
0.5 m segment moving 3-5 degrees, 0.5 px noise, N = 200 and 1000 correspondences, 0 / 30 / 50 %
outliers. Methods: :func:`apcc_graph.frontend.one_point_ransac`; ``cv2.findEssentialMat``
(RANSAC, prob 0.999, 1 px) + ``cv2.recoverPose``; ``cv2.findEssentialMat`` with
``cv2.USAC_DEFAULT``; ``poselib.estimate_relative_pose`` when PoseLib is installed (the ``bench``
extra). The peers estimate a full relative pose; their rotation is turned into theta_b with the
model (planar segment: the rotation about the bend axis is ``beta_b - beta_a``). Reported: median
wall time and median |theta_b error| per setting, and ratios to 1-point RANSAC. Also the minimal
solver's cost per correspondence in a batch of 1000.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import cv2
import numpy as np

from apcc_graph.bench import best_time
from apcc_graph.bench.scenes import TwoViewCase, make_case
from apcc_graph.frontend import one_point, one_point_ransac
from apcc_graph.model.camera import TipCamera
from apcc_graph.model.kinematics import apcc_transform
from apcc_graph.model.segment import Segment

try:  # optional peer
    import poselib
except ImportError:  # pragma: no cover - depends on the environment
    poselib = None


@dataclass(frozen=True)
class MethodResult:
    """One method in one setting: medians over the trials."""

    method: str
    n_points: int
    outlier_fraction: float
    median_seconds: float
    median_error: float  # radians
    failures: int


@dataclass(frozen=True)
class SolverBenchmark:
    """Result of :func:`run_solver_benchmark`."""

    trials: int
    rows: tuple[MethodResult, ...]
    minimal_cost: float  # seconds per correspondence, one_point on a batch of 1000
    methods: tuple[str, ...]

    def row(self, method: str, n_points: int, outlier_fraction: float) -> MethodResult:
        """The row of a method in a setting."""
        return next(r for r in self.rows if r.method == method and r.n_points == n_points
                    and r.outlier_fraction == outlier_fraction)


def theta_from_rotation(camB_R_camA: np.ndarray, case: TwoViewCase, segment: Segment,
                        camera: TipCamera) -> float:
    """theta_b of a planar segment from an estimated rotation (OpenCV / PoseLib convention)."""
    Rm = camera.tip_T_cam[:3, :3]
    camA_R_camB = camB_R_camA.T
    Ra = apcc_transform(case.theta_a, segment)[:3, :3]
    Rbase = np.eye(3) if case.base_motion is None else case.base_motion[:3, :3]
    Rb = Rbase.T @ Ra @ Rm @ camA_R_camB @ Rm.T  # = Ry(beta_b)
    beta_b = math.atan2(Rb[0, 2], Rb[2, 2])
    return beta_b / (1.0 - segment.deviation_rate)


def _ours(case: TwoViewCase, segment: Segment, camera: TipCamera) -> float:
    theta, info = one_point_ransac(case.f_a, case.f_b, case.theta_a, segment,
                                   camera.tip_T_cam, case.base_motion,
                                   threshold=1.0 / camera.fx, confidence=0.999,
                                   rng=np.random.default_rng(0))
    return theta


def _opencv(method: int):  # noqa: ANN202 - returns a solver closure
    def solve(case: TwoViewCase, segment: Segment, camera: TipCamera) -> float:
        K = camera.intrinsic_matrix
        E, mask = cv2.findEssentialMat(case.uv_a, case.uv_b, K, method=method, prob=0.999,
                                       threshold=1.0)
        if E is None or E.shape[0] < 3:
            return math.nan
        _, R, _, _ = cv2.recoverPose(E[:3], case.uv_a, case.uv_b, K, mask=mask)
        return theta_from_rotation(R, case, segment, camera)

    return solve


def _poselib(case: TwoViewCase, segment: Segment, camera: TipCamera) -> float:
    cam = {"model": "PINHOLE", "width": camera.width, "height": camera.height,
           "params": [camera.fx, camera.fy, camera.cx, camera.cy]}
    pose, _ = poselib.estimate_relative_pose(case.uv_a, case.uv_b, cam, cam,
                                             {"max_epipolar_error": 1.0, "success_prob": 0.999},
                                             {})
    return theta_from_rotation(np.asarray(pose.R), case, segment, camera)


def run_solver_benchmark(trials: int = 20, seed: int = 0,
                         sizes: tuple[int, ...] = (200, 1000),
                         outliers: tuple[float, ...] = (0.0, 0.3, 0.5),
                         noise_px: float = 0.5) -> SolverBenchmark:
    """Run every method on the same trials of every setting.

    Args:
        trials: random trials per setting.
        seed: random seed of the scenes.
        sizes: numbers of correspondences.
        outliers: outlier fractions.
        noise_px: pixel noise.
    """
    segment = Segment(0.5, k=0.25, delta_max=0.0, theta_max=math.radians(60.0))
    camera = TipCamera(500.0, 500.0, 320.0, 240.0, 640, 480)
    methods = {
        "one_point_ransac": _ours,
        "cv2 RANSAC + recoverPose": _opencv(cv2.RANSAC),
        "cv2 USAC_DEFAULT + recoverPose": _opencv(cv2.USAC_DEFAULT),
    }
    if poselib is not None:
        methods["poselib.estimate_relative_pose"] = _poselib
    rng = np.random.default_rng(seed)
    rows = []
    for n in sizes:
        for frac in outliers:
            cases = [make_case(rng, segment, camera, n, noise_px, frac,
                               theta_range=math.radians(45.0),
                               step_range=(math.radians(3.0), math.radians(5.0)),
                               depth=(2.0, 8.0)) for _ in range(trials)]
            for name, solve in methods.items():
                times, errors, failures = [], [], 0
                for case in cases:
                    start = time.perf_counter()
                    theta = solve(case, segment, camera)
                    times.append(time.perf_counter() - start)
                    if math.isfinite(theta):
                        errors.append(abs(theta - case.theta_b))
                    else:
                        failures += 1
                rows.append(MethodResult(name, n, frac, float(np.median(times)),
                                         float(np.median(errors)) if errors else math.nan,
                                         failures))
    case = make_case(np.random.default_rng(seed + 1), segment, camera, 1000, noise_px)
    cost = best_time(lambda: one_point(case.f_a, case.f_b, case.theta_a, segment), 20) / 1000
    return SolverBenchmark(trials=trials, rows=tuple(rows), minimal_cost=cost,
                           methods=tuple(methods))
