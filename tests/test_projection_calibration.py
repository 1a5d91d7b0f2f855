"""Self-calibration columns of the projection factor: the camera-pose derivatives in each
segment's k and delta_max, the reduced system's calibration blocks against a dense numerical
Schur complement, and the gtsam factor's Jacobian blocks on the calibration keys."""

from __future__ import annotations

import math

import gtsam
import numpy as np
import pytest
from helpers import factor_hessian, random_pose
from hypothesis import given, settings
from hypothesis import strategies as st

from apcc_graph import Robot, Segment, TipCamera
from apcc_graph.factors.camera_chain import CameraChain, camera_poses
from apcc_graph.factors.keys import calibration_key, frame_key
from apcc_graph.factors.projection import ProjectionFactor, build_observations, calibrated
from apcc_graph.factors.reduced_system import reduced_system
from apcc_graph.model.parameterisation import Bending
from apcc_graph.simulation.simulator import simulate

SEGMENTS = (Segment(0.3, k=0.2, delta_max=0.1, theta_max=1.0),
            Segment(0.3, k=0.3, delta_max=-0.05, theta_max=1.0),
            Segment(0.25, k=0.25, delta_max=0.03, theta_max=1.0))
FAST = 5.0  # fps: enough parallax in a dozen frames


def _with(segments, j: int, dk: float, dd: float) -> tuple[Segment, ...]:
    out = list(segments)
    s = out[j]
    out[j] = Segment(s.length, s.k + dk, s.delta_max + dd, s.theta_max)
    return tuple(out)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), free=st.booleans(), cam=st.integers(0, 2))
def test_calibration_pose_derivatives_match_central_differences(seed: int, free: bool,
                                                                cam: int) -> None:
    """In fixed planes and in bending vectors alike (k and delta_max move at fixed b)."""
    rng = np.random.default_rng(seed)
    n, n_frames = cam + 1, 3
    mount = random_pose(rng, 0.4, 0.05)
    thetas = rng.uniform(-1.0, 1.0, (n_frames, n))
    bending = Bending.free(SEGMENTS[:n]) if free else Bending.fixed(
        SEGMENTS[:n], rng.uniform(-math.pi, math.pi, n))
    if free:
        thetas = bending.vector(thetas, rng.uniform(-math.pi, math.pi, (n_frames, n)))
    poses, d_poses, d_cal = camera_poses(thetas, bending, mount, None, calibration=True)
    plain, d_plain = camera_poses(thetas, bending, mount, None, engine="numpy")
    np.testing.assert_array_equal(poses, plain)  # the same numpy code
    np.testing.assert_array_equal(d_poses, d_plain)
    compiled, d_compiled = camera_poses(thetas, bending, mount, None)  # fixed planes: compiled
    np.testing.assert_allclose(compiled, plain, rtol=0, atol=1e-14)
    np.testing.assert_allclose(d_compiled, d_plain, rtol=0, atol=1e-14)
    assert d_cal.shape == (n_frames, n, 2, 4, 4)
    np.testing.assert_array_equal(d_cal[..., 3, :], 0.0)
    h = 1e-6
    for j in range(n):
        for i, (dk, dd) in enumerate(((h, 0.0), (0.0, h))):
            plus = camera_poses(thetas, bending.with_segments(_with(SEGMENTS[:n], j, dk, dd)),
                                mount, None, False)[0]
            minus = camera_poses(thetas, bending.with_segments(_with(SEGMENTS[:n], j, -dk, -dd)),
                                 mount, None, False)[0]
            np.testing.assert_allclose(d_cal[:, j, i], (plus - minus) / (2 * h), atol=1e-8)


@pytest.fixture(scope="module")
def lens_robot() -> Robot:
    rng = np.random.default_rng(0)
    cam = TipCamera(500.0, 490.0, 320.0, 240.0, 640, 480,
                    distortion=(-0.2, 0.05, 1e-3, -1e-3), tip_T_cam=random_pose(rng, 0.2, 0.02))
    return Robot(SEGMENTS, [None, cam, cam])


def _setup(robot: Robot, cam: int, seed: int, spatial: bool = False, noise_px: float = 1.0):
    sim = simulate(robot, 10, noise_px=noise_px, seed=seed, scene="room", n_points=400,
                   moving_base=True, fps=FAST, spatial=spatial)
    seq = sim.sequence
    camera = robot.cameras[cam]
    tracks = seq.tracks[cam]
    xy = camera.normalized(tracks.uv)
    obs = build_observations(cam, tracks.frames, tracks.track_ids, xy,
                             camera.pixel_jacobian(xy), None)
    bending = Bending.free(robot.segments) if spatial else Bending.fixed(robot.segments)
    chain = CameraChain(bending.head(cam + 1), camera.tip_T_cam, seq.world_T_base)
    truth = bending.vector(seq.thetas, seq.psis)
    thetas = truth + np.random.default_rng(seed).normal(0.0, 0.003, truth.shape)
    return seq, obs, chain, thetas


def _chain_with(chain: CameraChain, cal: np.ndarray) -> CameraChain:
    return chain.with_segments([Segment(s.length, k, d, s.theta_max)
                                for s, (k, d) in zip(chain.segments, cal.reshape(-1, 2),
                                                     strict=True)])


@pytest.mark.parametrize(("cam", "spatial"), [(1, False), (2, False), (2, True)])
def test_calibration_gradient_is_half_the_derivative_of_the_retriangulated_cost(
        lens_robot: Robot, cam: int, spatial: bool) -> None:
    """g's calibration entries against central differences of the cost minimised over the
    points; the frame block of H and g is that of the system without calibration. In bending
    vectors too (``spatial``: two columns per segment, the calibration's still two)."""
    seq, obs, chain, thetas = _setup(lens_robot, cam, 30 + cam, spatial)
    w = np.ones(len(obs))
    out = reduced_system(obs, chain, thetas, 0, w, calibration=True)
    plain = reduced_system(obs, chain, thetas, 0, w)
    n, D0 = cam + 1, len(thetas) * chain.n_parameters
    assert out.H.shape == (D0 + 2 * n,) * 2
    np.testing.assert_allclose(out.H[:D0, :D0], plain.H, rtol=0, atol=1e-9 * np.abs(plain.H).max())
    np.testing.assert_allclose(out.g[:D0], plain.g, rtol=0, atol=1e-9 * np.abs(plain.g).max())
    np.testing.assert_allclose(out.H, out.H.T, rtol=0, atol=1e-9 * np.abs(out.H).max())
    cal = np.array([[s.k, s.delta_max] for s in chain.segments]).ravel()
    h = 1e-6
    numeric = np.zeros(2 * n)
    for c in range(2 * n):
        plus, minus = cal.copy(), cal.copy()
        plus[c] += h
        minus[c] -= h
        cost = [reduced_system(obs, _chain_with(chain, v), thetas, 0, w, out.points,
                               jacobians=False).cost for v in (plus, minus)]
        numeric[c] = (cost[0] - cost[1]) / (2 * h)
    np.testing.assert_allclose(out.g[D0:], 0.5 * numeric, rtol=0,
                               atol=1e-5 * np.abs(out.g[D0:]).max())


def test_calibration_information_is_the_gauss_newton_curvature(lens_robot: Robot) -> None:
    """At noise-free data and the true angles the residuals vanish, so the reduced cost's
    Hessian in (angles, calibration) is exactly 2 H: check H's calibration rows against central
    differences of the reduced gradient."""
    cam = 2
    seq, obs, chain, _ = _setup(lens_robot, cam, 41, noise_px=0.0)
    w = np.ones(len(obs))
    out = reduced_system(obs, chain, seq.thetas, 0, w, calibration=True)
    assert out.cost < 1e-12
    n, D0 = 3, len(seq.thetas) * 3
    cal = np.array([[s.k, s.delta_max] for s in chain.segments]).ravel()
    h = 1e-6
    for c in range(2 * n):
        plus, minus = cal.copy(), cal.copy()
        plus[c] += h
        minus[c] -= h
        g = [reduced_system(obs, _chain_with(chain, v), seq.thetas, 0, w, out.points,
                            calibration=True).g for v in (plus, minus)]
        column = (g[0] - g[1]) / (2 * h)
        np.testing.assert_allclose(out.H[:, D0 + c], column, rtol=0,
                                   atol=1e-4 * np.abs(out.H).max())


def test_factor_has_calibration_blocks(lens_robot: Robot) -> None:
    cam = 1
    seq, obs, chain, thetas = _setup(lens_robot, cam, 50)
    S, n = lens_robot.n_segments, cam + 1
    values = gtsam.Values()
    for f, t in enumerate(thetas):
        values.insert(frame_key(f), np.asarray(t, dtype=float))
    true_cal = [(s.k, s.delta_max) for s in lens_robot.segments]
    for j, (k, d) in enumerate(true_cal):
        values.insert(calibration_key(j), np.array([k + 0.01, d - 0.02]))
    pf = ProjectionFactor(obs, chain, S, calibrate=True)
    factor = pf.factor()
    F = len(thetas)
    assert list(factor.keys()) == ([frame_key(f) for f in range(F)]
                                   + [calibration_key(j) for j in range(n)])
    moved = _chain_with(chain, np.array([[k + 0.01, d - 0.02] for k, d in true_cal[:n]]))
    want = reduced_system(obs, moved, thetas, 0, np.ones(len(obs)), calibration=True)
    info, eta = factor_hessian(factor, values)
    D0 = F * S
    index = np.concatenate([((np.arange(F) * S)[:, None] + np.arange(n)).ravel(),
                            D0 + np.arange(2 * n)])
    scale = np.abs(want.H).max()
    np.testing.assert_allclose(info[np.ix_(index, index)], want.H, rtol=0, atol=1e-9 * scale)
    np.testing.assert_allclose(eta[index], -want.g, rtol=0, atol=1e-8 * np.abs(want.g).max())
    assert factor.error(values) == pytest.approx(0.5 * want.cost, rel=1e-9)


def test_calibrated_clamps_into_the_valid_range() -> None:
    s = Segment(0.3, 0.25, 0.05, 1.0)
    assert calibrated(s, 0.7, 2.0).k < 0.5 and calibrated(s, 0.7, 2.0).delta_max < 1.0
    assert calibrated(s, -1.0, -2.0).k > 0.0 and calibrated(s, -1.0, -2.0).delta_max > -1.0
    same = calibrated(s, 0.21, 0.07)
    assert (same.k, same.delta_max, same.length, same.theta_max) == (0.21, 0.07, 0.3, 1.0)
