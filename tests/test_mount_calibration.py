"""Mount calibration: the camera-pose derivatives in the mounting ``tip_T_cam`` (gtsam's Pose3
tangent), the reduced system's mount columns against numerical derivatives, the factor's
Pose3 block, and the batch that calibrates the mounts from known perturbed ones."""

from __future__ import annotations

import math
from dataclasses import replace

import gtsam
import numpy as np
import pytest
import test_projection_calibration as segment_calibration
from helpers import factor_hessian, random_pose
from hypothesis import given, settings
from hypothesis import strategies as st

from apcc_graph import Robot
from apcc_graph.estimation.batch import batch_estimate
from apcc_graph.estimation.model_calibration import (
    ModelCalibration,
    mount_change,
    mount_error,
)
from apcc_graph.estimation.options import BatchOptions
from apcc_graph.evaluation.sequence_bound import sequence_bound
from apcc_graph.factors.camera_chain import camera_poses, mount_derivatives
from apcc_graph.factors.keys import calibration_key, frame_key, mount_key
from apcc_graph.factors.projection import ProjectionFactor
from apcc_graph.factors.reduced_system import reduced_system
from apcc_graph.model.parameterisation import Bending
from apcc_graph.model.sequence import Sequence

# The lens robot and its short fast sequences are the segment-calibration tests'.
SEGMENTS, FAST = segment_calibration.SEGMENTS, segment_calibration.FAST
lens_robot = segment_calibration.lens_robot  # the fixture
_setup = segment_calibration._setup


def _moved(tip_T_cam: np.ndarray, xi: np.ndarray) -> np.ndarray:
    """``tip_T_cam . Exp(xi)`` (gtsam's retraction of a Pose3)."""
    return gtsam.Pose3(tip_T_cam).retract(np.asarray(xi, dtype=float)).matrix()


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), cam=st.integers(0, 2))
def test_mount_derivatives_match_central_differences(seed: int, cam: int) -> None:
    rng = np.random.default_rng(seed)
    n = cam + 1
    mount = random_pose(rng, 0.4, 0.05)
    bending = Bending.fixed(SEGMENTS[:n], rng.uniform(-math.pi, math.pi, n))
    x = rng.uniform(-1.0, 1.0, (3, n))
    base = np.stack([random_pose(rng, 1.0, 0.2) for _ in range(3)])
    poses = camera_poses(x, bending, mount, base, derivatives=False)[0]
    d = mount_derivatives(poses)
    assert d.shape == (3, 6, 4, 4)
    h = 1e-6
    for i in range(6):
        step = np.zeros(6)
        step[i] = h
        plus = camera_poses(x, bending, _moved(mount, step), base, False)[0]
        minus = camera_poses(x, bending, _moved(mount, -step), base, False)[0]
        np.testing.assert_allclose(d[:, i], (plus - minus) / (2 * h), atol=1e-8)


@pytest.mark.parametrize("calibration", [False, True])
def test_mount_gradient_is_half_the_derivative_of_the_retriangulated_cost(
        lens_robot: Robot, calibration: bool) -> None:
    """g's six mount entries (after the segment models' when both are calibrated) against
    central differences of the cost minimised over the points, along gtsam's retraction; the
    other blocks are those of the system without the mount."""
    cam = 2
    _, obs, chain, thetas = _setup(lens_robot, cam, 31)
    w = np.ones(len(obs))
    out = reduced_system(obs, chain, thetas, 0, w, calibration=calibration, mount=True)
    plain = reduced_system(obs, chain, thetas, 0, w, calibration=calibration)
    D1 = len(plain.g)
    assert out.H.shape == (D1 + 6,) * 2
    np.testing.assert_allclose(out.H[:D1, :D1], plain.H, rtol=0, atol=1e-9 * np.abs(plain.H).max())
    np.testing.assert_allclose(out.H, out.H.T, rtol=0, atol=1e-9 * np.abs(out.H).max())
    h = 1e-6
    numeric = np.zeros(6)
    for i in range(6):
        step = np.zeros(6)
        step[i] = h
        cost = [reduced_system(obs, chain.with_mount(_moved(chain.tip_T_cam, s)), thetas, 0, w,
                               out.points, jacobians=False).cost for s in (step, -step)]
        numeric[i] = (cost[0] - cost[1]) / (2 * h)
    np.testing.assert_allclose(out.g[D1:], 0.5 * numeric, rtol=0,
                               atol=1e-5 * np.abs(out.g[D1:]).max())


def test_mount_information_is_the_gauss_newton_curvature(lens_robot: Robot) -> None:
    """Noise-free data at the true angles: the mount rows of H are the central differences of
    the reduced gradient along the retraction."""
    cam = 1
    seq, obs, chain, _ = _setup(lens_robot, cam, 41, noise_px=0.0)
    w = np.ones(len(obs))
    out = reduced_system(obs, chain, seq.thetas[:, :2], 0, w, mount=True)
    assert out.cost < 1e-12
    D0 = len(out.g) - 6
    h = 1e-6
    for i in range(6):
        step = np.zeros(6)
        step[i] = h
        g = [reduced_system(obs, chain.with_mount(_moved(chain.tip_T_cam, s)),
                            seq.thetas[:, :2], 0, w, out.points, mount=True).g
             for s in (step, -step)]
        # The retraction moves the mount itself, so the gradient's mount rows are taken in
        # the moved tangent; at zero residual that first-order difference vanishes.
        np.testing.assert_allclose(out.H[:, D0 + i], (g[0] - g[1]) / (2 * h), rtol=0,
                                   atol=1e-4 * np.abs(out.H).max())


def test_factor_has_a_pose3_mount_block(lens_robot: Robot) -> None:
    cam = 1
    _, obs, chain, thetas = _setup(lens_robot, cam, 50)
    S = lens_robot.n_segments
    moved = _moved(chain.tip_T_cam, np.array([0.01, -0.02, 0.015, 0.003, -0.002, 0.004]))
    values = gtsam.Values()
    for f, t in enumerate(thetas):
        values.insert(frame_key(f), np.asarray(t, dtype=float))
    for j, s in enumerate(lens_robot.segments[:cam + 1]):
        values.insert(calibration_key(j), np.array([s.k, s.delta_max]))
    values.insert(mount_key(cam), gtsam.Pose3(moved))
    factor = ProjectionFactor(obs, chain, S, calibrate=True, mount=True).factor()
    F = len(thetas)
    assert list(factor.keys()) == ([frame_key(f) for f in range(F)]
                                   + [calibration_key(j) for j in range(cam + 1)]
                                   + [mount_key(cam)])
    want = reduced_system(obs, chain.with_mount(moved), thetas, 0, np.ones(len(obs)),
                          calibration=True, mount=True)
    info, eta = factor_hessian(factor, values)
    D0 = F * S
    index = np.concatenate([((np.arange(F) * S)[:, None] + np.arange(cam + 1)).ravel(),
                            D0 + np.arange(2 * (cam + 1) + 6)])
    scale = np.abs(want.H).max()
    np.testing.assert_allclose(info[np.ix_(index, index)], want.H, rtol=0, atol=1e-9 * scale)
    np.testing.assert_allclose(eta[index], -want.g, rtol=0, atol=1e-8 * np.abs(want.g).max())
    assert factor.error(values) == pytest.approx(0.5 * want.cost, rel=1e-9)


def test_model_calibration_round_trips_through_values(lens_robot: Robot) -> None:
    cal = ModelCalibration.of(lens_robot, True, [1, 2])
    assert cal.size == 2 * 3 + 12 and not cal.empty
    values = gtsam.Values()
    cal.insert(values)
    back = cal.read(values)
    np.testing.assert_allclose(back.segments, cal.segments)
    for (c, a), (d, b) in zip(back.mounts, cal.mounts, strict=True):
        assert c == d
        np.testing.assert_allclose(a, b, atol=1e-12)
    std = cal.sigmas_from(np.arange(cal.size, dtype=float))
    np.testing.assert_array_equal(std.segments, np.arange(6.0).reshape(3, 2))
    np.testing.assert_array_equal(std.mount_table(3)[2], np.arange(12.0, 18.0))
    assert np.isnan(std.mount_table(3)[0]).all()
    with pytest.raises(ValueError, match="segment 1 has no camera"):
        ModelCalibration.of(lens_robot, False, [0])


def test_mount_change_and_error_agree() -> None:
    rng = np.random.default_rng(3)
    given_ = random_pose(rng, 0.3, 0.05)
    xi = np.array([0.02, -0.01, 0.03, 0.004, 0.001, -0.002])
    found = _moved(given_, xi)
    np.testing.assert_allclose(mount_change(found, given_), xi, atol=1e-12)
    rot, pos = mount_error(found, given_)
    assert rot == pytest.approx(np.linalg.norm(xi[:3]), rel=1e-9)
    assert pos == pytest.approx(np.linalg.norm(gtsam.Pose3.Expmap(xi).translation()), rel=1e-9)


def _off_mounts(robot: Robot, seed: int, deg: float = 2.0, mm: float = 5.0) -> Robot:
    """``robot`` with every camera's mount turned by ``deg`` about a random axis and moved by
    ``mm`` in a random direction."""
    rng = np.random.default_rng(seed)
    cams = []
    for cam in robot.cameras:
        axis, way = rng.normal(size=3), rng.normal(size=3)
        turn = gtsam.Pose3(gtsam.Rot3.Expmap(axis / np.linalg.norm(axis) * math.radians(deg)),
                           way / np.linalg.norm(way) * mm * 1e-3)
        cams.append(None if cam is None else replace(cam, tip_T_cam=cam.tip_T_cam @ turn.matrix()))
    return Robot(robot.segments, cams)


@pytest.fixture(scope="module")
def robot() -> Robot:
    from test_batch_projection import ROBOT

    from apcc_graph.io.robot_file import load_robot

    return load_robot(ROBOT)


def test_batch_calibrates_perturbed_mounts_to_their_bound(robot: Robot) -> None:
    """Mounts off by 2 deg and 5 mm: without calibration a segment is far off; calibrating the
    mounts brings them back near the true-mount batch, every mount component within 4 of its
    Cramer-Rao bound (which its sigma matches) and closer than the robot file was where the
    images tell it."""
    from test_batch_projection import TRACK_FRAMES, room

    sim = room(robot, 120, seed=7)
    seq = sim.sequence
    wrong = Sequence(_off_mounts(robot, 1), seq.timestamps, seq.tracks, seq.world_T_base,
                     seq.thetas, seq.psis)
    start = dict(theta0=seq.thetas[0], initial=seq.thetas)
    true = batch_estimate(seq, **start, marginals=False)
    off = batch_estimate(wrong, **start, marginals=False)
    sigmas = (math.radians(5.0), 0.01)
    est = batch_estimate(wrong, **start, calibrate=True, calibration_sigmas=None,
                         mount_sigmas=sigmas)
    assert est.calibration_sigmas is None and est.mount_sigmas.shape == (3, 6)
    err_true, err_off = true.rms(seq.thetas), off.rms(seq.thetas)
    err = est.rms(seq.thetas)
    assert np.max(err_off / err_true) > 5.0, (np.degrees(err_off), np.degrees(err_true))
    assert np.all(err < 2.0 * err_true + math.radians(0.01)), (np.degrees(err),
                                                              np.degrees(err_true))
    bound = sequence_bound(sim, 1.0, max_track_frames=TRACK_FRAMES, mount_sigmas=sigmas)
    for c in range(3):
        xi = mount_change(est.robot.cameras[c].tip_T_cam, robot.cameras[c].tip_T_cam)
        assert np.all(np.abs(xi) < 4.0 * bound.mounts[c]), (c, xi / bound.mounts[c])
        np.testing.assert_allclose(est.mount_sigmas[c], bound.mounts[c], rtol=0.2)
        told = bound.mounts[c] < 0.3 * np.array([sigmas[0]] * 3 + [sigmas[1]] * 3)
        before = mount_change(wrong.robot.cameras[c].tip_T_cam, robot.cameras[c].tip_T_cam)
        assert np.linalg.norm(xi[told]) < np.linalg.norm(before[told])


def test_batch_options_refuse_calibrating_nothing() -> None:
    with pytest.raises(ValueError, match="calibrates nothing"):
        BatchOptions(calibrate=True, calibration_sigmas=None, mount_sigmas=None)
    with pytest.raises(ValueError, match="BatchOptions.mount_sigmas"):
        BatchOptions(calibrate=True, mount_sigmas=(0.1, -1.0))
    assert BatchOptions(calibrate=True).mount_sigmas == pytest.approx((math.radians(5), 0.01))
