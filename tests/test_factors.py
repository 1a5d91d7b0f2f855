"""Factors: Jacobians against numbers, zero residual at the truth, convergence from a perturbed
start, robust weights as gtsam weighs them, priors."""

from __future__ import annotations

import math
from pathlib import Path

import gtsam
import numpy as np
import pytest
from helpers import random_pose

from apcc_graph import Robot, Segment, TipCamera
from apcc_graph.factors.epipolar import epipolar_factor, epipolar_frame_factor, robust_weights
from apcc_graph.factors.epipolar_residual import epipolar_frame_residual, epipolar_residual
from apcc_graph.factors.priors import joint_limit_factor, joint_limit_residual, motion_prior
from apcc_graph.io.robot_file import load_robot
from apcc_graph.model.kinematics import apcc_transform, apcc_transform_derivative
from apcc_graph.model.scalar_kinematics import apcc_transform_scalar
from apcc_graph.simulation.simulator import simulate

ROBOT = Path(__file__).resolve().parents[1] / "data/robots/planar_three.toml"




@pytest.fixture(scope="module")
def mounted_robot() -> Robot:
    rng = np.random.default_rng(0)
    cam = TipCamera(500.0, 500.0, 320.0, 240.0, 640, 480, tip_T_cam=random_pose(rng, 0.2, 0.02))
    return Robot([Segment(0.3, k=0.2, delta_max=0.1, theta_max=1.0),
                  Segment(0.3, k=0.3, delta_max=-0.05, theta_max=1.0),
                  Segment(0.25)], [cam, cam, cam])


def test_scalar_kinematics_match_the_vectorised_functions() -> None:
    seg = Segment(0.4, k=0.3, delta_max=-0.2, theta_max=1.2)
    for theta, psi in [(0.0, 0.0), (0.7, 0.3), (-1.1, -2.0), (1e-9, 1.0)]:
        T, dT = apcc_transform_scalar(theta, seg, psi)
        np.testing.assert_allclose(T, apcc_transform(theta, seg, psi), atol=1e-15)
        np.testing.assert_allclose(dT, apcc_transform_derivative(theta, seg, psi)[0], atol=1e-15)


@pytest.mark.parametrize("cam", [0, 1, 2])
@pytest.mark.parametrize("moving_base", [False, True])
def test_epipolar_jacobians_match_central_differences(mounted_robot: Robot, cam: int,
                                                      moving_base: bool) -> None:
    sim = simulate(mounted_robot, 12, noise_px=0.5, seed=3 + cam, moving_base=moving_base)
    seq = sim.sequence
    a, b = 2, 7
    corr = seq.correspondences(cam, a, b)
    assert len(corr) > 20
    segs = mounted_robot.segments[: cam + 1]
    mount = mounted_robot.cameras[cam].tip_T_cam
    base_a = np.eye(4) if seq.world_T_base is None else seq.world_T_base[a]
    base_b = np.eye(4) if seq.world_T_base is None else seq.world_T_base[b]
    rng = np.random.default_rng(cam)
    th_a = list(seq.thetas[a, : cam + 1] + rng.normal(0, 0.02, cam + 1))
    th_b = list(seq.thetas[b, : cam + 1] + rng.normal(0, 0.02, cam + 1))
    args = (segs, mount, base_a, base_b, corr.f_a, corr.f_b, 1.0 / 500.0)
    r, ja, jb = epipolar_residual(th_a, th_b, *args)
    h = 1e-6
    for which, jac in (("a", ja), ("b", jb)):
        for j in range(cam + 1):
            plus = [list(th_a), list(th_b)]
            minus = [list(th_a), list(th_b)]
            idx = 0 if which == "a" else 1
            plus[idx][j] += h
            minus[idx][j] -= h
            num = (epipolar_residual(*plus, *args)[0]
                   - epipolar_residual(*minus, *args)[0]) / (2 * h)
            np.testing.assert_allclose(jac[:, j], num, rtol=1e-5, atol=1e-5 * np.abs(num).max())
    r_only, none_a, none_b = epipolar_residual(th_a, th_b, *args, jacobians=False)
    np.testing.assert_allclose(r_only, r, atol=1e-12)
    assert none_a is None and none_b is None


def test_zero_residual_at_the_truth() -> None:
    robot = load_robot(ROBOT)
    sim = simulate(robot, 10, noise_px=0.0, seed=5, moving_base=True)
    seq = sim.sequence
    for cam in range(3):
        corr = seq.correspondences(cam, 1, 6)
        r, _, _ = epipolar_residual(seq.thetas[1, : cam + 1], seq.thetas[6, : cam + 1],
                                    robot.segments[: cam + 1], robot.cameras[cam].tip_T_cam,
                                    seq.world_T_base[1], seq.world_T_base[6], corr.f_a,
                                    corr.f_b, 1.0 / 500.0)
        assert len(r) > 20 and np.max(np.abs(r)) < 1e-8


@pytest.mark.parametrize(("loss", "model"), [
    ("huber", gtsam.noiseModel.mEstimator.Huber.Create(1.345)),
    ("cauchy", gtsam.noiseModel.mEstimator.Cauchy.Create(1.345)),
])
def test_robust_weights_are_gtsams(loss: str, model) -> None:
    r = np.linspace(-8.0, 8.0, 161)
    np.testing.assert_allclose(robust_weights(r, loss, 1.345), [model.weight(x) for x in r],
                               rtol=1e-12)
    np.testing.assert_array_equal(robust_weights(r, "none", 1.345), np.ones_like(r))
    with pytest.raises(ValueError, match="robust loss"):
        robust_weights(r, "tukey", 1.0)


def test_factor_in_gtsam_linearises_to_the_weighted_jacobian() -> None:
    robot = load_robot(ROBOT)
    sim = simulate(robot, 8, noise_px=1.0, outlier_fraction=0.2, seed=6)
    seq = sim.sequence
    corr = seq.correspondences(1, 0, 4)
    keys_a, keys_b = [0, 1], [10, 11]
    th_a, th_b = seq.thetas[0, :2] + 0.01, seq.thetas[4, :2] - 0.01
    args = (robot.segments[:2], robot.cameras[1].tip_T_cam, np.eye(4), np.eye(4), corr.f_a,
            corr.f_b, 1.0 / 500.0)
    factor = epipolar_factor(keys_a, keys_b, *args, loss="huber", loss_scale=1.345,
                             compress=False)
    values = gtsam.Values()
    for k, t in zip(keys_a + keys_b, [*th_a, *th_b], strict=True):
        values.insert(k, np.array([t]))
    r, ja, jb = epipolar_residual(list(th_a), list(th_b), *args)
    sw = np.sqrt(robust_weights(r, "huber", 1.345))
    assert factor.error(values) == pytest.approx(0.5 * np.sum((sw * r) ** 2), rel=1e-12)
    A, _ = factor.linearize(values).jacobian()
    np.testing.assert_allclose(A, np.column_stack([ja, jb]) * sw[:, None], rtol=1e-12,
                               atol=1e-12)
    # Outliers are down-weighted: the largest residuals get the smallest weights.
    assert sw[np.argmax(np.abs(r))] < 0.5


def test_convergence_from_a_perturbed_start() -> None:
    robot = load_robot(ROBOT)
    sim = simulate(robot, 6, noise_px=0.0, seed=7)
    seq = sim.sequence
    graph = gtsam.NonlinearFactorGraph()
    noise = gtsam.noiseModel.Isotropic.Sigma(1, 1e-6)
    for i in range(3):  # frame 0 known exactly; frame 5 to be found
        graph.add(gtsam.PriorFactorVector(i, seq.thetas[0, i:i + 1], noise))
    for cam in range(3):
        corr = seq.correspondences(cam, 0, 5)
        graph.add(epipolar_factor(list(range(cam + 1)), [10 + j for j in range(cam + 1)],
                                  robot.segments[: cam + 1], robot.cameras[cam].tip_T_cam,
                                  np.eye(4), np.eye(4), corr.f_a, corr.f_b, 1.0 / 500.0))
    start = gtsam.Values()
    for i in range(3):
        start.insert(i, seq.thetas[0, i:i + 1])
        start.insert(10 + i, seq.thetas[5, i:i + 1] + math.radians(2.0))
    result = gtsam.LevenbergMarquardtOptimizer(graph, start).optimize()
    got = np.array([result.atVector(10 + i)[0] for i in range(3)])
    np.testing.assert_allclose(got, seq.thetas[5], atol=1e-8)


def test_joint_limit_and_motion_priors() -> None:
    assert joint_limit_residual(0.5, 1.0, 0.1) == (0.0, 0.0)
    r, d = joint_limit_residual(-1.2, 1.0, 0.1)
    assert r == pytest.approx(2.0) and d == pytest.approx(-10.0)
    factor = joint_limit_factor(3, 1.0, 0.1)
    values = gtsam.Values()
    values.insert(3, np.array([1.3]))
    assert factor.error(values) == pytest.approx(0.5 * 3.0**2)
    A, _ = factor.linearize(values).jacobian()
    assert A[0, 0] == pytest.approx(10.0)
    prior = motion_prior(1, 2, sigma_rate=0.5, dt=0.04)
    values.insert(1, np.array([0.2]))
    values.insert(2, np.array([0.3]))
    assert prior.error(values) == pytest.approx(0.5 * (0.1 / (0.5 * math.sqrt(0.04))) ** 2)


# ---------------------------------------------------------------- one camera, several pairs
def _frame_setup(robot: Robot, cam: int, seed: int, moving_base: bool = False):
    sim = simulate(robot, 14, noise_px=1.0, outlier_fraction=0.1, seed=seed,
                   moving_base=moving_base)
    seq = sim.sequence
    b, gaps = 12, (1, 4, 9)
    corr = [seq.correspondences(cam, b - g, b) for g in gaps]
    assert all(len(c) > 20 for c in corr)
    base = (lambda f: np.eye(4)) if seq.world_T_base is None else (lambda f: seq.world_T_base[f])
    args = dict(segments=robot.segments[: cam + 1], tip_T_cam=robot.cameras[cam].tip_T_cam,
                world_T_base_b=base(b), world_T_base_a=[base(b - g) for g in gaps],
                f_a=[c.f_a for c in corr], f_b=[c.f_b for c in corr])
    return seq, b, gaps, args


@pytest.mark.parametrize("cam", [0, 2])
@pytest.mark.parametrize("moving_base", [False, True])
def test_frame_residual_stacks_the_pair_residuals(mounted_robot: Robot, cam: int,
                                                  moving_base: bool) -> None:
    seq, b, gaps, args = _frame_setup(mounted_robot, cam, 11 + cam, moving_base)
    n = cam + 1
    th_b = seq.thetas[b, :n] + 0.003
    th_a = [seq.thetas[b - g, :n] - 0.002 * g for g in gaps]
    res = epipolar_frame_residual(th_b, th_a, sigma=[1e-3, 2e-3, 3e-3], **args)
    for p, _g in enumerate(gaps):
        r, ja, jb = epipolar_residual(th_a[p], th_b, args["segments"], args["tip_T_cam"],
                                      args["world_T_base_a"][p], args["world_T_base_b"],
                                      args["f_a"][p], args["f_b"][p], [1e-3, 2e-3, 3e-3][p])
        rows = slice(res.rows[p], res.rows[p + 1])
        np.testing.assert_allclose(res.r[rows], r, rtol=1e-10, atol=1e-10)
        np.testing.assert_allclose(res.J_a[p], ja, rtol=1e-9, atol=1e-8)
        np.testing.assert_allclose(res.J_b[rows], jb, rtol=1e-9, atol=1e-8)


@pytest.mark.parametrize("cam", [0, 1, 2])
def test_calibration_jacobians_match_central_differences(mounted_robot: Robot,
                                                         cam: int) -> None:
    seq, b, gaps, args = _frame_setup(mounted_robot, cam, 21 + cam, moving_base=True)
    n = cam + 1
    th_b = list(seq.thetas[b, :n] + 0.01)
    th_a = [list(seq.thetas[b - g, :n] - 0.01) for g in gaps]
    res = epipolar_frame_residual(th_b, th_a, sigma=1e-3, calibration=True, **args)
    base = dict(args)
    segs = list(args["segments"])
    h = 1e-6
    for j in range(n):
        for name, column in (("k", res.J_k[:, j]), ("delta_max", res.J_delta[:, j])):
            out = []
            for sign in (1.0, -1.0):
                s = segs[j]
                value = getattr(s, name) + sign * h
                moved = Segment(s.length, value if name == "k" else s.k,
                                value if name == "delta_max" else s.delta_max, s.theta_max)
                base["segments"] = segs[:j] + [moved] + segs[j + 1:]
                out.append(epipolar_frame_residual(th_b, th_a, sigma=1e-3, jacobians=False,
                                                   **base).r)
            numeric = (out[0] - out[1]) / (2 * h)
            scale = np.max(np.abs(numeric))
            assert scale > 1e-3, f"{name} of segment {j} should move the residual"
            np.testing.assert_allclose(column, numeric, atol=2e-5 * scale + 1e-6)
    # Calibration does not change the angle Jacobians.
    plain = epipolar_frame_residual(th_b, th_a, sigma=1e-3, **args)
    np.testing.assert_allclose(res.J_b, plain.J_b, rtol=1e-12, atol=1e-12)


def _values(keys_values: dict[int, float]) -> gtsam.Values:
    values = gtsam.Values()
    for k, v in keys_values.items():
        values.insert(k, np.array([v]))
    return values


@pytest.mark.parametrize("calibrate", [False, True])
def test_compressed_factor_gives_the_same_system_and_error(mounted_robot: Robot,
                                                           calibrate: bool) -> None:
    cam = 2
    seq, b, gaps, args = _frame_setup(mounted_robot, cam, 31)
    keys_b = [100, 101, 102]
    keys_a = [[10 * g, 10 * g + 1, 10 * g + 2] for g in gaps]
    cal = [(200 + 2 * j, 201 + 2 * j) for j in range(3)] if calibrate else None
    kv = {k: float(t) for k, t in zip(keys_b, seq.thetas[b] + 0.004, strict=True)}
    for ks, g in zip(keys_a, gaps, strict=True):
        kv.update({k: float(t) for k, t in zip(ks, seq.thetas[b - g] - 0.003, strict=True)})
    if cal:
        for (kk, kd), s in zip(cal, mounted_robot.segments, strict=True):
            kv[kk], kv[kd] = s.k + 0.01, s.delta_max - 0.01
    values = _values(kv)
    full = epipolar_frame_factor(keys_b, keys_a, sigma=2e-3, compress=False,
                                 calibration_keys=cal, **args)
    small = epipolar_frame_factor(keys_b, keys_a, sigma=2e-3, compress=True,
                                  calibration_keys=cal, **args)
    assert small.dim() == len(small.keys()) + 1 < full.dim()
    assert small.error(values) == pytest.approx(full.error(values), rel=1e-10)
    ordering = gtsam.Ordering()
    for k in small.keys():
        ordering.push_back(k)
    g_full, g_small = gtsam.GaussianFactorGraph(), gtsam.GaussianFactorGraph()
    g_full.push_back(full.linearize(values))
    g_small.push_back(small.linearize(values))
    info_full, eta_full = g_full.hessian(ordering)
    info_small, eta_small = g_small.hessian(ordering)
    np.testing.assert_allclose(info_small, info_full, rtol=1e-9, atol=1e-9 * np.abs(
        info_full).max())
    np.testing.assert_allclose(eta_small, eta_full, rtol=1e-9, atol=1e-9 * np.abs(
        eta_full).max())
    # Away from the linearisation point (no Jacobians asked), the error is still exact.
    kv2 = {k: v + 0.001 for k, v in kv.items()}
    assert small.error(_values(kv2)) == pytest.approx(full.error(_values(kv2)), rel=1e-10)


def test_factor_memo_answers_repeats_and_notices_new_points(mounted_robot: Robot,
                                                            monkeypatch) -> None:
    import apcc_graph.factors.epipolar as module

    seq, b, gaps, args = _frame_setup(mounted_robot, 1, 41)
    keys_b, keys_a = [100, 101], [[10 * g, 10 * g + 1] for g in gaps]
    kv = {k: float(t) for k, t in zip(keys_b, seq.thetas[b, :2], strict=True)}
    for ks, g in zip(keys_a, gaps, strict=True):
        kv.update({k: float(t) for k, t in zip(ks, seq.thetas[b - g, :2], strict=True)})
    factor = epipolar_frame_factor(keys_b, keys_a, sigma=1e-3, **args)
    calls = []
    real = module.epipolar_frame_residual
    monkeypatch.setattr(module, "epipolar_frame_residual",
                        lambda *a, **k: calls.append(1) or real(*a, **k))
    values = _values(kv)
    first = factor.linearize(values)
    again = factor.linearize(values)
    assert len(calls) == 1
    np.testing.assert_array_equal(first.jacobian()[0], again.jacobian()[0])
    kv[100] += 1e-4
    moved = factor.linearize(_values(kv))
    assert len(calls) == 2
    assert not np.allclose(moved.jacobian()[1], first.jacobian()[1])


def test_calibration_variables_converge_from_the_robot_files_values() -> None:
    """Noise-free data from segments whose k and delta_max differ from the robot file's: with
    the angles held at the truth, the calibration variables converge to the true values."""
    robot = load_robot(ROBOT)
    truth = [Segment(s.length, s.k + 0.03, s.delta_max + math.radians(3.0), s.theta_max)
             for s in robot.segments]
    seq = simulate(robot, 30, noise_px=0.0, seed=8, truth_segments=truth).sequence
    graph = gtsam.NonlinearFactorGraph()
    start = gtsam.Values()
    tight = gtsam.noiseModel.Isotropic.Sigma(1, 1e-9)
    n_seg = robot.n_segments
    for f in range(seq.n_frames):
        for i in range(n_seg):
            key = f * n_seg + i
            graph.add(gtsam.PriorFactorVector(key, seq.thetas[f, i:i + 1], tight))
            start.insert(key, seq.thetas[f, i:i + 1])
    cal = [(gtsam.symbol("k", i), gtsam.symbol("d", i)) for i in range(n_seg)]
    for (k_key, d_key), seg in zip(cal, robot.segments, strict=True):
        start.insert(k_key, np.array([seg.k]))
        start.insert(d_key, np.array([seg.delta_max]))
        # Weak priors around the robot file's values, as the smoother uses (0 < k < 0.5).
        graph.add(gtsam.PriorFactorVector(k_key, np.array([seg.k]),
                                          gtsam.noiseModel.Isotropic.Sigma(1, 0.1)))
        graph.add(gtsam.PriorFactorVector(d_key, np.array([seg.delta_max]),
                                          gtsam.noiseModel.Isotropic.Sigma(1, 0.2)))
    for cam in range(n_seg):
        for b in range(5, seq.n_frames):
            corr = [seq.correspondences(cam, b - g, b) for g in (1, 5)]
            graph.add(epipolar_frame_factor(
                [b * n_seg + j for j in range(cam + 1)],
                [[(b - g) * n_seg + j for j in range(cam + 1)] for g in (1, 5)],
                robot.segments[: cam + 1], robot.cameras[cam].tip_T_cam, np.eye(4),
                [np.eye(4)] * 2, [c.f_a for c in corr], [c.f_b for c in corr], 1.0 / 500.0,
                loss="none", calibration_keys=cal[: cam + 1]))
    result = gtsam.LevenbergMarquardtOptimizer(graph, start).optimize()
    # delta_max turns the tip (the relative rotation between frames): well observed. k only
    # moves the tip along the chord, which the scale-free epipolar geometry sees weakly: it
    # moves toward the truth but the weak prior still holds it back. Measured errors:
    # delta_max 1e-4, 1e-4, 1e-2 rad; k 0.010, 0.005, 0.030 (from 0.03 each).
    for (k_key, d_key), seg, file in zip(cal, truth, robot.segments, strict=True):
        k, d = result.atVector(k_key)[0], result.atVector(d_key)[0]
        assert abs(d - seg.delta_max) < 0.25 * abs(file.delta_max - seg.delta_max)
        assert abs(k - seg.k) <= abs(file.k - seg.k) + 1e-9
    errors_d = [abs(result.atVector(d)[0] - s.delta_max) for (_, d), s in zip(cal, truth,
                                                                              strict=True)]
    assert max(errors_d[:2]) < 1e-3
