"""The image-motion clock and the track cuts on it: still frames barely tick, a piece born while
the robot stands still lasts until it has moved, and the batch then knows those frames."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from apcc_graph.estimation.batch import batch_estimate
from apcc_graph.estimation.image_motion import STILL_TICK, motion_clock
from apcc_graph.estimation.options import GraphOptions
from apcc_graph.factors.track_points import cut_tracks
from apcc_graph.io.robot_file import load_robot
from apcc_graph.model.robot import Robot
from apcc_graph.simulation.faults import frozen_bends
from apcc_graph.simulation.simulator import Simulation, simulate

ROBOT = Path(__file__).resolve().parents[1] / "data/robots/planar_three.toml"
FROZEN = 30  # the robot stands still over frames 0 .. FROZEN - 1


@pytest.fixture(scope="module")
def robot() -> Robot:
    return load_robot(ROBOT)


@pytest.fixture(scope="module")
def still_start(robot: Robot) -> Simulation:
    """120 frames at 30 fps whose first 30 stand still (1 px, no outliers)."""
    moving = simulate(robot, 120, 1.0, 0.0, 3, scene="room", n_points=800)
    assert moving.sequence.thetas is not None
    bends = frozen_bends(moving.sequence.thetas, 0, FROZEN)
    return simulate(robot, 120, 1.0, 0.0, 3, scene="room", n_points=800, bends=bends)


def test_a_clock_cuts_pieces_by_its_ticks() -> None:
    frames = np.arange(200)
    ids = np.zeros(200, dtype=np.int64)
    assert np.array_equal(cut_tracks(frames, ids, 100), frames // 100)
    clock = np.concatenate([np.arange(100) * 0.25, 25.0 + np.arange(1, 101)])
    pieces = cut_tracks(frames, ids, 100, clock)
    # the clock reaches 100 ticks after the start at frame 174 (25 + 75)
    assert np.array_equal(pieces, (frames >= 174).astype(np.int64))
    assert np.array_equal(cut_tracks(frames, ids, 100, np.arange(200.0)), frames // 100)


@settings(max_examples=50, deadline=None)
@given(st.lists(st.integers(0, 5), min_size=1, max_size=60), st.integers(1, 20),
       st.lists(st.sampled_from([STILL_TICK, 1.0]), min_size=80, max_size=80))
def test_pieces_span_at_most_max_ticks(tracks: list[int], max_frames: int,
                                       ticks: list[float]) -> None:
    """Every piece spans fewer than ``max_frames`` ticks, belongs to one track, and pieces of
    one track follow each other in time."""
    rng = np.random.default_rng(len(tracks))
    frames = rng.integers(0, 80, len(tracks))
    ids = np.array(tracks, dtype=np.int64)
    clock = np.concatenate([[0.0], np.cumsum(ticks[1:])])
    pieces = cut_tracks(frames, ids, max_frames, clock)
    for piece in np.unique(pieces):
        rows = pieces == piece
        assert len(np.unique(ids[rows])) == 1
        assert np.ptp(clock[frames[rows]]) < max_frames
    for track in np.unique(ids):
        rows = np.flatnonzero(ids == track)
        order = rows[np.argsort(frames[rows], kind="stable")]
        assert np.all(np.diff(pieces[order]) >= 0)


def test_still_frames_barely_tick(still_start: Simulation) -> None:
    ticks = np.diff(motion_clock(still_start.sequence, 1.0))
    assert set(np.unique(ticks)) <= {STILL_TICK, 1.0}
    assert np.mean(ticks[:FROZEN - 1] == STILL_TICK) > 0.9  # measured 27 of 29
    assert np.mean(ticks[FROZEN + 5:] == 1.0) > 0.9


def test_the_batch_knows_the_still_frames_through_pieces_that_see_the_motion(
        still_start: Simulation) -> None:
    """With tracks cut every 20 frames, the pieces of the still frames see no parallax, and the
    frames after them were measured 2.4 degrees off on segment 1 (0.28 over the still frames);
    on the clock the pieces born still reach into the motion: 0.19-0.46 degree throughout."""
    seq = still_start.sequence
    assert seq.thetas is not None
    errors = {}
    for tick in (None, STILL_TICK):
        options = GraphOptions(max_track_frames=20, still_tick=tick,
                               theta0_sigma=math.radians(2.0))
        est = batch_estimate(seq, seq.thetas[0], options=options, marginals=False)
        errors[tick] = np.sqrt(np.mean((est.thetas - seq.thetas) ** 2, axis=0))
    assert errors[STILL_TICK][0] < 0.25 * errors[None][0], errors
    assert np.all(errors[STILL_TICK] < math.radians(0.8)), errors


def test_still_tick_is_checked() -> None:
    for bad in (0.0, -1.0, 1.5):
        with pytest.raises(ValueError, match="still_tick"):
            GraphOptions(still_tick=bad)
    assert GraphOptions(still_tick=None).still_tick is None
