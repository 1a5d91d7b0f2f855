"""The projection factor over tip poses (model error as noise): its pose derivatives against
central differences, its reduced system against the joint-space factor's by the chain rule, the
gtsam factor's linearisation, and that it solves tips from a perturbed start."""

from __future__ import annotations

import math

import gtsam
import numpy as np
import pytest
import scipy.linalg
from helpers import factor_hessian, random_pose
from hypothesis import given, settings
from hypothesis import strategies as st

from apcc_graph import Robot, Segment, TipCamera
from apcc_graph.factors.camera_chain import CameraChain, camera_poses
from apcc_graph.factors.keys import tip_key
from apcc_graph.factors.projection import build_observations
from apcc_graph.factors.reduced_system import reduced_system
from apcc_graph.factors.tip_projection import (
    GENERATORS,
    TipProjectionFactor,
    tip_camera_poses,
)
from apcc_graph.model.parameterisation import Bending
from apcc_graph.simulation.simulator import simulate

SEGMENTS = (Segment(0.3, k=0.2, delta_max=0.1, theta_max=1.0),
            Segment(0.3, k=0.3, delta_max=-0.05, theta_max=1.0))


@pytest.fixture(scope="module")
def rig():
    """A two-segment robot with a tilted, shifted lens on each tip, bending in 3-D; its
    sequence, the frame vectors of its truth, and each camera's observations."""
    rng = np.random.default_rng(3)
    cam = TipCamera(500.0, 490.0, 320.0, 240.0, 640, 480, distortion=(-0.2, 0.05, 1e-3, -1e-3),
                    tip_T_cam=random_pose(rng, 0.2, 0.02))
    robot = Robot(SEGMENTS, [cam, cam])
    seq = simulate(robot, 8, noise_px=1.0, seed=5, scene="room", n_points=300, spatial=True,
                   fps=5.0).sequence
    bending = Bending.free(robot.segments)
    x = bending.vector(seq.thetas, seq.psis)
    obs = []
    for c in (0, 1):
        tracks = seq.tracks[c]
        xy = cam.normalized(tracks.uv)
        obs.append(build_observations(c, tracks.frames, tracks.track_ids, xy,
                                      cam.pixel_jacobian(xy)))
    return robot, seq, bending, x, obs


def _tips(bending: Bending, x: np.ndarray, c: int) -> tuple[np.ndarray, np.ndarray]:
    """Segment ``c``'s tip poses ``(F, 4, 4)`` and their body twists ``(F, P, 6)`` in the
    frame vectors' components (``T^-1 dT/dx``, gtsam's order)."""
    T, dT = camera_poses(x[:, :bending.width * (c + 1)], bending.head(c + 1), np.eye(4))
    body = np.linalg.inv(T)[:, None] @ dT
    twist = np.stack([body[..., 2, 1], body[..., 0, 2], body[..., 1, 0],
                      body[..., 0, 3], body[..., 1, 3], body[..., 2, 3]], axis=-1)
    return T, twist


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31 - 1))
def test_camera_pose_derivatives_match_central_differences(seed: int) -> None:
    rng = np.random.default_rng(seed)
    tips = np.stack([random_pose(rng, 1.0, 0.5) for _ in range(3)])
    mount = random_pose(rng, 0.3, 0.05)
    poses, d = tip_camera_poses(tips, mount)
    np.testing.assert_allclose(poses, tips @ mount)
    h = 1e-6
    for i in range(6):
        step = np.zeros(6)
        step[i] = h
        plus = np.stack([(gtsam.Pose3(T).retract(step)).matrix() for T in tips]) @ mount
        minus = np.stack([(gtsam.Pose3(T).retract(-step)).matrix() for T in tips]) @ mount
        np.testing.assert_allclose(d[:, i], (plus - minus) / (2 * h), atol=1e-8)


def test_generators_follow_gtsams_tangent_order() -> None:
    xi = np.array([0.1, -0.2, 0.3, 0.4, -0.5, 0.6])
    hat = np.einsum("i,iab->ab", xi, GENERATORS)
    np.testing.assert_allclose(gtsam.Pose3.Expmap(xi).matrix(), scipy.linalg.expm(hat),
                               atol=1e-12)


@pytest.mark.parametrize("cam", [0, 1])
def test_reduced_system_is_the_joint_spaces_by_the_chain_rule(rig, cam: int) -> None:
    """At tips on the model, the joint-space system is ``J^T H J`` of the tip system, with
    ``J`` each tip's body twists in the frame vector (its gradient ``J^T g``, same cost)."""
    robot, seq, bending, truth, obs = rig
    rng = np.random.default_rng(cam)
    x = truth + rng.normal(0.0, 0.01, truth.shape)
    mount = robot.cameras[cam].tip_T_cam
    chain = CameraChain(bending.head(cam + 1), mount, seq.world_T_base)
    first = int(obs[cam].frames.min())
    joint = reduced_system(obs[cam], chain, x[first:, :bending.width * (cam + 1)], first,
                           np.ones(len(obs[cam])))
    T, twist = _tips(bending, x, cam)
    factor = TipProjectionFactor(obs[cam], mount)
    tip = factor.system(T[first:])
    F, P = len(T) - first, twist.shape[1]
    J = np.zeros((6 * F, P * F))
    for f in range(F):
        J[6 * f:6 * f + 6, P * f:P * f + P] = twist[first + f].T
    scale = np.abs(joint.H).max()
    np.testing.assert_allclose(J.T @ tip.H @ J, joint.H, atol=1e-7 * scale)
    np.testing.assert_allclose(J.T @ tip.g, joint.g, atol=1e-7 * np.abs(joint.g).max())
    assert tip.cost == pytest.approx(joint.cost, rel=1e-9)
    np.testing.assert_allclose(tip.points, joint.points, atol=1e-6)


def test_gradient_is_half_the_derivative_of_the_retriangulated_cost(rig) -> None:
    robot, seq, bending, truth, obs = rig
    T, _ = _tips(bending, truth, 1)
    factor = TipProjectionFactor(obs[1], robot.cameras[1].tip_T_cam)
    out = factor.system(T)
    g = out.g
    h, rng = 1e-6, np.random.default_rng(1)
    for column in rng.choice(len(g), 8, replace=False):
        f, i = divmod(int(column), 6)
        step = np.zeros(6)
        step[i] = h
        costs = []
        for sign in (1.0, -1.0):
            moved = T.copy()
            moved[f] = gtsam.Pose3(T[f]).retract(sign * step).matrix()
            fresh = TipProjectionFactor(obs[1], robot.cameras[1].tip_T_cam)
            fresh.points = out.points  # the triangulation starts at the optimum's points
            costs.append(fresh.system(moved, jacobians=False).cost)
        assert g[column] == pytest.approx((costs[0] - costs[1]) / (4 * h), rel=0,
                                          abs=1e-5 * np.abs(g).max())


def test_factor_linearises_to_its_reduced_system(rig) -> None:
    robot, seq, bending, truth, obs = rig
    T, _ = _tips(bending, truth + 0.005, 1)
    factor = TipProjectionFactor(obs[1], robot.cameras[1].tip_T_cam)
    values = gtsam.Values()
    for f in range(len(T)):
        values.insert(tip_key(f, 1), gtsam.Pose3(T[f]))
    gtsam_factor = factor.factor()
    assert list(gtsam_factor.keys()) == [tip_key(f, 1) for f in range(len(T))]
    want = TipProjectionFactor(obs[1], robot.cameras[1].tip_T_cam).system(T)
    info, eta = factor_hessian(gtsam_factor, values)
    scale = np.abs(want.H).max()
    np.testing.assert_allclose(info, want.H, atol=1e-9 * scale)
    np.testing.assert_allclose(eta, -want.g, atol=1e-8 * np.abs(want.g).max())
    assert gtsam_factor.error(values) == pytest.approx(0.5 * want.cost, rel=1e-9)


def test_tips_are_solved_from_a_perturbed_start(rig) -> None:
    """Two tips held by tight priors fix the gauge; the rest start a few degrees and
    centimetres off and come back to the truth (noise-free rows)."""
    robot, seq, bending, truth, obs = rig
    T, _ = _tips(bending, truth, 0)
    clean = simulate(robot, 8, noise_px=0.0, seed=5, scene="room", n_points=300, spatial=True,
                     fps=5.0).sequence
    cam = robot.cameras[0]
    tracks = clean.tracks[0]
    xy = cam.normalized(tracks.uv)
    rows = build_observations(0, tracks.frames, tracks.track_ids, xy, cam.pixel_jacobian(xy))
    graph = gtsam.NonlinearFactorGraph()
    graph.add(TipProjectionFactor(rows, cam.tip_T_cam).factor())
    tight = gtsam.noiseModel.Isotropic.Sigma(6, 1e-6)
    for f in (0, len(T) - 1):
        graph.add(gtsam.PriorFactorPose3(tip_key(f, 0), gtsam.Pose3(T[f]), tight))
    rng = np.random.default_rng(2)
    start = gtsam.Values()
    for f in range(len(T)):
        off = np.concatenate([rng.normal(0, math.radians(2.0), 3), rng.normal(0, 0.02, 3)])
        start.insert(tip_key(f, 0), gtsam.Pose3(T[f]).retract(off))
    assert graph.error(start) > 1e3
    result = gtsam.LevenbergMarquardtOptimizer(graph, start).optimize()
    for f in range(len(T)):
        np.testing.assert_allclose(result.atPose3(tip_key(f, 0)).matrix(), T[f], atol=1e-5)
