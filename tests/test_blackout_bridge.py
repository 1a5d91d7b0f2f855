"""The blind frames of a blackout, bridged once the frames after it are re-acquired: the
two-filter fusion (:func:`~apcc_graph.estimation.blackout.bridged`) against gtsam solving the
same random walk as a graph."""

from __future__ import annotations

import gtsam
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from apcc_graph.estimation.blackout import Forward, bridged


def _spd(rng: np.random.Generator, n: int, width: int, scale: float) -> np.ndarray:
    """``n`` random symmetric positive definite ``(width, width)`` blocks."""
    A = rng.normal(size=(n, width, width)) * scale
    return A @ A.transpose(0, 2, 1) + (0.1 * scale) ** 2 * np.eye(width)


def _gtsam_bridge(m: np.ndarray, P: np.ndarray, b: np.ndarray, B: np.ndarray, steps: int,
                  dt: float, q: float) -> tuple[np.ndarray, np.ndarray]:
    """One segment block: the blind frame (key 0) has the forward prior ``(m, P)``; a random
    walk of ``steps`` blind frames leads to the first frame after (key ``steps``), which has
    the prior ``(b, B)``. gtsam's solution and marginal at key 0."""
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    graph.add(gtsam.PriorFactorVector(0, m, gtsam.noiseModel.Gaussian.Covariance(P)))
    graph.add(gtsam.PriorFactorVector(steps, b, gtsam.noiseModel.Gaussian.Covariance(B)))
    walk = gtsam.noiseModel.Isotropic.Sigma(len(m), q * np.sqrt(dt))
    for k in range(steps):
        graph.add(gtsam.BetweenFactorVector(k, k + 1, np.zeros(len(m)), walk))
    for k in range(steps + 1):
        values.insert(k, m)
    result = gtsam.LevenbergMarquardtOptimizer(graph, values).optimize()
    return result.atVector(0), gtsam.Marginals(graph, result).marginalCovariance(0)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), width=st.sampled_from([1, 2]),
       segments=st.integers(1, 3), steps=st.integers(1, 30))
def test_the_bridge_is_the_random_walk_smoothed_over_the_blind_frames(
        seed: int, width: int, segments: int, steps: int) -> None:
    rng = np.random.default_rng(seed)
    dt, q = 1.0 / 30.0, 0.5
    P, B = _spd(rng, segments, width, 0.3), _spd(rng, segments, width, 0.05)
    m, b = rng.normal(size=(segments, width)), rng.normal(size=(segments, width))
    forward = Forward(m.ravel(), P.ravel(), time=2.0)
    x, C = bridged(forward, b.ravel(), B.ravel(), 2.0 + steps * dt, q, width)
    x, C = x.reshape(segments, width), C.reshape(segments, width, width)
    for s in range(segments):
        want_x, want_C = _gtsam_bridge(m[s], P[s], b[s], B[s], steps, dt, q)
        np.testing.assert_allclose(x[s], want_x, rtol=1e-6, atol=1e-9)
        np.testing.assert_allclose(C[s], want_C, rtol=1e-6, atol=1e-12)
    # what the frames after add can only tighten it
    assert np.all(np.diagonal(C, axis1=-2, axis2=-1) <= np.diagonal(P, axis1=-2, axis2=-1))


def test_without_a_covariance_the_forward_estimate_stands() -> None:
    forward = Forward(np.array([0.1, 0.2]), np.array([np.nan, np.nan]), time=0.0)
    x, C = bridged(forward, np.array([1.0, 2.0]), np.array([1e-4, 1e-4]), 1.0, 0.5, 1)
    assert x is forward.thetas and C is forward.blocks
