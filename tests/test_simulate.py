"""The simulator: geometry against ground truth, noise and outlier statistics, options, seeds."""

from __future__ import annotations

import math

import numpy as np
import pytest

from apcc_graph import Robot, Segment, TipCamera
from apcc_graph.simulation.simulator import simulate, simulate_sequence

CAM = TipCamera(500.0, 500.0, 320.0, 240.0, 640, 480)
DISTORTED = TipCamera(480.0, 490.0, 315.0, 245.0, 640, 480, distortion=(-0.1, 0.02, 0.0, 0.0))


@pytest.fixture(scope="module")
def three() -> Robot:
    return Robot([Segment(0.3, k=0.22, delta_max=0.1, theta_max=1.0), Segment(0.3, k=0.24),
                  Segment(0.3)], [CAM, DISTORTED, CAM])


def epipolar_residuals(sim, cam: int, a: int, b: int) -> np.ndarray:
    """``f_a . (t x R f_b)`` with ``(R, t) = camA_T_camB`` from the true camera poses."""
    corr = sim.sequence.correspondences(cam, a, b)
    camA_T_camB = np.linalg.inv(sim.world_T_cam[cam][a]) @ sim.world_T_cam[cam][b]
    R, t = camA_T_camB[:3, :3], camA_T_camB[:3, 3]
    return np.einsum("ni,ni->n", corr.f_a, np.cross(t, corr.f_b @ R.T))


@pytest.mark.parametrize(
    "options",
    [
        {},
        {"moving_base": True, "spatial": True},
        {"motion": "paper", "scene": "room"},
        {"curvature_growth": 1.5},
    ],
)
def test_noise_free_tracks_satisfy_the_epipolar_constraint(three: Robot, options: dict) -> None:
    sim = simulate(three, 40, noise_px=0.0, seed=4, **options)
    checked = 0
    for cam in sim.sequence.cameras:
        for a, b in [(0, 1), (5, 6), (10, 30), (39, 2)]:
            res = epipolar_residuals(sim, cam, a, b)
            assert np.max(np.abs(res), initial=0.0) < 1e-9
            checked += len(res)
    assert checked > 1000


def test_reprojection_of_the_scene_reproduces_the_tracks(three: Robot) -> None:
    sim = simulate(three, 30, noise_px=0.0, seed=5, moving_base=True)
    for cam in sim.sequence.cameras:
        trk = sim.sequence.tracks[cam]
        camera = three.cameras[cam]
        poses = sim.world_T_cam[cam][trk.frames]
        points = sim.points_world[sim.landmarks[cam]]
        in_cam = np.einsum("nji,nj->ni", poses[:, :3, :3], points - poses[:, :3, 3])
        assert np.all(in_cam[:, 2] > 0)
        np.testing.assert_allclose(camera.project(in_cam), trk.uv, atol=1e-9)
        np.testing.assert_array_equal(trk.uv, sim.clean_uv[cam])


def test_noise_statistics_match_sigma(three: Robot) -> None:
    sim = simulate(three, 60, noise_px=1.5, seed=6)
    err = np.concatenate([sim.sequence.tracks[c].uv - sim.clean_uv[c]
                          for c in sim.sequence.cameras])
    assert len(err) > 20000
    np.testing.assert_allclose(err.std(axis=0), 1.5, rtol=0.03)
    np.testing.assert_allclose(err.mean(axis=0), 0.0, atol=0.05)


@pytest.mark.parametrize("fraction", [0.1, 0.3])
def test_outlier_fraction_matches(three: Robot, fraction: float) -> None:
    sim = simulate(three, 30, noise_px=0.5, outlier_fraction=fraction, seed=7)
    for cam in sim.sequence.cameras:
        flags = sim.outliers[cam]
        assert flags.sum() == round(fraction * len(flags))
        err = np.linalg.norm(sim.sequence.tracks[cam].uv - sim.clean_uv[cam], axis=1)
        assert np.max(err[~flags]) < 6 * 0.5 * math.sqrt(2)
        assert np.median(err[flags]) > 50.0  # random pixels land far from the true one


def test_same_seed_same_sequence(three: Robot) -> None:
    kwargs = {"noise_px": 0.7, "outlier_fraction": 0.1, "track_lifetime": 10.0,
              "blackout_fraction": 0.1, "moving_base": True}
    a = simulate_sequence(three, 25, seed=11, **kwargs)
    b = simulate_sequence(three, 25, seed=11, **kwargs)
    c = simulate_sequence(three, 25, seed=12, **kwargs)
    assert a.equals(b)
    assert not a.equals(c)


def test_paper_protocol_steps_and_range(three: Robot) -> None:
    seq = simulate_sequence(three, 400, motion="paper", seed=8)
    steps = np.abs(np.diff(seq.thetas, axis=0))
    assert np.max(steps) < math.radians(5.0) + 1e-12
    assert np.max(steps) > math.radians(4.0)
    limit = [min(math.radians(50), s.theta_max) for s in three.segments]
    assert np.all(np.abs(seq.thetas) <= np.array(limit) + 1e-12)


def test_smooth_motion_stays_within_the_limits(three: Robot) -> None:
    seq = simulate_sequence(three, 300, seed=9)
    limits = np.array([s.theta_max for s in three.segments])
    assert np.all(np.abs(seq.thetas) <= 0.8 * limits + 1e-12)
    assert np.all(np.max(np.abs(seq.thetas), axis=0) > 0.2 * limits)  # it does move
    assert seq.world_T_base is None and seq.psis is None


def test_moving_base_bounds(three: Robot) -> None:
    seq = simulate_sequence(three, 200, seed=10, moving_base=True)
    base = seq.world_T_base
    assert base is not None
    assert np.max(np.linalg.norm(base[:, :3, 3], axis=1)) == pytest.approx(0.1)
    angles = np.degrees(np.arccos(np.clip((np.trace(base[:, :3, :3], axis1=1, axis2=2) - 1) / 2,
                                          -1, 1)))
    assert 1.0 < np.max(angles) < 5.0 * math.sqrt(3) + 1e-9


def test_track_ids_follow_one_landmark_and_lifetimes_shorten_tracks(three: Robot) -> None:
    long = simulate(three, 60, seed=12)
    short = simulate(three, 60, seed=12, track_lifetime=5.0)
    for sim in (long, short):
        for cam in sim.sequence.cameras:
            ids = sim.sequence.tracks[cam].track_ids
            marks = sim.landmarks[cam]
            # Each track id belongs to exactly one landmark.
            pairs = np.unique(np.column_stack([ids, marks]), axis=0)
            assert len(pairs) == len(np.unique(ids))

    def mean_length(sim) -> float:
        trk = sim.sequence.tracks[0]
        return len(trk) / len(np.unique(trk.track_ids))

    assert mean_length(short) < 0.5 * mean_length(long)
    assert 3.0 < mean_length(short) < 7.0


def test_blackout_frames_see_nothing(three: Robot) -> None:
    sim = simulate(three, 300, seed=13, blackout_fraction=0.2)
    for cam in sim.sequence.cameras:
        counts = np.bincount(sim.sequence.tracks[cam].frames, minlength=300)
        assert 0.13 < np.mean(counts == 0) < 0.27


def test_model_mismatch_tracks_follow_the_true_segments(three: Robot) -> None:
    truth = [Segment(s.length, k=0.17, delta_max=0.3, theta_max=s.theta_max)
             for s in three.segments]
    sim = simulate(three, 20, noise_px=0.0, seed=14, truth_segments=truth)
    assert sim.sequence.robot == three  # the file keeps the model
    np.testing.assert_allclose(sim.world_T_tip, Robot(truth).forward(sim.sequence.thetas),
                               atol=1e-15)
    model_tips = three.forward(sim.sequence.thetas)
    assert np.max(np.abs(model_tips[..., :3, 3] - sim.world_T_tip[..., :3, 3])) > 1e-3
    assert np.max(np.abs(epipolar_residuals(sim, 2, 0, 5))) < 1e-9


def test_room_scene_points_lie_on_the_walls(three: Robot) -> None:
    sim = simulate(three, 5, seed=15, scene="room", room_half_size=(2.0, 3.0, 1.5))
    rel = np.abs(sim.points_world - [0.0, 0.0, 0.45])
    on_wall = np.isclose(rel, [2.0, 3.0, 1.5], atol=1e-12).any(axis=1)
    assert np.all(on_wall) and np.all(rel <= np.array([2.0, 3.0, 1.5]) + 1e-12)


def test_decimals_round_the_pixels(three: Robot) -> None:
    seq = simulate_sequence(three, 5, seed=16, decimals=2)
    uv = seq.tracks[0].uv
    np.testing.assert_allclose(uv * 100, np.round(uv * 100), atol=1e-6)


@pytest.mark.parametrize(
    ("kwargs", "fragment"),
    [
        ({"n_frames": 1}, "at least 2"),
        ({"noise_px": -1.0}, "noise_px"),
        ({"outlier_fraction": 1.0}, "outlier_fraction"),
        ({"blackout_fraction": -0.1}, "blackout_fraction"),
        ({"motion": "jerky"}, "motion"),
        ({"scene": "forest"}, "scene"),
        ({"fps": 0.0}, "fps"),
        ({"track_lifetime": 0.5}, "track_lifetime"),
        ({"depth_range": (2.0, 1.0)}, "depth_range"),
        ({"truth_segments": [Segment(0.3)]}, "truth_segments"),
        ({"decimals": -1}, "decimals"),
    ],
)
def test_bad_options_are_named(three: Robot, kwargs: dict, fragment: str) -> None:
    args = {"n_frames": 5} | kwargs
    n_frames = args.pop("n_frames")
    with pytest.raises(ValueError, match=fragment):
        simulate(three, n_frames, **args)


def test_robot_without_camera_is_refused() -> None:
    with pytest.raises(ValueError, match="no camera"):
        simulate(Robot([Segment(0.3)]), 5)
