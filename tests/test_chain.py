"""The paper's chained front end on simulated sequences: tracking, carry-over outcomes, Estimate."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from apcc_graph.estimation.chain import chain_estimate
from apcc_graph.estimation.result import Estimate
from apcc_graph.io.robot_file import load_robot
from apcc_graph.model.kinematics import apcc_transform
from apcc_graph.model.robot import Robot
from apcc_graph.model.sequence import Sequence
from apcc_graph.simulation.simulator import simulate, simulate_sequence

ROBOT_FILE = Path(__file__).resolve().parents[1] / "data" / "robots" / "planar_three.toml"
N_FRAMES = 40


@pytest.fixture(scope="module")
def robot() -> Robot:
    return load_robot(ROBOT_FILE)


@pytest.fixture(scope="module")
def still_base(robot: Robot):
    seq = simulate_sequence(robot, N_FRAMES, noise_px=0.5, seed=0)
    return seq, chain_estimate(seq, theta0=seq.thetas[0])


@pytest.fixture(scope="module")
def moving_base(robot: Robot):
    seq = simulate_sequence(robot, N_FRAMES, noise_px=0.5, outlier_fraction=0.3, seed=1,
                            moving_base=True)
    return seq, chain_estimate(seq, theta0=seq.thetas[0])


def without_camera(robot: Robot, segment: int) -> Robot:
    cams = list(robot.cameras)
    cams[segment] = None
    return Robot(robot.segments, cams)


# ----------------------------------------------------------------------------- tracking
def test_chain_follows_a_planar_sequence(robot: Robot, still_base) -> None:
    seq, est = still_base
    assert robot.n_segments == 3 and seq.world_T_base is None
    assert est.thetas.shape == (N_FRAMES, 3)
    assert est.status.shape == est.inliers.shape == est.sigmas.shape == (N_FRAMES, 3)
    # The truth moves: following it is not the same as standing still.
    travel = np.ptp(seq.thetas, axis=0)
    assert np.all(travel > math.radians(5.0))
    rms = est.rms(seq.thetas)
    assert np.all(rms < math.radians(1.0)), np.degrees(rms)
    assert np.all(est.status[0] == "initial")
    later = est.status[1:]
    assert np.mean(later == "ok") > 0.9
    assert set(np.unique(later)) <= {"ok", "no-motion"}
    np.testing.assert_array_equal(est.thetas[0], seq.thetas[0])
    # The inlier counts are those of successful RANSAC calls: most of the ~200 tracks.
    assert np.all(est.inliers[1:][later == "ok"] >= 50)
    assert np.all(est.inliers[0] == 0)


def test_chain_follows_with_a_moving_base_and_outliers(moving_base) -> None:
    seq, est = moving_base
    assert seq.world_T_base is not None
    rms = est.rms(seq.thetas)
    assert np.all(rms < math.radians(1.5)), np.degrees(rms)
    assert np.mean(est.status[1:] == "ok") > 0.9
    np.testing.assert_array_equal(est.world_T_base, seq.world_T_base)


def test_moving_base_is_not_ignored(moving_base) -> None:
    """Treating a moving base as fixed breaks the estimate: the base motion is really used."""
    seq, est = moving_base
    fixed = Sequence(seq.robot, seq.timestamps, seq.tracks, thetas=seq.thetas)
    wrong = chain_estimate(fixed, theta0=seq.thetas[0])
    assert np.max(wrong.rms(seq.thetas)) > 2.0 * np.max(est.rms(seq.thetas))


def test_chain_is_deterministic(still_base) -> None:
    seq, est = still_base
    again = chain_estimate(seq, theta0=seq.thetas[0])
    np.testing.assert_array_equal(again.thetas, est.thetas)
    np.testing.assert_array_equal(again.status, est.status)


# --------------------------------------------------------------------- carried-over angles
@pytest.mark.parametrize("blind", [1, 2])
def test_segment_without_camera_is_carried_over(robot: Robot, blind: int) -> None:
    partial = without_camera(robot, blind)
    seq = simulate_sequence(partial, 30, noise_px=0.5, seed=2)
    assert blind not in seq.cameras
    theta0 = seq.thetas[0]
    est = chain_estimate(seq, theta0=theta0)
    assert np.all(est.status[1:, blind] == "no-camera")
    np.testing.assert_array_equal(est.thetas[:, blind], theta0[blind])
    assert np.all(est.inliers[:, blind] == 0)
    # Segments inside the blind one are unaffected by it.
    assert np.mean(est.status[1:, :blind] == "ok") > 0.9
    assert np.all(est.rms(seq.thetas)[:blind] < math.radians(1.0))


def test_blackout_frames_carry_the_angle_over(robot: Robot) -> None:
    sim = simulate(robot, N_FRAMES, noise_px=0.5, seed=3, blackout_fraction=0.1)
    seq = sim.sequence
    est = chain_estimate(seq, theta0=seq.thetas[0])
    checked = 0
    for cam in range(robot.n_segments):
        dark = [f for f in range(1, N_FRAMES) if len(seq.observations(cam, f)[0]) == 0]
        for f in dark:
            # Nothing seen in frame f: no correspondences with f - 1 nor with f + 1.
            for g in (f, f + 1):
                if g >= N_FRAMES:
                    continue
                assert len(seq.correspondences(cam, g - 1, g)) == 0
                assert est.status[g, cam] == "too-few-correspondences"
                assert est.status[g, cam] != "ok"
                assert est.thetas[g, cam] == est.thetas[g - 1, cam]
                assert est.inliers[g, cam] == 0
                checked += 1
    assert checked >= 5
    # Frames with views are still estimated.
    seen = 0
    for cam in range(robot.n_segments):
        for g in range(1, N_FRAMES):
            if len(seq.correspondences(cam, g - 1, g)) >= 50:
                assert est.status[g, cam] in ("ok", "no-motion")
                seen += est.status[g, cam] == "ok"
    assert seen >= 40


# ------------------------------------------------------------------------------- arguments
def test_theta0_shape_is_checked(still_base) -> None:
    seq, _ = still_base
    for bad in (np.zeros(2), np.zeros(4), np.zeros((3, 1)), np.zeros((1, 3)),
                np.array([0.1, np.nan, 0.0]), np.array([0.1, np.inf, 0.0]), 0.3):
        with pytest.raises(ValueError, match="theta0"):
            chain_estimate(seq, theta0=bad)


def test_default_theta0_is_straight(still_base) -> None:
    seq, _ = still_base
    short = simulate_sequence(seq.robot, 6, noise_px=0.5, seed=4)
    est = chain_estimate(short)
    np.testing.assert_array_equal(est.thetas[0], np.zeros(3))
    assert np.all(est.status[0] == "initial")
    explicit = chain_estimate(short, theta0=[0.0, 0.0, 0.0])
    np.testing.assert_array_equal(explicit.thetas, est.thetas)


# -------------------------------------------------------------------------------- Estimate
def test_estimate_fields(still_base) -> None:
    seq, est = still_base
    assert isinstance(est, Estimate)
    assert est.method == "chain"
    assert est.robot == seq.robot
    assert est.n_frames == N_FRAMES
    np.testing.assert_array_equal(est.timestamps, seq.timestamps)
    assert np.all(np.isnan(est.sigmas))
    assert est.inliers.dtype == np.int64


@pytest.mark.parametrize("which", ["still_base", "moving_base"])
def test_world_T_tip_is_forward_kinematics(which: str, request: pytest.FixtureRequest) -> None:
    seq, est = request.getfixturevalue(which)
    tips = est.world_T_tip()
    assert tips.shape == (N_FRAMES, 3, 4, 4)
    np.testing.assert_allclose(
        tips, seq.robot.forward(est.thetas, world_T_base=seq.world_T_base), atol=1e-14)
    # ... and that is the product of the segments' transforms on the base pose.
    for f in (0, 17, N_FRAMES - 1):
        pose = np.eye(4) if seq.world_T_base is None else seq.world_T_base[f]
        for i, seg in enumerate(seq.robot.segments):
            pose = pose @ apcc_transform(est.thetas[f, i], seg)
            np.testing.assert_allclose(tips[f, i], pose, atol=1e-12)


def test_estimate_errors_and_rms_by_hand(still_base) -> None:
    seq, est = still_base
    truth = np.asarray(seq.thetas)
    np.testing.assert_array_equal(est.errors(truth), est.thetas - truth)
    by_hand = [math.sqrt(sum((est.thetas[f, i] - truth[f, i]) ** 2 for f in range(N_FRAMES))
                         / N_FRAMES) for i in range(3)]
    np.testing.assert_allclose(est.rms(truth), by_hand, rtol=1e-12)
    assert est.rms(truth).shape == (3,)
    # A hand-made Estimate: known numbers.
    thetas = np.array([[0.0, 1.0, 0.5], [3.0, -1.0, 0.5]])
    small = Estimate(method="x", robot=seq.robot, timestamps=np.array([0.0, 1.0]),
                     thetas=thetas, sigmas=np.full((2, 3), np.nan),
                     status=np.full((2, 3), "ok"), inliers=np.zeros((2, 3), np.int64))
    np.testing.assert_allclose(small.rms(np.zeros((2, 3))), [math.sqrt(4.5), 1.0, 0.5])
    np.testing.assert_allclose(small.rms(thetas), [0.0, 0.0, 0.0])
    np.testing.assert_allclose(small.errors(np.ones((2, 3))), thetas - 1.0)
