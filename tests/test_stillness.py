"""A robot standing still: the motion test, the held frames' bookkeeping, and the projection
smoother over a recording in which the robot stops for longer than its lag."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from apcc_graph.estimation.smoother import FixedLagSmoother
from apcc_graph.estimation.smoother_options import FaultOptions, SmootherOptions
from apcc_graph.estimation.stillness import SPREAD_LIMIT, StillFrames, flow_statistics
from apcc_graph.estimation.window import SmootherFrame
from apcc_graph.io import load_robot
from apcc_graph.simulation import faults
from apcc_graph.simulation.simulator import simulate

ROBOT = Path(__file__).resolve().parents[1] / "data" / "robots" / "planar_three.toml"
CHI2 = 18.4  # the default: noise alone exceeds it with probability 1e-4


def _rows(xy: np.ndarray, ids: np.ndarray | None = None, cam: int = 0) -> dict:
    """One camera's rows with a whitening of 1 / (0.002 rad) (1 px at f = 500)."""
    ids = np.arange(len(xy)) if ids is None else ids
    return {cam: (ids, xy, np.repeat(np.eye(2)[None] * 500.0, len(xy), axis=0))}


def _noisy(points: np.ndarray, rng: np.random.Generator, outliers: float = 0.1) -> np.ndarray:
    out = points + rng.normal(0.0, 1.0 / 500.0, points.shape)
    bad = rng.random(len(points)) < outliers
    out[bad] = rng.uniform(-0.6, 0.6, (int(bad.sum()), 2))
    return out


@pytest.mark.parametrize("n", [30, 200])
def test_noise_alone_looks_still_and_a_small_common_shift_does_not(n: int) -> None:
    rng = np.random.default_rng(n)
    points = rng.uniform(-0.6, 0.6, (n, 2))
    coherent, spread = [], []
    for _ in range(300):
        stats = flow_statistics(_rows(_noisy(points, rng)), _rows(_noisy(points, rng)))
        coherent.append(stats[0][0])
        spread.append(stats[0][1])
    # about chi-square with 2 degrees of freedom (median 1.39) despite 10% outliers
    assert 0.9 < np.median(coherent) < 2.2 and np.mean(np.array(coherent) > CHI2) < 0.01
    assert np.mean(np.array(spread) > SPREAD_LIMIT) < 0.01
    # every point moved by 2 px in x and y (30 tracks), less with more tracks
    shift = 2.0 * math.sqrt(30.0 / n) / 500.0  # as detectable with few tracks as with many
    moved = [flow_statistics(_rows(_noisy(points, rng)), _rows(_noisy(points + shift, rng)))
             [0][0] for _ in range(50)]
    assert np.mean(np.array(moved) > CHI2) > 0.9


def test_a_roll_about_the_optical_axis_is_motion() -> None:
    rng = np.random.default_rng(3)
    points = rng.uniform(-0.6, 0.6, (200, 2))
    c, s = math.cos(0.02), math.sin(0.02)  # 1.1 deg: points move by up to 8 px, mean zero
    rolled = points @ np.array([[c, -s], [s, c]]).T
    coherent, spread = flow_statistics(_rows(_noisy(points, rng)),
                                       _rows(_noisy(rolled, rng)))[0]
    assert coherent < CHI2 and spread > SPREAD_LIMIT


def test_cameras_with_too_few_common_tracks_take_no_part() -> None:
    rng = np.random.default_rng(4)
    points = rng.uniform(-0.6, 0.6, (20, 2))
    a = _rows(points)
    b = _rows(_noisy(points, rng), ids=np.arange(20) + 15)  # 5 tracks in common
    assert flow_statistics(a, b, min_tracks=8) == {}
    assert set(flow_statistics(a, b, min_tracks=5)) == {0}
    assert flow_statistics(a, _rows(points, cam=1)) == {}


def _frame(slot: int, t: float) -> SmootherFrame:
    return SmootherFrame(slot, t, np.full(2, float(slot)), np.full(2, 0.1),
                         np.array(["ok", "ok"], dtype="<U24"))


def test_still_frames_are_held_after_settling_and_stand_for_their_slot() -> None:
    rng = np.random.default_rng(5)
    points = rng.uniform(-0.6, 0.6, (100, 2))
    still = StillFrames(settle=3, chi2=CHI2)
    slot, held, dt = 0, [], 1.0 / 30.0
    for frame in range(12):  # moving: 0..2; still from 3 (the anchor) to 9; moving again 10, 11
        shift = 0.01 * min(frame, 3) + (0.01 * (frame - 9) if frame > 9 else 0.0)
        t = frame * dt
        if still.hold(_rows(_noisy(points + shift, rng, 0.0)), None, slot, t):
            held.append(frame)
        else:
            slot += 1
    # 3 is the anchor; 4, 5, 6 settle (they enter); 7, 8, 9 are held; 10 moves
    assert held == [7, 8, 9] and slot == 9 and still.count == 12
    assert still.paused == pytest.approx(3 * dt)
    out = still.expand([_frame(g, g * dt) for g in range(slot)])
    assert [f.frame for f in out] == list(range(12))
    assert [f.status[0] for f in out] == ["ok"] * 7 + ["still"] * 3 + ["ok"] * 2
    assert all(f.timestamp == pytest.approx(f.frame * dt) for f in out)
    assert all(out[f].thetas[0] == 6.0 for f in (6, 7, 8, 9))  # the slot of frame 6
    assert out[10].thetas[0] == 7.0


def test_nothing_is_held_when_the_base_moves_the_slot_left_or_holding_is_off() -> None:
    rng = np.random.default_rng(6)
    points = rng.uniform(-0.6, 0.6, (100, 2))
    for still, bases, can_hold in [
            (StillFrames(settle=0), [np.eye(4), np.eye(4) * 1.0 + np.eye(4, k=3) * 0.01], True),
            (StillFrames(settle=0), [None, None], False),
            (StillFrames(settle=math.inf), [None, None], True)]:
        results = []
        for f in range(6):
            base = bases[f % 2]
            results.append(still.hold(_rows(_noisy(points, rng, 0.0)), base, f, f / 30.0,
                                      can_hold))
        assert not any(results)


def test_options_refuse_a_bad_stillness_setting() -> None:
    with pytest.raises(ValueError, match="FaultOptions.still_frames = -1"):
        FaultOptions(still_frames=-1)
    with pytest.raises(ValueError, match="FaultOptions.still_chi2 = 0.0"):
        FaultOptions(still_chi2=0.0)
    assert FaultOptions(still_frames=None).still_frames is None


@pytest.fixture(scope="module")
def frozen() -> tuple:
    """120 frames at 30 fps, the robot still in frames 40..100 (twice the 1 s lag)."""
    robot = load_robot(ROBOT)
    clean = simulate(robot, 120, noise_px=1.0, outlier_fraction=0.05, seed=2, fps=30.0)
    bends = faults.frozen_bends(clean.sequence.thetas, 40, 60)
    sim = simulate(robot, 120, noise_px=1.0, outlier_fraction=0.05, seed=2, fps=30.0,
                   bends=bends)
    return robot, sim.sequence


def _run(robot, seq, **options) -> tuple[list[SmootherFrame], list[SmootherFrame], int]:
    smoother = FixedLagSmoother(robot, lag=1.0, theta0=seq.thetas[0],
                                settings=SmootherOptions(faults=FaultOptions(**options)))
    now, popped = [], []
    for f in range(seq.n_frames):
        now.append(smoother.update(seq.frame(f)))
        popped += smoother.pop_final()
    assert smoother.n_frames == seq.n_frames
    return now, popped + smoother.finish(), smoother.recoveries


def test_the_smoother_holds_a_still_robot_and_returns_every_frame(frozen: tuple) -> None:
    robot, seq = frozen
    now, final, recoveries = _run(robot, seq)
    assert recoveries == 0
    assert [f.frame for f in now] == list(range(seq.n_frames))
    assert [f.frame for f in final] == list(range(seq.n_frames))
    assert np.allclose([f.timestamp for f in final], seq.timestamps)
    held = [f.frame for f in final if f.status[0] == "still"]
    # frames 40..100 show one configuration: 40 is the anchor, 10 settle, the rest are held
    assert held == list(range(51, 101))
    errors = np.array([f.thetas for f in final]) - seq.thetas
    sigmas = np.array([f.sigmas for f in final])
    assert np.all(np.abs(errors) < 4.0 * sigmas), np.degrees(np.abs(errors).max(axis=0))
    assert np.degrees(np.abs(errors)).max() < 0.5


def test_without_holding_no_frame_is_still(frozen: tuple) -> None:
    robot, seq = frozen
    _, final, _ = _run(robot, seq, still_frames=None)
    assert [f.frame for f in final] == list(range(seq.n_frames))
    assert not any(f.status[0] == "still" for f in final)


def test_tracks_returned_only_after_a_frame_without_tracks_and_only_new_ones() -> None:
    from apcc_graph.estimation.blackout import tracks_returned

    rows = _rows(np.zeros((5, 2)), ids=np.arange(10, 15))
    nothing_known = lambda cam, ids: np.zeros(len(ids), dtype=bool)  # noqa: E731
    one_known = lambda cam, ids: ids == 12  # noqa: E731
    assert tracks_returned(rows, {}, nothing_known)
    assert not tracks_returned(rows, {}, one_known)  # a track goes on: tied to the window
    assert not tracks_returned(rows, rows, nothing_known)  # the previous frame had tracks
    assert not tracks_returned({}, {}, nothing_known)  # still blind


def test_a_recording_that_starts_without_tracks_is_no_blackout(frozen: tuple) -> None:
    import warnings

    from apcc_graph.estimation.blackout import BlackoutWarning
    from apcc_graph.model.sequence import FrameObservations

    robot, seq = frozen
    smoother = FixedLagSmoother(robot, lag=1.0, theta0=seq.thetas[0])
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        for f in range(3):  # the cameras warm up: nothing tracked yet
            smoother.update(FrameObservations(seq.timestamps[f], {}))
        for f in range(3, 8):
            smoother.update(seq.frame(f))
        smoother.update(FrameObservations(seq.timestamps[8], {}))  # a dropped frame, then
        smoother.update(seq.frame(9))  # the same tracks: still no blackout
    assert not [w for w in caught if issubclass(w.category, BlackoutWarning)]
