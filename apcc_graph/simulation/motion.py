"""True motions of the simulated robot: smooth random signals, the paper's random steps,
given angles (checked) and a moving base.

Units: radians, seconds, metres.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import gtsam
import numpy as np
from numpy.typing import ArrayLike

from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.robot import Robot

MOTIONS = ("smooth", "paper")


@dataclass(frozen=True)
class SmoothSignal:
    """Smooth random signals in [-1, 1]: per channel a weighted sum of three sinusoids.

    Drawn once (:meth:`draw`), then evaluated at any times, so a stream generated frame by
    frame follows the same curve as a whole sequence.
    """

    freqs: FloatArray  # (3, n) Hz
    phases: FloatArray  # (3, n) radians
    weights: FloatArray  # (3, n)

    @classmethod
    def draw(cls, rng: np.random.Generator, n: int,
             freq_range: tuple[float, float] = (0.05, 0.4)) -> SmoothSignal:
        """``n`` channels with frequencies drawn in ``freq_range`` (Hz)."""
        freqs = rng.uniform(*freq_range, (3, n))
        phases = rng.uniform(0.0, 2 * math.pi, (3, n))
        return cls(freqs, phases, rng.uniform(0.5, 1.0, (3, n)))

    def __call__(self, t: FloatArray) -> FloatArray:
        """``(F, n)`` values at the times ``t`` ``(F,)`` (seconds)."""
        t = np.asarray(t, dtype=float)
        signal = np.einsum("kn,fkn->fn", self.weights,
                           np.sin(2 * math.pi * self.freqs[None] * t[:, None, None]
                                  + self.phases[None]))
        return signal / self.weights.sum(axis=0)


def smooth_signal(rng: np.random.Generator, t: FloatArray, n: int,
                   freq_range: tuple[float, float] = (0.05, 0.4)) -> FloatArray:
    """``(F, n)`` smooth random signals in [-1, 1] (:class:`SmoothSignal`) at the times ``t``."""
    return SmoothSignal.draw(rng, n, freq_range)(t)


def paper_walk(rng: np.random.Generator, n_frames: int, limits: FloatArray,
                max_step: float) -> FloatArray:
    """Random steps ``|theta_b - theta_a| < max_step`` reflected into ``[-limit, limit]``."""
    steps = rng.uniform(-max_step, max_step, (n_frames, len(limits)))
    steps[0] = rng.uniform(-1.0, 1.0, len(limits)) * limits
    walk = np.cumsum(steps, axis=0)
    period = 4 * limits
    folded = np.mod(walk + limits, period)  # reflect: a triangle wave of the unbounded walk
    return np.where(folded < 2 * limits, folded - limits, 3 * limits - folded)


def bends_of(rng: np.random.Generator, robot: Robot, t: FloatArray, motion: str, amplitude: float,
           max_step_deg: float, paper_range_deg: float) -> FloatArray:
    """``(F, S)`` true bends of the smooth or the paper motion (see :func:`simulate`)."""
    limits = np.array([seg.theta_max for seg in robot.segments])
    if motion == "smooth":
        return amplitude * limits * smooth_signal(rng, t, robot.n_segments)
    bound = np.minimum(math.radians(paper_range_deg), limits)
    return paper_walk(rng, len(t), bound, math.radians(max_step_deg))


def given_bends(robot: Robot, bends: ArrayLike, n_frames: int) -> FloatArray:
    """The ``bends`` option checked: ``(F, S)`` finite angles within each theta_max."""
    out = np.asarray(bends, dtype=float)
    if out.shape != (n_frames, robot.n_segments) or not np.all(np.isfinite(out)):
        raise ValueError(f"bends: expected ({n_frames}, {robot.n_segments}) finite angles "
                         f"(radians), got shape {out.shape}")
    limits = np.array([seg.theta_max for seg in robot.segments])
    beyond = np.flatnonzero(np.any(np.abs(out) > limits + 1e-12, axis=0))
    if len(beyond):
        i = int(beyond[0])
        raise ValueError(f"bends: segment {i + 1} reaches "
                         f"{math.degrees(float(np.max(np.abs(out[:, i])))):.1f} deg, beyond its "
                         f"theta_max of {math.degrees(limits[i]):.1f} deg")
    return out


def base_motion(rng: np.random.Generator, t: FloatArray, rotation_deg: float,
                 translation: float) -> FloatArray:
    """``(F, 4, 4)`` base poses: smooth rotations within ``rotation_deg`` about each axis and
    translations of norm up to ``translation`` metres."""
    rot = math.radians(rotation_deg) * smooth_signal(rng, t, 3)
    trans = smooth_signal(rng, t, 3)
    trans *= translation / float(np.max(np.linalg.norm(trans, axis=1)))
    return np.stack([gtsam.Pose3(gtsam.Rot3.RzRyRx(*r), p).matrix()
                     for r, p in zip(rot, trans, strict=True)])
