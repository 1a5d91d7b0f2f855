"""The segment tie (the kinematic residual in any parameterisation of a frame): Jacobians against
central differences for fixed and free bending planes, agreement with the one-angle factor, zero
at the kinematic pose, the gtsam factor against the residual, and bad arguments refused."""

from __future__ import annotations

import math

import gtsam
import numpy as np
import pytest
from helpers import random_pose
from hypothesis import given, settings
from hypothesis import strategies as st

from apcc_graph import Segment
from apcc_graph.factors.kinematic import (
    kinematic_residual,
    segment_tie_factor,
    segment_tie_residual,
)
from apcc_graph.model.parameterisation import Bending

SEGMENTS = (Segment(0.3, k=0.2, delta_max=0.15, theta_max=1.0),
            Segment(0.25, k=0.35, delta_max=-0.3, theta_max=1.4),
            Segment(0.2))
SIGMAS = np.array([0.01, 0.02, 0.015, 0.002, 0.001, 0.003])


def _bending(free: bool) -> Bending:
    return Bending.free(SEGMENTS) if free else Bending.fixed(SEGMENTS, [0.3, -1.1, 2.0])


def _point(seed: int, free: bool, exact: bool = False
           ) -> tuple[Bending, int, gtsam.Pose3, np.ndarray, gtsam.Pose3]:
    """A random (bending, segment, base, frame vector, tip); the tip off the model unless exact."""
    rng = np.random.default_rng(seed)
    bending = _bending(free)
    j = int(rng.integers(0, len(SEGMENTS)))
    x = rng.uniform(-0.8, 0.8, bending.dim)
    base = gtsam.Pose3(random_pose(rng, 1.0, 0.5))
    tip = base.compose(gtsam.Pose3(bending.transform(x, j)))
    if not exact:
        tip = tip.compose(gtsam.Pose3(random_pose(rng, 0.3, 0.05)))
    return bending, j, base, x, tip


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10**6), free=st.booleans())
def test_jacobians_match_central_differences(seed: int, free: bool) -> None:
    bending, j, base, x, tip = _point(seed, free)
    r0, h_base, h_x, h_tip = segment_tie_residual(base, x, tip, bending, j)

    def r(b: gtsam.Pose3, v: np.ndarray, t: gtsam.Pose3) -> np.ndarray:
        return segment_tie_residual(b, v, t, bending, j, jacobians=False)[0]

    h = 1e-6
    for i in range(6):
        d = np.zeros(6)
        d[i] = h
        np.testing.assert_allclose(h_base[:, i], (r(base.retract(d), x, tip)
                                                  - r(base.retract(-d), x, tip)) / (2 * h),
                                   atol=1e-6)
        np.testing.assert_allclose(h_tip[:, i], (r(base, x, tip.retract(d))
                                                 - r(base, x, tip.retract(-d))) / (2 * h),
                                   atol=1e-6)
    for p in range(bending.dim):
        d = np.zeros(bending.dim)
        d[p] = h
        np.testing.assert_allclose(h_x[:, p], (r(base, x + d, tip) - r(base, x - d, tip)) / (2 * h),
                                   atol=1e-6)
    outside = np.ones(bending.dim, dtype=bool)
    outside[bending.columns(j)] = False
    assert np.all(h_x[:, outside] == 0.0)


@pytest.mark.parametrize("free", [False, True])
def test_zero_at_the_kinematic_pose_and_not_elsewhere(free: bool) -> None:
    bending, j, base, x, tip = _point(3, free, exact=True)
    r = segment_tie_residual(base, x, tip, bending, j, jacobians=False)[0]
    np.testing.assert_allclose(r, 0.0, atol=1e-12)
    moved = x.copy()
    moved[bending.columns(j).start] += 0.05
    assert np.linalg.norm(segment_tie_residual(base, moved, tip, bending, j)[0]) > 1e-3


def test_fixed_planes_agree_with_the_one_angle_factor() -> None:
    bending, j, base, x, tip = _point(5, free=False)
    r, h_base, h_x, h_tip = segment_tie_residual(base, x, tip, bending, j)
    r1, h_base1, h_theta1, h_tip1 = kinematic_residual(base, x[j], tip, SEGMENTS[j],
                                                       float(bending.planes[j]))
    np.testing.assert_allclose(r, r1, atol=1e-12)
    np.testing.assert_allclose(h_base, h_base1, atol=1e-10)
    np.testing.assert_allclose(h_x[:, [j]], h_theta1, atol=1e-10)
    np.testing.assert_allclose(h_tip, h_tip1, atol=1e-10)


@pytest.mark.parametrize("known_base", [False, True])
def test_factor_whitens_the_residual(known_base: bool) -> None:
    bending, j, base, x, tip = _point(7, free=True)
    xk, tk, bk = gtsam.symbol("x", 0), gtsam.symbol("t", 1), gtsam.symbol("t", 0)
    factor = segment_tie_factor(xk, tk, base.matrix() if known_base else bk, bending, j, SIGMAS)
    values = gtsam.Values()
    values.insert(xk, x)
    values.insert(tk, tip)
    if not known_base:
        values.insert(bk, base)
    assert len(factor.keys()) == (2 if known_base else 3)
    r = segment_tie_residual(base, x, tip, bending, j, jacobians=False)[0]
    np.testing.assert_allclose(factor.error(values), 0.5 * np.sum((r / SIGMAS) ** 2), rtol=1e-10)
    # The linearisation's blocks are the whitened Jacobians.
    _, h_base, h_x, h_tip = segment_tie_residual(base, x, tip, bending, j)
    A, _ = factor.linearize(values).jacobian()
    expected = np.hstack([h_x, h_tip] + ([] if known_base else [h_base])) / SIGMAS[:, None]
    np.testing.assert_allclose(A, expected, atol=1e-9)


def test_bad_arguments_are_refused() -> None:
    bending = _bending(True)
    with pytest.raises(ValueError, match="segment 3"):
        segment_tie_factor(0, 1, np.eye(4), bending, 3, 0.01)
    with pytest.raises(ValueError, match="dimension 3"):
        segment_tie_factor(0, 1, np.eye(4), bending, 0, gtsam.noiseModel.Isotropic.Sigma(3, 1.0))
    with pytest.raises(ValueError, match="expected 1 or 6"):
        segment_tie_factor(0, 1, np.eye(4), bending, 0, [0.1, math.nan])
