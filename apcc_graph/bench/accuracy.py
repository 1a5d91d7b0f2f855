"""``apcc-graph bench accuracy``: the paper's Fig. 10 protocol against the Cramer-Rao bound.

Protocol (paper V.B; docs/estimation.md, "The paper's two-view experiment"): L = 0.5 m, f = 500 px
(640x480), theta_a in [-50, 50] deg, steps 1 to 5 deg (the paper: under 5 deg; steps under 1 deg
carry almost no parallax and are the chain's "no-motion" case), fixed base and moving base (rotation
alpha in [-5, 5] deg about a pivot 1 m below the base, so the base moves under 0.1 m), Gaussian
pixel noise 0 to 2 px, ``points`` correspondences at 1-5 m, no outliers, 5000 trials per point by
default. Each trial is solved by :func:`apcc_graph.frontend.one_point_ransac`, and its bound
is :func:`apcc_graph.evaluation.two_view_bound.crlb_theta` at the truth. Reported per noise
level: mean and median |error|, the median bound, and efficiency =
median(|error| / bound) / 0.6745 (the median of |N(0, 1)|), which is 1.0 for an estimator that
reaches the bound.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from apcc_graph.bench.scenes import make_case
from apcc_graph.evaluation.two_view_bound import crlb_theta
from apcc_graph.frontend import one_point_ransac
from apcc_graph.io.console import progress_bar
from apcc_graph.model.camera import TipCamera
from apcc_graph.model.segment import Segment

HALF_NORMAL_MEDIAN = 0.6744897501960817


@dataclass(frozen=True)
class AccuracyRow:
    """One noise level of one base case."""

    base: str
    noise_px: float
    trials: int
    failures: int
    mean_error: float  # radians
    median_error: float  # radians
    median_bound: float  # radians
    efficiency: float  # median(|error| / bound) / 0.6745; nan at zero noise


@dataclass(frozen=True)
class AccuracyBenchmark:
    """Result of :func:`run_accuracy_benchmark`."""

    points: int
    rows: tuple[AccuracyRow, ...]


def run_accuracy_benchmark(
    trials: int = 5000,
    noise_levels: tuple[float, ...] = (0.0, 0.5, 1.0, 1.5, 2.0),
    points: int = 100,
    seed: int = 0,
    progress: bool = False,
) -> AccuracyBenchmark:
    """Run the Fig. 10 protocol (see the module docstring)."""
    segment = Segment(0.5, k=0.25, delta_max=0.0, theta_max=math.radians(60.0))
    camera = TipCamera(500.0, 500.0, 320.0, 240.0, 640, 480)
    rng = np.random.default_rng(seed)
    rows = []
    total = 2 * len(noise_levels) * trials
    bar = progress_bar(total=total, desc="accuracy", progress=progress)
    for base, alpha in (("fixed", None), ("moving", math.radians(5.0))):
        for noise in noise_levels:
            errors, ratios, bounds, failures = [], [], [], 0
            for _ in range(trials):
                case = make_case(rng, segment, camera, points, noise, base_alpha=alpha)
                theta, info = one_point_ransac(
                    case.f_a, case.f_b, case.theta_a, segment, None, case.base_motion,
                    threshold=max(3.0 * noise, 0.5) / camera.fx, rng=rng)
                bar.update()
                if not info.success:
                    failures += 1
                    continue
                err = abs(theta - case.theta_b)
                errors.append(err)
                if noise > 0.0:
                    bound = crlb_theta(case.clean_f_a, case.clean_f_b, case.theta_a,
                                       case.theta_b, segment, None, case.base_motion,
                                       noise_px=noise, camera=camera)
                    bounds.append(bound)
                    ratios.append(err / bound)
            rows.append(AccuracyRow(
                base=base, noise_px=noise, trials=trials, failures=failures,
                mean_error=float(np.mean(errors)) if errors else math.nan,
                median_error=float(np.median(errors)) if errors else math.nan,
                median_bound=float(np.median(bounds)) if bounds else 0.0,
                efficiency=(float(np.median(ratios)) / HALF_NORMAL_MEDIAN) if ratios
                else math.nan,
            ))
    bar.close()
    return AccuracyBenchmark(points=points, rows=tuple(rows))
