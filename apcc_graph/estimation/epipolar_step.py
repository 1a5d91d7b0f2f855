"""A frame's vector from the generalized epipolar constraints against a keyframe: the cheap
per-frame step of a smoother that keeps keyframes only (``docs/estimation.md``, "Two frames").

Given the keyframe's vector ``x_k`` (held fixed) and, for every camera, the unit bearings of
the tracks it shares with the keyframe (``f_k`` there, ``f_n`` now), the new frame's vector
``x_n`` minimises

    sum_cameras sum_rows rho(e(x_k, x_n) / sigma) + |x_n - x_guess|^2 / prior_sigma^2

with ``e`` the Sampson errors (:func:`~apcc_graph.factors.epipolar.epipolar_residual`), ``rho``
Cauchy's loss (scale ``k`` sigmas, widened while the residuals' robust spread is larger), by
Gauss-Newton with the weights held fixed each step (iteratively reweighted least squares),
each step halved until the robust cost drops, all cameras and segments jointly. The prior keeps what
the constraints do not tell (a camera that barely moved says little about the bends) at the
guess. Nothing is a gtsam variable: a few segments' vector, solved in numpy. The guess must
not be the keyframe's vector itself: there the cameras have not moved, every error vanishes
whatever the bearings (the constraint's trivial root), and the constraints say nothing; a
motion prediction from the previous frames, or the cameras' rotations, is what to start from.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from apcc_graph.factors.camera_chain import CameraChain
from apcc_graph.factors.epipolar import epipolar_residual
from apcc_graph.model.arrays import FloatArray

MAX_HALVINGS = 6
"""A Gauss-Newton step whose robust cost is not lower is halved, at most this many times
(undamped steps oscillated on 2 of 30 seeds with 10% outliers)."""

Bearings = tuple[FloatArray, FloatArray]
"""``(f_k, f_n)``: ``(N, 3)`` bearings of the shared tracks at the keyframe and now."""


@dataclass(frozen=True)
class EpipolarStep:
    """The new frame's vector and what its solve saw.

    Attributes:
        x: the vector (radians).
        covariance: its covariance from the last step's information (radians^2).
        weights: camera -> each row's Cauchy weight at the end (near 0: an outlier).
        iterations: Gauss-Newton steps taken.
    """

    x: FloatArray
    covariance: FloatArray
    weights: dict[int, FloatArray]
    iterations: int


def epipolar_step(chains: Mapping[int, CameraChain], keyframe: int, x_key: ArrayLike,
                  frame: int, x_guess: ArrayLike, bearings: Mapping[int, Bearings],
                  sigma: float, prior_sigma: float, cauchy: float = 3.0,
                  max_iterations: int = 10, tolerance: float = 1e-9) -> EpipolarStep:
    """Frame ``frame``'s vector from its cameras' epipolar constraints against ``keyframe``
    (module docstring).

    Args:
        chains: camera -> its chain (base poses covering both frames).
        keyframe, x_key: the keyframe and its vector (held fixed).
        frame, x_guess: the new frame and its guess (also the prior's mean).
        bearings: camera -> the shared tracks' bearings ``(f_k, f_n)``.
        sigma: a row's Sampson noise (radians: pixel noise / focal length).
        prior_sigma: the prior's standard deviation on every component (radians).
        cauchy: Cauchy's scale in sigmas.
        max_iterations, tolerance: Gauss-Newton stops after this many steps, or when a step
            is below ``tolerance`` (radians).
    """
    x_key = np.asarray(x_key, dtype=float)
    guess = np.asarray(x_guess, dtype=float)
    x, dim = guess.copy(), len(guess)

    def rows(at: FloatArray, jacobians: bool) -> dict[int, tuple]:
        return {cam: epipolar_residual(x_key, at, chains[cam], keyframe, frame, f_k, f_n, dim,
                                       jacobians) for cam, (f_k, f_n) in bearings.items()}

    def cost(at: FloatArray, scale: float) -> float:
        whitened = [e / sigma for e, _, _ in rows(at, False).values()]
        data = sum(float(np.sum(np.log1p((r / scale) ** 2))) for r in whitened)
        return 0.5 * scale**2 * data + 0.5 * float(np.sum((at - guess) ** 2)) / prior_sigma**2

    weights: dict[int, FloatArray] = {}
    info = np.eye(dim) / prior_sigma**2
    done = 0
    for done in range(1, max_iterations + 1):  # noqa: B007 (done is read after the loop)
        now = rows(x, True)
        scale = cauchy * _spread([e / sigma for e, _, _ in now.values()])
        info = np.eye(dim) / prior_sigma**2
        grad = (x - guess) / prior_sigma**2
        for cam, (e, _, H) in now.items():
            r, J = e / sigma, H / sigma
            weights[cam] = w = 1.0 / (1.0 + (r / scale) ** 2)
            info += J.T @ (w[:, None] * J)
            grad += J.T @ (w * r)
        step = -np.linalg.solve(info, grad)
        before = cost(x, scale)
        for _ in range(MAX_HALVINGS):  # Gauss-Newton's step, halved until the cost drops
            if cost(x + step, scale) < before:
                break
            step = 0.5 * step
        x = x + step
        if np.max(np.abs(step)) < tolerance:
            break
    return EpipolarStep(x, np.linalg.inv(info), weights, done)


def _spread(residuals: list[FloatArray]) -> float:
    """How far the whitened residuals spread, robustly (1.4826 times their median absolute
    value), but at least 1: Cauchy's scale follows the inliers down while the guess is
    still far (then every row is large, and a scale of a few sigmas would call them all
    outliers), and is ``cauchy`` sigmas once they fit."""
    if not residuals:
        return 1.0
    r = np.abs(np.concatenate(residuals))
    return max(1.0, 1.4826 * float(np.median(r))) if len(r) else 1.0
