"""``apcc-graph bench calibration``: APCC sweep fit vs the paper's one-pose method vs PCC.

A synthetic sweep of a rod whose curvature grows along the arc
(:func:`apcc_graph.simulation.planar_curves.growing_curvature_tip`), measured with Gaussian
noise on the tip position and angle. Each model is fitted to the noisy poses and its tip is
compared with the true (noise-free) tip at every pose: RMS position error (metres) and RMS tip-
angle error (radians).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from apcc_graph.calibration.closed_form import calibrate_from_tip
from apcc_graph.calibration.fit import fit_segment, fit_thetas
from apcc_graph.model.arrays import rms
from apcc_graph.model.kinematics import apcc_in_plane, pcc_in_plane
from apcc_graph.model.segment import Segment
from apcc_graph.simulation.planar_curves import growing_curvature_tip


@dataclass(frozen=True)
class ModelError:
    """One model's error against the true tips of the sweep."""

    model: str
    rms_position: float  # metres
    rms_angle: float  # radians
    k: float
    delta_max: float  # radians


@dataclass(frozen=True)
class CalibrationBenchmark:
    """Result of :func:`run_calibration_benchmark`."""

    length: float
    growth: float
    n_poses: int
    theta_max: float
    noise_position: float
    noise_angle: float
    rows: tuple[ModelError, ...]
    thetas: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)
    """``(N,)`` true bends of the sweep (radians)."""
    truth_tips: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)), repr=False)
    """``(N, 2)`` true tip positions ``(x, z)`` (metres)."""
    model_tips: dict[str, np.ndarray] = field(default_factory=dict, repr=False)
    """model name -> ``(N, 2)`` its fitted tip positions (metres)."""

    def row(self, model: str) -> ModelError:
        """The row of a model by name."""
        return next(r for r in self.rows if r.model == model)


def _apcc_tips(seg: Segment, thetas: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(N, 2)`` tip positions ``(x, z)`` (metres) and ``(N,)`` tip angles of ``seg``."""
    planar = apcc_in_plane(thetas, seg)
    return np.column_stack([planar.px, planar.pz]), seg.tip_angle(thetas)


def run_calibration_benchmark(
    length: float = 0.5,
    growth: float = 2.0,
    n_poses: int = 41,
    theta_max: float = math.radians(80.0),
    noise_position: float = 0.0005,
    noise_angle: float = math.radians(0.5),
    seed: int = 0,
) -> CalibrationBenchmark:
    """Fit APCC (sweep and one-pose) and PCC to a noisy growing-curvature sweep; score vs truth.

    Args:
        length: rod length (metres).
        growth: curvature growth g from base to tip (curvature at the tip is ``1 + g`` times that
            at the base).
        n_poses: poses evenly spread over ``[-theta_max, theta_max]``.
        theta_max: largest bend (radians).
        noise_position: standard deviation of the measured tip position, per axis (metres).
        noise_angle: standard deviation of the measured tip angle (radians).
        seed: random seed of the noise.
    """
    rng = np.random.default_rng(seed)
    thetas = np.linspace(-theta_max, theta_max, n_poses)
    x, z, angle = growing_curvature_tip(thetas, length, growth)
    truth = np.column_stack([x, z])
    measured = truth + rng.normal(0.0, noise_position, truth.shape)
    measured_angle = angle + rng.normal(0.0, noise_angle, angle.shape)

    model_tips: dict[str, np.ndarray] = {}

    def score(name: str, seg: Segment | None, tips: np.ndarray, angles: np.ndarray) -> ModelError:
        model_tips[name] = tips
        return ModelError(model=name, rms_position=float(rms(np.linalg.norm(tips - truth, axis=1))),
                          rms_angle=float(rms(angles - angle)),
                          k=seg.k if seg else math.nan,
                          delta_max=seg.delta_max if seg else math.nan)

    sweep = fit_segment(measured, measured_angle, length)
    top = int(np.argmax(thetas))
    one = calibrate_from_tip(measured[top], float(measured_angle[top]), length).segment
    rows = [score(name, seg, *_apcc_tips(seg, fitted)) for name, seg, fitted in (
        ("APCC, fit_segment (sweep)", sweep.segment, sweep.thetas),
        ("APCC, calibrate_from_tip (paper, one pose)", one,
         fit_thetas(one, measured, measured_angle).thetas))]
    px, pz = pcc_in_plane(sweep.pcc.thetas, length)
    rows.append(score("PCC (best fit)", None, np.column_stack([px, pz]), sweep.pcc.thetas))
    return CalibrationBenchmark(
        length=length,
        growth=growth,
        n_poses=n_poses,
        theta_max=theta_max,
        noise_position=noise_position,
        noise_angle=noise_angle,
        rows=tuple(rows),
        thetas=thetas,
        truth_tips=truth,
        model_tips=model_tips,
    )
