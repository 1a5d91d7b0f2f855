"""Spatial robots in the back end: bending-vector conversions and their sigmas, the joint-limit
factor on |b|, the projection factor over bending vectors (gradient and linearisation),
self-calibration in bending vectors, the spatial batch at the Cramer-Rao bound, a robot passing
through straight, and the API's refusals."""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import gtsam
import numpy as np
import pytest
from helpers import factor_hessian
from hypothesis import given, settings
from hypothesis import strategies as st

from apcc_graph import estimate
from apcc_graph.estimation.batch import batch_estimate
from apcc_graph.estimation.bends import start_vector
from apcc_graph.estimation.blackout import BlackoutWarning
from apcc_graph.estimation.graph import camera_chain, camera_observations, limit_factor
from apcc_graph.estimation.model_calibration import MOUNT_SIGMAS
from apcc_graph.estimation.options import BatchOptions
from apcc_graph.estimation.smoother import FixedLagSmoother
from apcc_graph.estimation.smoother_options import SmootherOptions, WindowOptions
from apcc_graph.evaluation.sequence_bound import sequence_bound
from apcc_graph.factors.keys import frame_key
from apcc_graph.factors.projection import ProjectionFactor
from apcc_graph.factors.reduced_system import reduced_system
from apcc_graph.io.robot_file import load_robot
from apcc_graph.model.arrays import rms
from apcc_graph.model.parameterisation import Bending
from apcc_graph.model.robot import Robot
from apcc_graph.model.segment import Segment
from apcc_graph.model.sequence import Sequence
from apcc_graph.simulation import faults
from apcc_graph.simulation.simulator import simulate

ROBOT = Path(__file__).resolve().parents[1] / "data/robots/planar_three.toml"


@pytest.fixture(scope="module")
def robot():
    return load_robot(ROBOT)


def _free(n: int) -> Bending:
    """Free planes of ``n`` segments (the conversions depend only on how many)."""
    return Bending.free([Segment(0.3, theta_max=2.0)] * n)


def bends_from(thetas: np.ndarray, psis: np.ndarray) -> np.ndarray:
    return _free(np.shape(thetas)[-1]).vector(thetas, psis)


def polar_from(bends: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return _free(np.shape(bends)[-1] // 2).polar(bends)


def polar_sigmas(bends: np.ndarray, covariances: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return _free(np.shape(bends)[-1] // 2).deviations(bends, covariances)


def start_bends(robot, theta0, psi0) -> np.ndarray:
    return start_vector(robot, Bending.free(robot.segments), theta0, psi0)


# ------------------------------------------------------------------------------ conversions
@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(-1.2, 1.2), min_size=3, max_size=3),
       st.lists(st.floats(-4.0, 4.0), min_size=3, max_size=3))
def test_polar_of_bends_is_the_same_bend(thetas: list, psis: list) -> None:
    b = bends_from(np.array(thetas), np.array(psis))
    theta, psi = polar_from(b)
    assert np.all(theta >= 0.0) and np.all(np.abs(psi) <= math.pi)
    np.testing.assert_allclose(bends_from(theta, psi), b, atol=1e-12)


def test_polar_sigmas_are_the_first_order_propagation() -> None:
    rng = np.random.default_rng(3)
    for _ in range(20):
        b = rng.normal(0.0, 0.5, 2)
        A = rng.normal(0.0, 1e-2, (2, 2))
        C = A @ A.T
        # Numerical Jacobian of (theta, psi) in b, then J C J^T.
        h = 1e-7
        J = np.zeros((2, 2))
        for k in range(2):
            d = np.zeros(2)
            d[k] = h
            plus, minus = polar_from(b + d), polar_from(b - d)
            J[:, k] = [(plus[0][0] - minus[0][0]) / (2 * h), (plus[1][0] - minus[1][0]) / (2 * h)]
        want = np.sqrt(np.diag(J @ C @ J.T))
        s_theta, s_psi = polar_sigmas(b, C[None])
        np.testing.assert_allclose([s_theta[0], s_psi[0]], want, rtol=1e-6)


def test_polar_sigmas_at_exactly_straight() -> None:
    C = np.diag([4e-4, 1e-4])[None]
    s_theta, s_psi = polar_sigmas(np.zeros(2), C)
    assert s_theta[0] == pytest.approx(0.02) and math.isinf(s_psi[0])
    nan_theta, nan_psi = polar_sigmas(np.array([0.1, 0.0]), np.full((1, 2, 2), np.nan))
    assert math.isnan(nan_theta[0]) and math.isnan(nan_psi[0])


def test_start_bends_checks_its_inputs(robot) -> None:
    np.testing.assert_allclose(start_bends(robot, [0.1, -0.2, 0.3], [0.0, math.pi / 2, 0.0]),
                               [0.1, 0.0, 0.0, -0.2, 0.3, 0.0], atol=1e-15)
    with pytest.raises(ValueError, match=r"psi0 has shape \(2,\)"):
        start_bends(robot, None, [0.0, 1.0])
    with pytest.raises(ValueError, match=r"psi0\[1\] = nan"):
        start_bends(robot, None, [0.0, math.nan, 0.0])
    with pytest.raises(ValueError, match="theta0"):
        start_bends(robot, [3.0, 0.0, 0.0], None)


# ------------------------------------------------------------------------------ limits
def test_bend_limit_factor_acts_on_the_length_with_the_right_jacobian() -> None:
    theta_max = np.array([0.5, 0.8])
    free = Bending.free([Segment(0.3, theta_max=t) for t in theta_max])
    factor = limit_factor(frame_key(0), free, 0.01)
    values = gtsam.Values()
    inside = np.array([0.3, -0.3, 0.0, 0.0])  # |b_0| = 0.42 < 0.5, b_1 straight
    values.insert(frame_key(0), inside)
    assert factor.error(values) == 0.0
    outside = np.array([0.4, -0.4, 0.1, 0.85])  # |b_0| = 0.566, |b_1| = 0.856
    values.update(frame_key(0), outside)
    r = factor.unwhitenedError(values)
    np.testing.assert_allclose(r, (np.hypot([0.4, 0.1], [-0.4, 0.85]) - theta_max) / 0.01)
    J = factor.linearize(values).jacobian()[0][:, :4]
    h = 1e-7
    numeric = np.zeros((2, 4))
    for k in range(4):
        d = np.zeros(4)
        d[k] = h
        for sign in (1, -1):
            values.update(frame_key(0), outside + sign * d)
            numeric[:, k] += sign * factor.unwhitenedError(values) / (2 * h)
    np.testing.assert_allclose(J, numeric, atol=1e-5)


# ------------------------------------------------------------------------------ factor
def _straight_through(robot, n_frames: int, crossing: int) -> np.ndarray:
    """``(F, S)`` angles ramping through 0 at frame ``crossing`` (segments 1 and 3)."""
    t = np.arange(n_frames) - crossing
    thetas = np.column_stack([0.02 * t, 0.3 + 0.01 * t, -0.015 * t])
    assert np.all(np.abs(thetas) < [s.theta_max for s in robot.segments])
    return thetas


@pytest.mark.parametrize("cam", [0, 2])
def test_spatial_factor_gradient_and_linearisation_through_straight(robot, cam: int) -> None:
    """The factor over bending vectors: its gradient is half the derivative of the
    re-triangulated cost in (u, v), and gtsam's linearisation is the reduced system, at values
    that include an exactly straight segment (where psi is undefined)."""
    sim = simulate(robot, 8, noise_px=1.0, seed=4 + cam, scene="room", n_points=500,
                   spatial=True, fps=5.0, bends=_straight_through(robot, 8, 3))
    seq = sim.sequence
    obs = camera_observations(seq, cam, 1.0)
    chain = camera_chain(robot, cam, Bending.free(robot.segments), seq.world_T_base)
    bends = bends_from(seq.thetas, seq.psis)
    assert np.all(bends[3, 0:2] == 0.0) and np.all(bends[3, 4:6] == 0.0)
    bends[:, 2:4] += np.random.default_rng(cam).normal(0.0, 0.003, (8, 2))
    n = 2 * (cam + 1)
    w = np.ones(len(obs))
    out = reduced_system(obs, chain, bends, 0, w)
    h = 1e-6
    numeric = np.zeros_like(out.g)
    for f in range(8):
        for j in range(n):
            plus, minus = bends.copy(), bends.copy()
            plus[f, j] += h
            minus[f, j] -= h
            cost = [reduced_system(obs, chain, x, 0, w, out.points, jacobians=False).cost
                    for x in (plus, minus)]
            numeric[f * n + j] = (cost[0] - cost[1]) / (2 * h)
    np.testing.assert_allclose(out.g, 0.5 * numeric, rtol=0, atol=2e-5 * np.abs(out.g).max())
    factor = ProjectionFactor(obs, chain, 6).factor()
    values = gtsam.Values()
    for f in range(8):
        values.insert(frame_key(f), bends[f])
    info, _ = factor_hessian(factor, values)
    index = ((np.arange(8) * 6)[:, None] + np.arange(n)).ravel()
    want = reduced_system(obs, chain, bends, 0, w, out.points)
    np.testing.assert_allclose(info[np.ix_(index, index)], want.H, rtol=0,
                               atol=1e-8 * np.abs(want.H).max())
    others = np.setdiff1d(np.arange(48), index)
    assert np.all(info[others] == 0.0)


def _wrong_models(seq: Sequence, dk: float = 0.03, dd_deg: float = 3.0) -> Sequence:
    """The sequence with every segment's k off by ``dk`` and delta_max off by ``dd_deg``."""
    robot = Robot([Segment(s.length, s.k + dk, s.delta_max + math.radians(dd_deg), s.theta_max)
                   for s in seq.robot.segments], seq.robot.cameras)
    return Sequence(robot, seq.timestamps, seq.tracks, seq.world_T_base, seq.thetas, seq.psis)


def test_self_calibration_of_a_spatial_robot(robot) -> None:
    """Wrong k and delta_max on every segment of a robot that bends in 3-D: the batch in
    bending vectors finds the models within a few of its sigmas, and its sigmas (of the models
    and, by default, the mounts) are the Cramer-Rao bound with the planes free; without
    self-calibration the bends are several times worse than with the models calibrated."""
    sim = simulate(robot, 60, noise_px=1.0, seed=21, scene="room", spatial=True, fps=10.0)
    seq = _wrong_models(sim.sequence)
    sigmas = (0.05, math.radians(5.0))
    start = dict(theta0=seq.thetas[0], psi0=seq.psis[0], spatial=True)
    est = estimate(seq, method="batch", **start,
                   settings=BatchOptions(calibrate=True, calibration_sigmas=sigmas))
    found = np.array([[s.k, s.delta_max] for s in est.robot.segments])
    truth = np.array([[s.k, s.delta_max] for s in robot.segments])
    assert np.all(np.abs(found - truth) < 4.0 * est.calibration_sigmas), (found, truth)
    # The default self-calibration also estimates the mounts: the bound has them unknown too.
    bound = sequence_bound(sim, 1.0, calibration_sigmas=sigmas, spatial=True,
                           mount_sigmas=MOUNT_SIGMAS)
    np.testing.assert_allclose(est.calibration_sigmas, bound.calibration, rtol=0.15)
    np.testing.assert_allclose(est.mount_sigmas, bound.mounts, rtol=0.15)
    err = est.rms(seq.thetas, seq.psis)
    assert np.all(err < 2.0 * bound.rms()), (np.degrees(err), np.degrees(bound.rms()))
    blind = estimate(seq, method="batch", **start)
    models = estimate(seq, method="batch", **start, settings=BatchOptions(
        calibrate=True, calibration_sigmas=sigmas, mount_sigmas=None))
    assert np.max(blind.rms(seq.thetas, seq.psis)) > 3.0 * np.max(models.rms(seq.thetas,
                                                                             seq.psis))


# ------------------------------------------------------------------------------ batch
@pytest.fixture(scope="module")
def spatial_run(robot):
    sim = simulate(robot, 60, noise_px=1.0, seed=11, scene="room", spatial=True, fps=10.0)
    seq = sim.sequence
    est = estimate(seq, method="batch", theta0=seq.thetas[0], psi0=seq.psis[0], spatial=True)
    bound = sequence_bound(sim, noise_px=1.0, spatial=True)
    return sim, est, bound


def test_spatial_batch_is_at_the_bound_with_honest_sigmas(spatial_run) -> None:
    sim, est, bound = spatial_run
    seq = sim.sequence
    assert est.spatial and est.psis.shape == est.thetas.shape
    assert np.all(est.thetas >= 0.0)
    err = est.rms(seq.thetas, seq.psis)
    crb = np.sqrt(np.mean(bound.sigmas**2, axis=0))
    assert np.all(err < 2.0 * crb), (np.degrees(err), np.degrees(crb))
    sig = np.sqrt(np.mean(est.bend_sigmas()**2, axis=0))
    np.testing.assert_allclose(sig / crb, 1.0, atol=0.25)
    # The chain it started from is far worse: the batch did the work.
    chain = estimate(seq, method="chain", theta0=seq.thetas[0], psi0=seq.psis[0],
                     spatial=True)
    assert np.max(chain.rms(seq.thetas, seq.psis)) > 2.0 * np.max(err)


def _spatial_smoother_run(robot, seed: int, n_points: int, outliers: float, frames: int):
    sim = simulate(robot, frames, noise_px=1.0, outlier_fraction=outliers, seed=seed,
                   scene="room", n_points=n_points, spatial=True)
    seq = sim.sequence
    est = estimate(seq, method="smoother", theta0=seq.thetas[0], psi0=seq.psis[0],
                   spatial=True)
    bound = sequence_bound(sim, noise_px=1.0, spatial=True)
    return seq, est, np.sqrt(np.mean(bound.sigmas**2, axis=0))


def test_spatial_smoother_near_the_bound(robot) -> None:
    """The fixed-lag smoother in bending vectors, through estimate(): within 3x of the whole
    recording's bound, with sigmas no smaller than that bound (a 1 s window sees less) and
    honest."""
    seq, est, crb = _spatial_smoother_run(robot, 1, 4000, 0.1, 90)
    assert est.spatial and np.all(np.isfinite(est.psis))
    err = est.errors(seq.thetas, seq.psis)
    assert np.all(np.sqrt(np.mean(err**2, axis=0)) < 3.0 * crb), np.degrees(err).max()
    sig = est.bend_sigmas()
    assert np.all(np.sqrt(np.mean(sig**2, axis=0)) > 0.9 * crb)
    assert np.mean((err / sig) ** 2) < 2.0


def test_spatial_smoother_follows_the_first_frames(robot) -> None:
    """Each frame's filtered estimate (the smoother's answer when the frame arrives) over the
    first 40 frames at 30 fps, where no track is four frames long yet at first: the tracks the
    2-point front end accepts join the graph from their second frame. Without them the
    window had no vision for three frames, held the start, and strayed 5-10 deg."""
    sim = simulate(robot, 40, noise_px=1.0, seed=11, scene="room", spatial=True, fps=30.0)
    seq = sim.sequence
    truth = bends_from(seq.thetas, seq.psis).reshape(40, -1, 2)
    smoother = FixedLagSmoother(robot, theta0=seq.thetas[0], psi0=seq.psis[0],
                                spatial=True)
    errors = []
    for f in range(40):
        now = smoother.update(seq.frame(f))
        b = bends_from(now.thetas[None], now.psis[None]).reshape(-1, 2)
        errors.append(np.hypot(*(b - truth[f]).T))
    errors = np.degrees(np.array(errors))
    assert errors[1:4].max() < 1.0, errors[1:4]
    assert errors.max() < 1.0, errors.max(axis=0)
    assert np.sqrt(np.mean(errors[20:] ** 2)) < 0.3


@pytest.mark.parametrize("method", ["batch", "smoother"])
def test_a_robot_passing_through_straight(robot, method: str) -> None:
    crossing = 30
    sim = simulate(robot, 60, noise_px=1.0, seed=2, scene="room", spatial=True, fps=10.0,
                   bends=_straight_through(robot, 60, crossing))
    seq = sim.sequence
    est = estimate(seq, method=method, theta0=seq.thetas[0], psi0=seq.psis[0], spatial=True)
    assert np.all(np.isfinite(est.thetas)) and np.all(np.isfinite(est.psis))
    err = est.errors(seq.thetas, seq.psis)
    sig = est.bend_sigmas()
    assert np.all(np.isfinite(sig))
    # Every bending vector within 4.5 sigma, through the crossing too.
    assert np.max(err / sig) < 4.5
    # Near straight the bending plane is uncertain and says so; far from it, it is not.
    assert est.psi_sigmas[crossing, 0] > 10 * est.psi_sigmas[0, 0]
    # psi turns by about pi across the crossing (b goes through 0), as the truth's does.
    _, true_psis = polar_from(bends_from(seq.thetas, seq.psis))

    def turn(psis: np.ndarray) -> float:
        return abs(math.remainder(psis[crossing + 5, 0] - psis[crossing - 5, 0], 2 * math.pi))

    assert turn(true_psis) > 2.5
    assert turn(est.psis) == pytest.approx(turn(true_psis), abs=0.05)


def test_spatial_api_refusals(robot) -> None:
    seq = simulate(robot, 5, seed=1, spatial=True, fps=5.0).sequence
    theta0 = seq.thetas[0]
    with pytest.raises(ValueError, match="psi0 is given but spatial is False"):
        estimate(seq, theta0=theta0, psi0=[0.0, 0.0, 0.0])
    with pytest.raises(ValueError, match="psi0 without theta0"):
        estimate(seq, spatial=True, psi0=[0.0, 0.0, 0.0])
    with pytest.raises(ValueError, match="psi0 is given but the bending planes are fixed"):
        FixedLagSmoother(robot, theta0=theta0, psi0=[0.0, 0.0, 0.0])
    with pytest.raises(TypeError, match="vision"):  # the epipolar back end is gone
        estimate(seq, theta0=theta0, spatial=True, vision="epipolar")
    with pytest.raises(ValueError, match=r"psi0 has shape \(2,\)"):
        estimate(seq, theta0=theta0, psi0=[0.0, 1.0], spatial=True)
    with pytest.raises(ValueError, match="initial has shape"):
        batch_estimate(seq, theta0=theta0, spatial=True, initial=np.zeros((5, 3)))
    with pytest.raises(TypeError, match="calibrate"):  # the batch's option, in its record
        estimate(seq, theta0=theta0, spatial=True, calibrate=True)
    with pytest.raises(TypeError, match="calibration"):  # misspelled: refused by name
        BatchOptions(calibration=True)
    with pytest.raises(TypeError, match="expected BatchOptions for method 'batch'"):
        estimate(seq, theta0=theta0, spatial=True,
                 settings=SmootherOptions(window=WindowOptions(lag=0.5)))


def test_a_spatial_robot_is_reacquired_after_every_camera_went_blind(robot) -> None:
    """Every camera blind for 1 s while the robot bends in 3-D: the smoother says so and
    re-acquires the bending vectors by one batch over the new tracks. Measured (200 frames,
    blind 60-89): 0.06 / 0.09 / 0.08 deg RMS from 50 frames after, against twice the bound
    of 0.25 / 0.24 / 0.29 (with 300 frames, blind 120-149, without the re-acquisition: 1.4 /
    0.27 / 0.26, 77 deg at worst)."""
    sim = simulate(robot, 200, noise_px=1.0, outlier_fraction=0.1, seed=1, fps=30.0,
                   scene="room", spatial=True)
    blind = faults.blind(sim, [0, 1, 2], 60, 90)
    seq = blind.sequence
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        est = estimate(seq, method="smoother", theta0=seq.thetas[0], psi0=seq.psis[0],
                       spatial=True)
    said = [w for w in caught if issubclass(w.category, BlackoutWarning)]
    assert len(said) == 1 and "frame 90 " in str(said[0].message)
    assert np.any(est.status[90:120] == "reacquired")
    later = slice(140, None)
    err = rms(est.errors(seq.thetas, seq.psis)[later])
    bound = rms(sequence_bound(blind, 1.0, spatial=True).sigmas[later])
    assert np.all(err < 2.0 * bound), (np.degrees(err), np.degrees(bound))


def test_the_unknown_start_of_a_spatial_robot(robot) -> None:
    """No theta0, no psi0: the search finds every bending vector at frame 0 from one second of
    images (hypotheses around the first segment's ring of bends, propagated by the 2-point
    chain, refined by the batch), within 3 of its own sigmas, which are the vision-only
    bound; the batch then starts there and the estimate says where it found the start."""
    sim = simulate(robot, 31, noise_px=1.0, outlier_fraction=0.1, seed=3, fps=30.0,
                   scene="room", amplitude=0.8, spatial=True)
    seq = sim.sequence
    free = Bending.free(robot.segments)
    truth = free.vector(seq.thetas[0], seq.psis[0])
    assert np.degrees(free.magnitudes(truth)[0]) > 10.0  # far from straight: a real search
    est = estimate(seq, method="batch", spatial=True)
    start = est.start
    assert start is not None and start.psi0 is not None and start.hypotheses == 4
    found = free.vector(start.theta0, start.psi0)
    error = free.magnitudes(found - truth)
    bound = sequence_bound(sim, 1.0, theta0_sigma=None, spatial=True).sigmas[0]
    assert np.all(error < 3.0 * start.sigma0), (np.degrees(error), np.degrees(start.sigma0))
    assert np.sqrt(np.mean((error / bound) ** 2)) < 2.0
    # sigma0 is the worst direction's sigma of each bending vector: between the bound of the
    # vector's error norm over sqrt(2) and that bound
    assert np.all((start.sigma0 > 0.6 * bound) & (start.sigma0 < 1.1 * bound)), (
        np.degrees(start.sigma0), np.degrees(bound))
    err = est.rms(seq.thetas, seq.psis)
    assert np.all(err < 2.0 * np.sqrt(np.mean(sequence_bound(
        sim, 1.0, theta0_sigma=None, spatial=True).sigmas ** 2, axis=0)))
