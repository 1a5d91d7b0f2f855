"""The generalized epipolar factor: zero at the truth, its Jacobians against central
differences (fixed planes and bending vectors, every camera), zero columns above the camera,
a small graph of a user's that recovers a frame, and clear errors."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest
from helpers import bearings_between, random_pose
from hypothesis import given, settings
from hypothesis import strategies as st

from apcc_graph import Segment
from apcc_graph.factors.camera_chain import CameraChain
from apcc_graph.factors.epipolar import epipolar_factor, epipolar_residual
from apcc_graph.factors.keys import frame_key
from apcc_graph.model.parameterisation import Bending

SEGMENTS = (Segment(0.3, k=0.2, delta_max=0.1, theta_max=1.5),
            Segment(0.3, k=0.3, delta_max=-0.05, theta_max=1.5),
            Segment(0.25, k=0.25, delta_max=0.03, theta_max=1.5))


def _setup(rng: np.random.Generator, cam: int, free: bool, n: int = 12):
    """A camera on segment ``cam`` of a 3-segment robot with a moving base, two frames'
    vectors, and bearings of points 1-3 m in front of the camera at frame a, seen from both
    frames without noise."""
    full = Bending.free(SEGMENTS) if free else Bending.fixed(SEGMENTS, rng.uniform(-1, 1, 3))
    part = Bending.free(SEGMENTS[:cam + 1]) if free else Bending.fixed(
        SEGMENTS[:cam + 1], full.planes[:cam + 1])
    bases = np.stack([random_pose(rng, 0.1, 0.05) for _ in range(8)])
    chain = CameraChain(part, random_pose(rng, 0.3, 0.02), bases, frame0=2)
    x_a = rng.uniform(-0.8, 0.8, full.dim)
    x_b = x_a + rng.normal(0.0, 0.15, full.dim)
    a, b = 3, 6
    local = np.column_stack([rng.uniform(-0.5, 0.5, (n, 2)), rng.uniform(1.0, 3.0, n)])
    f_a, f_b = bearings_between(chain, x_a, x_b, a, b, local)
    return chain, full.dim, x_a, x_b, a, b, f_a, f_b


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), cam=st.integers(0, 2), free=st.booleans())
def test_zero_at_the_truth_and_jacobians_match_central_differences(seed: int, cam: int,
                                                                   free: bool) -> None:
    rng = np.random.default_rng(seed)
    chain, dim, x_a, x_b, a, b, f_a, f_b = _setup(rng, cam, free)
    e, _, _ = epipolar_residual(x_a, x_b, chain, a, b, f_a, f_b, dim, jacobians=False)
    assert np.max(np.abs(e)) < 1e-9
    # away from the truth the errors are of the size of the perturbation
    y_a, y_b = x_a + rng.normal(0.0, 0.05, dim), x_b + rng.normal(0.0, 0.05, dim)
    e, H_a, H_b = epipolar_residual(y_a, y_b, chain, a, b, f_a, f_b, dim)
    assert H_a.shape == H_b.shape == (len(f_a), dim)
    assert np.max(np.abs(e)) > 1e-4
    h = 1e-6
    for which, H in ((0, H_a), (1, H_b)):
        for p in range(dim):
            step = np.zeros(dim)
            step[p] = h
            args = [(y_a + step, y_b), (y_a - step, y_b)] if which == 0 else \
                [(y_a, y_b + step), (y_a, y_b - step)]
            plus = epipolar_residual(*args[0], chain, a, b, f_a, f_b, dim, False)[0]
            minus = epipolar_residual(*args[1], chain, a, b, f_a, f_b, dim, False)[0]
            np.testing.assert_allclose(H[:, p], (plus - minus) / (2 * h), atol=1e-6,
                                       err_msg=f"frame {'ab'[which]}, component {p}")
    # the camera does not depend on the segments above its own
    width = 2 if free else 1
    assert not H_a[:, width * (cam + 1):].any() and not H_b[:, width * (cam + 1):].any()


def test_a_users_graph_recovers_a_frame_from_its_epipolar_factors() -> None:
    """Frame a known (a tight prior), frame b started 0.1 rad off in every angle: the three
    cameras' epipolar factors bring it back to the truth, and the factor's error at the
    truth is zero."""
    rng = np.random.default_rng(11)
    full = Bending.fixed(SEGMENTS)
    x_a = np.array([0.4, -0.3, 0.5])
    x_b = np.array([0.55, -0.1, 0.3])
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    truth = gtsam.Values()
    for cam in range(3):
        chain = CameraChain(Bending.fixed(SEGMENTS[:cam + 1]), random_pose(rng, 0.3, 0.02),
                            None)
        local = np.column_stack([rng.uniform(-1.0, 1.0, (30, 2)), rng.uniform(1.0, 3.0, 30)])
        f_a, f_b = bearings_between(chain, x_a, x_b, 0, 1, local)
        graph.add(epipolar_factor(0, 1, chain, 2.0 * f_a, f_b, 1e-3, full.dim))  # any length
    graph.add(gtsam.PriorFactorVector(frame_key(0), x_a, gtsam.noiseModel.Isotropic.Sigma(3, 1e-6)))
    truth.insert(frame_key(0), x_a)
    truth.insert(frame_key(1), x_b)
    assert graph.error(truth) < 1e-12
    values.insert(frame_key(0), x_a)
    values.insert(frame_key(1), x_b + 0.1)
    assert graph.error(values) > 1.0
    result = gtsam.LevenbergMarquardtOptimizer(graph, values).optimize()
    np.testing.assert_allclose(result.atVector(frame_key(1)), x_b, atol=1e-6)


def test_bad_input_is_named() -> None:
    rng = np.random.default_rng(2)
    chain = CameraChain(Bending.fixed(SEGMENTS[:1]), np.eye(4), None)
    f = rng.normal(size=(4, 3))
    with pytest.raises(ValueError, match="two frames"):
        epipolar_factor(3, 3, chain, f, f, 1e-3, 3)
    with pytest.raises(ValueError, match="positive noise"):
        epipolar_factor(0, 1, chain, f, f, 0.0, 3)
    with pytest.raises(ValueError, match="no correspondence"):
        epipolar_factor(0, 1, chain, np.zeros((0, 3)), np.zeros((0, 3)), 1e-3, 3)
    with pytest.raises(ValueError, match="expected the same"):
        epipolar_factor(0, 1, chain, f, f[:3], 1e-3, 3)
