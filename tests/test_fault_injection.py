"""The fault injections, the frame-by-frame stream and the recovery measures: the tools of the
reliability suite must themselves be right, or its figures mean nothing."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from apcc_graph.evaluation.recovery import moving_rms, recovery_frames, sigma_honesty
from apcc_graph.evaluation.sequence_bound import sequence_bound
from apcc_graph.io import load_robot
from apcc_graph.simulation import faults
from apcc_graph.simulation.simulator import Simulation, simulate
from apcc_graph.simulation.stream import SimulatedStream

ROBOT = Path(__file__).resolve().parents[1] / "data" / "robots" / "planar_three.toml"


@pytest.fixture(scope="module")
def sim() -> Simulation:
    return simulate(load_robot(ROBOT), 60, noise_px=1.0, outlier_fraction=0.1, seed=4,
                    scene="room", n_points=1500)


def _truth_consistent(s: Simulation) -> None:
    """Every row's truth describes it: inliers lie within noise of their clean pixel."""
    for cam, t in s.sequence.tracks.items():
        n = len(t)
        assert len(s.landmarks[cam]) == len(s.clean_uv[cam]) == len(s.outliers[cam]) == n
        inlier = ~s.outliers[cam]
        assert np.all(np.abs(t.uv[inlier] - s.clean_uv[cam][inlier]) < 6.0)
        order = np.lexsort((t.track_ids, t.frames))
        assert np.array_equal(order, np.arange(n))


def test_blind_cameras_see_nothing_and_come_back_with_new_ids(sim: Simulation) -> None:
    out = faults.blind(sim, [0, 2], 20, 30)
    _truth_consistent(out)
    for cam in (0, 2):
        before, after = sim.sequence.tracks[cam], out.sequence.tracks[cam]
        assert not np.any((after.frames >= 20) & (after.frames < 30))
        assert len(after) == np.sum((before.frames < 20) | (before.frames >= 30))
        ids_before = set(after.track_ids[after.frames < 20].tolist())
        assert ids_before.isdisjoint(after.track_ids[after.frames >= 30].tolist())
    assert out.sequence.tracks[1].equals(sim.sequence.tracks[1])
    # frames no camera saw have no bound; the others keep a finite one
    bound = sequence_bound(faults.blind(sim, [0, 1, 2], 20, 30), 1.0).sigmas
    assert np.all(np.isinf(bound[21:29])) and np.all(np.isfinite(bound[:20]))


def test_blind_cameras_that_keep_their_ids(sim: Simulation) -> None:
    """A re-identifying front end: the same rows as with new ids; each point tracked in the
    last frame before the gap comes back under its old track's id (also one that left the view
    during the gap, which the simulation gave a new track); the other tracks keep theirs."""
    start, stop = 20, 40
    new = faults.blind(sim, [0], start, stop)
    kept = faults.blind(sim, [0], start, stop, keep_ids=True)
    _truth_consistent(kept)
    before, t_kept = sim.sequence.tracks[0], kept.sequence.tracks[0]
    outside = (before.frames < start) | (before.frames >= stop)
    assert np.array_equal(t_kept.frames, before.frames[outside])
    np.testing.assert_array_equal(t_kept.uv, before.uv[outside])
    np.testing.assert_array_equal(kept.landmarks[0], new.landmarks[0])
    points = kept.landmarks[0]
    last = t_kept.frames == start - 1
    tracked = dict(zip(points[last].tolist(), t_kept.track_ids[last].tolist(), strict=True))
    later = t_kept.frames >= stop
    reidentified = 0
    for point, old in tracked.items():
        rows = later & (points == point)
        if not rows.any():
            continue
        first = np.flatnonzero(rows)[0]
        original = before.track_ids[outside][first]  # the simulation's id of that track
        assert t_kept.track_ids[first] == old
        same_track = later & (before.track_ids[outside] == original)
        assert np.all(t_kept.track_ids[same_track] == old)
        reidentified += int(original != old)
    assert reidentified > 0  # points that left the view in the gap and came back
    for f in np.unique(t_kept.frames).tolist():  # one row per track and frame
        ids = t_kept.track_ids[t_kept.frames == f]
        assert len(np.unique(ids)) == len(ids)
    # with new ids no point comes back under an id it had
    t_new = new.sequence.tracks[0]
    assert set(t_new.track_ids[t_new.frames < start].tolist()).isdisjoint(
        t_new.track_ids[t_new.frames >= stop].tolist())
    assert kept.sequence.tracks[1].equals(sim.sequence.tracks[1])


def test_a_camera_removed_and_the_bound_of_its_segment(sim: Simulation) -> None:
    out = faults.without_camera(sim, 1)
    assert 1 not in out.sequence.tracks
    _truth_consistent(out)
    worse = np.median(sequence_bound(out, 1.0).sigmas, axis=0)
    clean = np.median(sequence_bound(sim, 1.0).sigmas, axis=0)
    assert worse[1] > 2.0 * clean[1]  # segment 2 now rests on camera 3 alone
    assert np.isfinite(worse[1])


def test_a_paused_simulation_drops_the_frames_and_their_truth(sim: Simulation) -> None:
    out = faults.paused(sim, 20, 35)
    _truth_consistent(out)
    assert out.sequence.n_frames == sim.sequence.n_frames - 15
    np.testing.assert_array_equal(out.sequence.timestamps[19:21],
                                  sim.sequence.timestamps[[19, 35]])
    np.testing.assert_array_equal(out.world_T_tip[20], sim.world_T_tip[35])
    for cam, poses in out.world_T_cam.items():
        np.testing.assert_array_equal(poses[20], sim.world_T_cam[cam][35])
    for cam, t in out.sequence.tracks.items():  # row by row, the same observation and truth
        was = sim.sequence.tracks[cam]
        rows = (was.frames < 20) | (was.frames >= 35)
        np.testing.assert_array_equal(t.uv, was.uv[rows])
        np.testing.assert_array_equal(out.landmarks[cam], sim.landmarks[cam][rows])
    # the bound of the paused recording: every frame after the pause is still seen
    assert np.all(np.isfinite(sequence_bound(out, 1.0).sigmas[20:]))
    with pytest.raises(ValueError, match="frames before and after"):
        faults.paused(sim, 0, 10)


def test_an_outlier_burst_marks_the_fraction_asked(sim: Simulation) -> None:
    out = faults.outlier_burst(sim, 1, 10, 40, fraction=0.5, seed=1)
    _truth_consistent(out)
    t = out.sequence.tracks[1]
    inside = (t.frames >= 10) & (t.frames < 40)
    assert abs(out.outliers[1][inside].mean() - 0.5) < 0.01
    assert np.array_equal(out.outliers[1][~inside], sim.outliers[1][~inside])


def test_swapped_ids_exchange_pixels_then_return(sim: Simulation) -> None:
    out = faults.swapped_ids(sim, 0, 20, 25, fraction=0.2, seed=2)
    _truth_consistent(out)
    before, after = sim.sequence.tracks[0], out.sequence.tracks[0]
    swapped = out.outliers[0] & ~sim.outliers[0]
    assert swapped.sum() >= 2 * 5
    assert np.all((after.frames[swapped] >= 20) & (after.frames[swapped] < 25))
    # a swapped row shows another track's point than its id's
    outside = (before.frames < 20) | (before.frames >= 25)
    assert np.array_equal(after.track_ids[outside], before.track_ids[outside])
    with pytest.raises(ValueError, match="too few to swap"):
        faults.swapped_ids(sim, 0, 20, 25, fraction=1e-4)


def test_frozen_and_jumped_motions() -> None:
    thetas = np.linspace(0.0, 0.5, 40)[:, None] * np.ones((1, 3))
    frozen = faults.frozen_bends(thetas, 10, 15)
    assert np.all(frozen[10:25] == thetas[10])
    assert np.array_equal(frozen[25:], thetas[10:25])  # resumes where it stopped
    jumped = faults.jumped_bends(thetas, 20, 1, 10.0, math.radians(60.0))
    assert np.allclose(jumped[20:, 1] - thetas[20:, 1], math.radians(10.0))
    assert np.array_equal(jumped[:20], thetas[:20]) and np.array_equal(jumped[:, 0], thetas[:, 0])
    down = faults.jumped_bends(thetas, 20, 1, 10.0, math.radians(30.0))  # would pass theta_max
    assert np.allclose(down[20:, 1] - thetas[20:, 1], -math.radians(10.0))
    with pytest.raises(ValueError, match="frame = 0"):
        faults.jumped_bends(thetas, 0, 1, 10.0, 1.0)


def test_simulate_takes_given_bends_and_keeps_the_rest_of_the_draws(sim: Simulation) -> None:
    robot = load_robot(ROBOT)
    same = simulate(robot, 60, noise_px=1.0, outlier_fraction=0.1, seed=4, scene="room",
                    n_points=1500, bends=sim.sequence.thetas)
    assert same.sequence.equals(sim.sequence)
    with pytest.raises(ValueError, match="segment 2 reaches 70.0 deg"):
        bends = sim.sequence.thetas.copy()
        bends[5, 1] = math.radians(70.0)
        simulate(robot, 60, seed=4, bends=bends)
    with pytest.raises(ValueError, match=r"expected \(60, 3\)"):
        simulate(robot, 60, seed=4, bends=np.zeros((59, 3)))


def test_the_stream_is_seeded_continuous_and_keeps_no_history() -> None:
    robot = load_robot(ROBOT)
    a, b = SimulatedStream(robot, seed=7), SimulatedStream(robot, seed=7)
    frames_a = [a.next_frame() for _ in range(40)]
    frames_b = [b.next_frame() for _ in range(40)]
    for (obs_a, th_a), (obs_b, th_b) in zip(frames_a, frames_b, strict=True):
        assert np.array_equal(th_a, th_b)
        for cam in obs_a.tracks:
            assert np.array_equal(obs_a.tracks[cam][1], obs_b.tracks[cam][1])
    thetas = np.array([th for _, th in frames_a])
    assert np.max(np.abs(np.diff(thetas, axis=0))) < math.radians(2.0)  # smooth at 30 fps
    assert np.allclose(a.thetas(np.arange(40)), thetas)
    obs, _ = frames_a[-1]
    for cam, (ids, uv) in obs.tracks.items():
        assert np.all(np.diff(ids) > 0)  # sorted, unique
        camera = robot.cameras[cam]
        assert camera is not None and np.all(camera.in_image(uv))
        # tracks continue: most ids of the last frame were seen in the one before
        assert np.isin(ids, frames_a[-2][0].tracks[cam][0]).mean() > 0.8
    sizes = {cam: len(v) for cam, v in a._ids.items()}
    for _ in range(100):
        a.next_frame()
    assert {cam: len(v) for cam, v in a._ids.items()} == sizes


def test_moving_rms_and_recovery_frames() -> None:
    err = np.full((100, 2), 0.1)
    assert np.allclose(moving_rms(err, 10), 0.1)
    assert moving_rms(err[:5], 10).shape == (0, 2)
    calm = np.full((100, 2), 0.1)
    assert recovery_frames(err, calm, 20) == 0
    late = err.copy()
    late[20:45, 1] = 1.0  # still off for 25 frames after the fault ends at 20
    assert recovery_frames(late, calm, 20) == 25
    never = err.copy()
    never[90:, 0] = 5.0
    assert recovery_frames(never, calm, 20) is None
    # against a level (a recording simulated anew): the undisturbed run's windows are not
    # consulted; where they are high, its frames would excuse the faulted run's error there
    rough, bumpy = calm.copy(), err.copy()
    rough[40:60], bumpy[40:60] = 1.0, 0.5
    assert recovery_frames(bumpy, rough, 20) == 0
    # the last window with two frames of the bump (frames 58, 59) starts 38 frames after 20
    assert recovery_frames(bumpy, None, 20, level=np.array([0.1, 0.1])) == 39
    assert recovery_frames(err, None, 20, level=np.array([0.1, 0.1])) == 0
    assert recovery_frames(late, None, 20, level=np.array([0.1, 0.1])) == 25
    assert recovery_frames(err, None, 20, level=np.array([0.04, 0.1])) is None
    with pytest.raises(ValueError, match="undisturbed errors or their level"):
        recovery_frames(err, None, 20)


def test_sigma_honesty() -> None:
    rng = np.random.default_rng(0)
    sig = np.full((4000, 2), 0.5)
    z2, inside = sigma_honesty(rng.normal(0.0, 0.5, (4000, 2)), sig)
    assert np.all(np.abs(z2 - 1.0) < 0.1) and np.all(inside > 0.99)
    z2, inside = sigma_honesty(rng.normal(0.0, 5.0, (4000, 2)), sig)
    assert np.all(z2 > 50) and np.all(inside < 0.4)
    z2, _ = sigma_honesty(np.ones((3, 1)), np.full((3, 1), np.nan))
    assert np.isnan(z2[0])
