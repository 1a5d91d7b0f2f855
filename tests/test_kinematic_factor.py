"""APCC kinematic factor (pose space): Jacobians against central differences, zero residual at
the truth, the CustomFactor against the numpy residual, convergence of small graphs."""

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
    _transform_and_twist,
    kinematic_factor,
    kinematic_noise,
    kinematic_residual,
)
from apcc_graph.model.kinematics import apcc_body_twists, apcc_transform

X = gtsam.symbol_shorthand.X  # poses
A = gtsam.symbol_shorthand.A  # angles

SEGMENTS = [
    Segment(0.5),
    Segment(0.3, k=0.2, delta_max=0.15, theta_max=1.0),
    Segment(0.25, k=0.35, delta_max=-0.3, theta_max=1.4),
]
SIGMAS = np.array([0.01, 0.02, 0.015, 0.002, 0.001, 0.003])


def pose(matrix: np.ndarray) -> gtsam.Pose3:
    return gtsam.Pose3(matrix)


def exact_tip(world_T_base: gtsam.Pose3, theta: float, segment: Segment,
              psi: float) -> gtsam.Pose3:
    return world_T_base.compose(pose(apcc_transform(theta, segment, psi)))


def random_point(seed: int, exact: bool) -> tuple[gtsam.Pose3, float, gtsam.Pose3, Segment, float]:
    """A random (base, theta, tip, segment, psi); the tip is off the kinematic pose unless exact."""
    rng = np.random.default_rng(seed)
    segment = SEGMENTS[seed % len(SEGMENTS)]
    base = pose(random_pose(rng, 1.0, 0.5))
    theta = float(rng.uniform(-segment.theta_max, segment.theta_max))
    psi = float(rng.uniform(-math.pi, math.pi))
    tip = exact_tip(base, theta, segment, psi)
    if not exact:
        tip = tip.compose(pose(random_pose(rng, 0.4, 0.1)))
    return base, theta, tip, segment, psi


def numerical_jacobians(base: gtsam.Pose3, theta: float, tip: gtsam.Pose3, segment: Segment,
                        psi: float, h: float = 1e-6) -> tuple[np.ndarray, ...]:
    """Central differences through the optimiser's retraction: ``T.retract(d)``, ``theta + d``."""

    def r(b: gtsam.Pose3, t: float, e: gtsam.Pose3) -> np.ndarray:
        return kinematic_residual(b, t, e, segment, psi, jacobians=False)[0]

    n_base, n_tip = np.zeros((6, 6)), np.zeros((6, 6))
    for i in range(6):
        d = np.zeros(6)
        d[i] = h
        n_base[:, i] = (r(base.retract(d), theta, tip) - r(base.retract(-d), theta, tip)) / (2 * h)
        n_tip[:, i] = (r(base, theta, tip.retract(d)) - r(base, theta, tip.retract(-d))) / (2 * h)
    n_theta = ((r(base, theta + h, tip) - r(base, theta - h, tip)) / (2 * h))[:, None]
    return n_base, n_theta, n_tip


def test_retract_is_the_right_exponential() -> None:
    """The Jacobian convention is ``T Exp(d)``; the optimiser steps with ``retract``: same map."""
    rng = np.random.default_rng(1)
    T = pose(random_pose(rng, 1.0, 0.5))
    d = rng.normal(0.0, 0.3, 6)
    np.testing.assert_allclose(T.retract(d).matrix(),
                               T.compose(gtsam.Pose3.Expmap(d)).matrix(), atol=1e-12)


@pytest.mark.parametrize("seed", range(9))
@pytest.mark.parametrize("exact", [False, True])
def test_jacobians_match_central_differences(seed: int, exact: bool) -> None:
    base, theta, tip, segment, psi = random_point(seed, exact)
    r, h_base, h_theta, h_tip = kinematic_residual(base, theta, tip, segment, psi)
    assert h_base is not None and h_theta is not None and h_tip is not None
    assert h_base.shape == (6, 6) and h_theta.shape == (6, 1) and h_tip.shape == (6, 6)
    if not exact:
        assert np.linalg.norm(r) > 0.1  # really off the kinematic pose: J_r^-1 is not I
    n_base, n_theta, n_tip = numerical_jacobians(base, theta, tip, segment, psi)
    np.testing.assert_allclose(h_base, n_base, atol=1e-8)
    np.testing.assert_allclose(h_theta, n_theta, atol=1e-8)
    np.testing.assert_allclose(h_tip, n_tip, atol=1e-8)


def test_jacobians_at_the_straight_segment() -> None:
    """theta = 0 (the straight segment) and psi = 0: no special case breaks the derivatives."""
    rng = np.random.default_rng(5)
    segment = SEGMENTS[1]
    base = pose(random_pose(rng, 1.0, 0.5))
    tip = exact_tip(base, 0.0, segment, 0.0).compose(pose(random_pose(rng, 0.2, 0.05)))
    _, h_base, h_theta, h_tip = kinematic_residual(base, 0.0, tip, segment)
    for analytic, numeric in zip((h_base, h_theta, h_tip),
                                 numerical_jacobians(base, 0.0, tip, segment, 0.0), strict=True):
        np.testing.assert_allclose(analytic, numeric, atol=1e-8)


@settings(max_examples=100, deadline=None)
@given(theta=st.floats(-1.0, 1.0), psi=st.floats(-math.pi, math.pi), which=st.integers(0, 2))
def test_scalar_twist_matches_apcc_body_twists(theta: float, psi: float, which: int) -> None:
    segment = SEGMENTS[which]
    T, xi = _transform_and_twist(theta, segment, psi)
    np.testing.assert_allclose(T, apcc_transform(theta, segment, psi), atol=1e-14)
    np.testing.assert_allclose(xi, apcc_body_twists(theta, segment, psi)[0], atol=1e-14)


@settings(max_examples=100, deadline=None)
@given(seed=st.integers(0, 2**31), theta=st.floats(-1.0, 1.0), psi=st.floats(-math.pi, math.pi))
def test_zero_residual_at_the_truth(seed: int, theta: float, psi: float) -> None:
    rng = np.random.default_rng(seed)
    segment = SEGMENTS[seed % 3]
    base = pose(random_pose(rng, 1.0, 0.5))
    tip = exact_tip(base, theta, segment, psi)
    r, *_ = kinematic_residual(base, theta, tip, segment, psi)
    np.testing.assert_allclose(r, 0.0, atol=1e-12)


def test_residual_is_the_log_of_the_pose_error() -> None:
    """Off the truth, r equals Log(tip^-1 base A) computed independently with 4x4 matrices."""
    base, theta, tip, segment, psi = random_point(4, exact=False)
    expected = gtsam.Pose3.Logmap(pose(np.linalg.inv(tip.matrix()) @ base.matrix()
                                       @ apcc_transform(theta, segment, psi)))
    r, *_ = kinematic_residual(base, theta, tip, segment, psi)
    np.testing.assert_allclose(r, expected, atol=1e-12)
    assert np.linalg.norm(r) > 0.1
    # A wrong angle, or a wrong bending plane, is seen by the residual.
    exact = exact_tip(base, theta, segment, psi)
    assert np.linalg.norm(kinematic_residual(base, theta + 0.01, exact, segment, psi)[0]) > 5e-3
    assert np.linalg.norm(kinematic_residual(base, theta, exact, segment, psi + 0.1)[0]) > 1e-3


def test_without_jacobians_returns_the_same_residual() -> None:
    base, theta, tip, segment, psi = random_point(2, exact=False)
    r, h_base, _, _ = kinematic_residual(base, theta, tip, segment, psi)
    r_only, *rest = kinematic_residual(base, theta, tip, segment, psi, jacobians=False)
    np.testing.assert_array_equal(r_only, r)
    assert h_base is not None and rest == [None, None, None]


@pytest.mark.parametrize("noise", ["sigmas", "scalar", "model"])
def test_custom_factor_matches_the_numpy_residual(noise: str) -> None:
    base, theta, tip, segment, psi = random_point(7, exact=False)
    sigmas = {"sigmas": SIGMAS, "scalar": np.full(6, 0.01), "model": SIGMAS}[noise]
    arg = {"sigmas": SIGMAS, "scalar": 0.01,
           "model": gtsam.noiseModel.Diagonal.Sigmas(SIGMAS)}[noise]
    factor = kinematic_factor(X(0), A(0), X(1), segment, arg, psi=psi)
    values = gtsam.Values()
    values.insert(X(0), base)
    values.insert(A(0), np.array([theta]))
    values.insert(X(1), tip)

    r, h_base, h_theta, h_tip = kinematic_residual(base, theta, tip, segment, psi)
    np.testing.assert_allclose(factor.unwhitenedError(values), r, atol=1e-14)
    assert factor.error(values) == pytest.approx(0.5 * np.sum((r / sigmas) ** 2), rel=1e-12)
    assert list(factor.keys()) == [X(0), A(0), X(1)]

    linear = factor.linearize(values)
    jac, rhs = linear.jacobian()  # whitened: [H_base H_theta H_tip] / sigma, -r / sigma
    expected = np.hstack([h_base, h_theta, h_tip]) / sigmas[:, None]
    np.testing.assert_allclose(jac, expected, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(rhs, -r / sigmas, rtol=1e-12, atol=1e-12)


def test_noise_arguments_are_checked() -> None:
    with pytest.raises(ValueError, match="expected 1 or 6"):
        kinematic_noise([0.1, 0.1, 0.1])
    with pytest.raises(ValueError, match="expected 1 or 6"):
        kinematic_noise(-0.1)
    with pytest.raises(ValueError, match="dimension 3"):
        kinematic_factor(X(0), A(0), X(1), SEGMENTS[0], gtsam.noiseModel.Unit.Create(3))


def optimise(graph: gtsam.NonlinearFactorGraph, initial: gtsam.Values) -> gtsam.Values:
    params = gtsam.LevenbergMarquardtParams()
    params.setRelativeErrorTol(1e-16)
    params.setAbsoluteErrorTol(1e-30)
    params.setMaxIterations(100)
    return gtsam.LevenbergMarquardtOptimizer(graph, initial, params).optimize()


def pose_error(a: gtsam.Pose3, b: gtsam.Pose3) -> float:
    return float(np.linalg.norm(gtsam.Pose3.Logmap(a.between(b))))


@pytest.mark.parametrize("which", range(3))
def test_convergence_recovers_the_angle_between_known_poses(which: int) -> None:
    """Priors on base and tip, angle unknown: LM from a perturbed start finds the true angle."""
    rng = np.random.default_rng(10 + which)
    segment = SEGMENTS[which]
    theta, psi = 0.7 * segment.theta_max, 0.4 * which - 0.3
    base = pose(random_pose(rng, 1.0, 0.5))
    tip = exact_tip(base, theta, segment, psi)
    prior = gtsam.noiseModel.Isotropic.Sigma(6, 1e-3)
    graph = gtsam.NonlinearFactorGraph()
    graph.add(gtsam.PriorFactorPose3(X(0), base, prior))
    graph.add(gtsam.PriorFactorPose3(X(1), tip, prior))
    graph.add(kinematic_factor(X(0), A(0), X(1), segment, SIGMAS, psi=psi))
    initial = gtsam.Values()
    initial.insert(X(0), base.retract(rng.normal(0.0, 0.05, 6)))
    initial.insert(A(0), np.array([theta - 0.4]))
    initial.insert(X(1), tip.retract(rng.normal(0.0, 0.05, 6)))
    assert graph.error(initial) > 1.0

    result = optimise(graph, initial)
    assert abs(result.atVector(A(0))[0] - theta) < 1e-8
    assert pose_error(result.atPose3(X(0)), base) < 1e-8
    assert pose_error(result.atPose3(X(1)), tip) < 1e-8
    assert graph.error(result) < 1e-12


def test_convergence_recovers_the_tip_from_base_and_angle() -> None:
    """Priors on base and angle, tip unknown: the optimum is the forward kinematics."""
    rng = np.random.default_rng(20)
    segment = SEGMENTS[2]
    theta, psi = -0.9, 1.1
    base = pose(random_pose(rng, 1.0, 0.5))
    tip = exact_tip(base, theta, segment, psi)
    graph = gtsam.NonlinearFactorGraph()
    graph.add(gtsam.PriorFactorPose3(X(0), base, gtsam.noiseModel.Isotropic.Sigma(6, 1e-3)))
    graph.add(gtsam.PriorFactorVector(A(0), np.array([theta]),
                                      gtsam.noiseModel.Isotropic.Sigma(1, 1e-3)))
    graph.add(kinematic_factor(X(0), A(0), X(1), segment, SIGMAS, psi=psi))
    initial = gtsam.Values()
    initial.insert(X(0), base)
    initial.insert(A(0), np.array([theta + 0.3]))
    initial.insert(X(1), tip.retract(rng.normal(0.0, 0.3, 6)))
    assert pose_error(initial.atPose3(X(1)), tip) > 0.1

    result = optimise(graph, initial)
    assert abs(result.atVector(A(0))[0] - theta) < 1e-8
    assert pose_error(result.atPose3(X(1)), tip) < 1e-8


def test_three_segment_chain_recovers_every_pose() -> None:
    """base0 -> tip0 = base1 -> tip1 = base2 -> tip2; priors on the first base, the last tip and
    the angles; LM from perturbed poses recovers every intermediate pose."""
    rng = np.random.default_rng(30)
    thetas = [0.6, -0.8, 1.0]
    psis = [0.0, 0.9, -1.7]
    poses = [pose(random_pose(rng, 1.0, 0.5))]
    for theta, segment, psi in zip(thetas, SEGMENTS, psis, strict=True):
        poses.append(exact_tip(poses[-1], theta, segment, psi))

    prior = gtsam.noiseModel.Isotropic.Sigma(6, 1e-3)
    graph = gtsam.NonlinearFactorGraph()
    graph.add(gtsam.PriorFactorPose3(X(0), poses[0], prior))
    graph.add(gtsam.PriorFactorPose3(X(3), poses[3], prior))
    for j, (theta, segment, psi) in enumerate(zip(thetas, SEGMENTS, psis, strict=True)):
        graph.add(gtsam.PriorFactorVector(A(j), np.array([theta]),
                                          gtsam.noiseModel.Isotropic.Sigma(1, 1e-3)))
        graph.add(kinematic_factor(X(j), A(j), X(j + 1), segment, SIGMAS, psi=psi))

    initial = gtsam.Values()
    for j, p in enumerate(poses):
        initial.insert(X(j), p.retract(np.concatenate([rng.normal(0.0, 0.2, 3),
                                                       rng.normal(0.0, 0.05, 3)])))
    for j, theta in enumerate(thetas):
        initial.insert(A(j), np.array([theta + rng.normal(0.0, 0.1)]))
    assert min(pose_error(initial.atPose3(X(j)), poses[j]) for j in (1, 2)) > 0.05

    result = optimise(graph, initial)
    for j, p in enumerate(poses):
        assert pose_error(result.atPose3(X(j)), p) < 1e-8, j
    for j, theta in enumerate(thetas):
        assert abs(result.atVector(A(j))[0] - theta) < 1e-8, j
