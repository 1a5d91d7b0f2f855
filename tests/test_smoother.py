"""The experimental projection smoother and its parts: the live-track bookkeeping, the new
frame's initial guess, and the smoother itself on small room-scene simulations.

Every simulation uses a fixed seed; the figures quoted next to the assertions were measured on
commit e8f4598 (degrees unless stated).
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from helpers import random_pose
from hypothesis import given, settings
from hypothesis import strategies as st

import apcc_graph
from apcc_graph.estimation.batch import batch_estimate
from apcc_graph.estimation.front_end import FramePairs, chained_guess
from apcc_graph.estimation.initial_guess import (
    FrameRows,
    frame_poses,
    predict,
    refine,
    row_inliers,
)
from apcc_graph.estimation.live_tracks import LiveTracks
from apcc_graph.estimation.options import BatchOptions, GraphOptions
from apcc_graph.estimation.smoother import FixedLagSmoother
from apcc_graph.estimation.smoother_options import (
    LandmarkOptions,
    SmootherOptions,
    TrackOptions,
    WindowOptions,
)
from apcc_graph.estimation.smoother_runs import smoother_estimate
from apcc_graph.estimation.window import RestartWarning, SmootherFrame
from apcc_graph.evaluation.sequence_bound import sequence_bound
from apcc_graph.io.robot_file import load_robot
from apcc_graph.model.parameterisation import Bending
from apcc_graph.model.robot import Robot
from apcc_graph.model.sequence import FrameObservations, Sequence
from apcc_graph.simulation.simulator import Simulation, simulate

REPO = Path(__file__).resolve().parents[1]
ROBOT = REPO / "data/robots/planar_three.toml"


def PLANAR(robot: Robot) -> Bending:  # noqa: N802 - reads as the parameterisation's name
    """A planar robot's parameterisation: its angles in the planes psi = 0."""
    return Bending.fixed(robot.segments)


def refine_planar(prediction: np.ndarray, robot: Robot, rows: list[FrameRows],
                  threshold: float, **keywords: int):
    """:func:`refine` of a planar robot whose base is the world frame."""
    return refine(prediction, robot, PLANAR(robot), None, rows, threshold, **keywords)


def one_point_guess(previous: np.ndarray, prediction: np.ndarray, robot: Robot,
                    base_previous: np.ndarray | None, base_now: np.ndarray | None,
                    pairs: list[FramePairs], threshold_px: float
                    ) -> tuple[np.ndarray, dict[int, np.ndarray]]:
    """The front end with the 1-point solver; the inlier masks of the cameras that solved."""
    x, infos = chained_guess(previous, prediction, robot, PLANAR(robot), base_previous,
                             base_now, pairs, threshold_px)
    return x, {cam: info.inliers for cam, info in infos.items() if info.success}


@pytest.fixture(scope="module")
def robot() -> Robot:
    return load_robot(ROBOT)


def room(robot: Robot, n_frames: int, noise_px: float, seed: int = 1) -> Simulation:
    return simulate(robot, n_frames, noise_px, 0.0, seed, scene="room", n_points=4000, fps=30)


def deg(x: np.ndarray | float) -> np.ndarray:
    return np.degrees(np.asarray(x, dtype=float))


def thetas(frames: list[SmootherFrame]) -> np.ndarray:
    return np.array([fr.thetas for fr in frames])


def blank(obs: FrameObservations) -> FrameObservations:
    """The frame with every camera's tracks removed."""
    return FrameObservations(obs.timestamp, {}, obs.world_T_base)


# ================================================================ 1. LiveTracks bookkeeping
def rows_of(ids: list[int], frame: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Track ids, xy and whitening of one synthetic frame: ``xy = (frame, track id)`` so that a
    committed row tells where it came from."""
    ids_arr = np.asarray(ids, dtype=np.int64)
    xy = np.column_stack([np.full(len(ids), float(frame)), ids_arr.astype(float)])
    return ids_arr, xy, np.tile(np.eye(2), (len(ids), 1, 1))


def committed(obs) -> list[tuple[int, int, int]]:  # noqa: ANN001
    """(piece id, frame, track id) of every committed row (track id read back from xy)."""
    return [(int(obs.ids[t]), int(f), int(xy[1]))
            for t, f, xy in zip(obs.tracks, obs.frames, obs.xy, strict=True)]


def test_a_track_that_ends_is_committed_with_all_its_rows_and_a_seen_one_is_not() -> None:
    live = LiveTracks((0,), max_frames=100, min_rows=2)
    for f in range(5):
        assert live.take_due(f, {0: np.array([7, 8])}, leaving_before=0) == {}
        live.add(f, 0, *rows_of([7, 8], f))
    piece7, piece8 = live.piece_ids(0, np.array([7, 8]))
    out = live.take_due(5, {0: np.array([8])}, leaving_before=0)
    assert sorted(out) == [0]
    obs = out[0]
    assert len(obs) == 5 and obs.n_tracks == 1
    assert committed(obs) == [(piece7, f, 7) for f in range(5)]
    # Track 8 is still seen: not committed, still live under the same piece.
    assert live.piece_ids(0, np.array([7, 8])).tolist() == [-1, piece8]
    live.add(5, 0, *rows_of([8], 5))
    rest = live.take_all()
    assert committed(rest[0]) == [(piece8, f, 8) for f in range(6)]
    assert live.take_all() == {}  # nothing is committed twice
    # After take_all a track seen again starts a new piece.
    assert live.piece_ids(0, np.array([8])).tolist() == [-1]
    assert live.take_due(6, {0: np.array([8])}, leaving_before=0) == {}
    live.add(6, 0, *rows_of([8], 6))
    assert live.piece_ids(0, np.array([8]))[0] not in (-1, piece7, piece8)


def test_vouched_pieces_join_the_live_factor_early_and_lose_it_with_an_unchecked_row() -> None:
    """A piece joins ``live_rows`` at 4 rows, or at 2 when the front end accepted its pair; a
    vouched piece whose new row the front end did not accept leaves, and forgets its point so
    that all its rows are decided again once it is long enough."""
    live = LiveTracks((0,), max_frames=100, min_rows=2)

    def live_pieces() -> list[int]:
        found = live.live_rows(0, 4)
        return [] if found is None else sorted(set(found[0].ids.tolist()))

    live.add(0, 0, *rows_of([1, 2, 3], 0))
    live.vouch(0, {})
    live.add(1, 0, *rows_of([1, 2, 3], 1))
    live.vouch(1, {0: np.array([1, 2])})  # track 3's pair was an outlier of the consensus
    p1, p2, p3 = live.piece_ids(0, np.array([1, 2, 3])).tolist()
    assert live_pieces() == sorted([p1, p2])
    assert live.lengths(0, np.array([p1, p3, -1])).tolist() == [2, 2, 0]
    live.points(0)[p1] = np.ones(3)
    live.points(0)[p2] = np.ones(3)
    live.add(2, 0, *rows_of([1, 2, 3], 2))
    live.vouch(2, {0: np.array([1, 3])})  # 2's new row unchecked; 3 was never vouched
    assert live_pieces() == [p1]
    assert p2 not in live.points(0) and p1 in live.points(0)
    live.add(3, 0, *rows_of([1, 2, 3], 3))
    live.vouch(3, {})  # no front end: 4 rows are needed again
    assert live_pieces() == sorted([p1, p2, p3])
    assert p1 not in live.points(0)
    # A vouched piece that is committed is forgotten with its vouching.
    live.add(4, 0, *rows_of([4], 4))
    live.vouch(4, {0: []})
    live.add(5, 0, *rows_of([4], 5))
    live.vouch(5, {0: np.array([4])})
    (p4,) = live.piece_ids(0, np.array([4])).tolist()
    assert p4 in live_pieces()
    live.take_all()
    assert live_pieces() == []


def test_a_piece_leaving_the_window_is_committed_and_the_track_starts_a_new_piece() -> None:
    live = LiveTracks((0,), max_frames=100, min_rows=2)
    for f in range(4):
        live.add(f, 0, *rows_of([3], f))
    old = int(live.piece_ids(0, np.array([3]))[0])
    live.points(0)[old] = np.ones(3)
    # Frame 0 leaves the window at frame 4: the piece (frames 0..3) is committed although the
    # track is still seen ...
    out = live.take_due(4, {0: np.array([3])}, leaving_before=1)
    assert committed(out[0]) == [(old, f, 3) for f in range(4)]
    assert old not in live.points(0)  # its cached point is forgotten with it
    live.drop_frames_before(1)
    # ... and the track's next observation starts a new piece with a new id.
    live.add(4, 0, *rows_of([3], 4))
    new = int(live.piece_ids(0, np.array([3]))[0])
    assert new != old and new >= 0
    live.add(5, 0, *rows_of([3], 5))
    assert committed(live.take_all()[0]) == [(new, 4, 3), (new, 5, 3)]


def test_max_frames_cuts_pieces() -> None:
    live = LiveTracks((0,), max_frames=3, min_rows=1)
    pieces = []
    for f in range(8):
        for obs in live.take_due(f, {0: np.array([5])}, leaving_before=0).values():
            pieces.append(committed(obs))
        live.add(f, 0, *rows_of([5], f))
    pieces += [committed(obs) for obs in live.take_all().values()]
    frames = [[f for _, f, _ in rows] for rows in pieces]
    assert frames == [[0, 1, 2], [3, 4, 5], [6, 7]]
    assert len({rows[0][0] for rows in pieces}) == 3  # three pieces, three ids


def test_pieces_shorter_than_min_rows_are_dropped() -> None:
    live = LiveTracks((0,), max_frames=100, min_rows=3)
    live.add(0, 0, *rows_of([1, 2], 0))
    live.add(1, 0, *rows_of([1, 2], 1))
    assert live.take_due(2, {0: np.array([2])}, leaving_before=0) == {}  # track 1: 2 rows
    live.add(2, 0, *rows_of([2], 2))
    # A camera that saw nothing ends no track; a frame with another track ends track 2.
    assert live.take_due(3, {0: np.array([], dtype=np.int64)}, leaving_before=0) == {}
    assert live.take_due(3, {0: np.array([9])}, leaving_before=0)[0].n_tracks == 1
    # Nothing of track 1 comes back later.
    assert live.take_all() == {}


def name(frames: np.ndarray, track_ids: np.ndarray) -> np.ndarray:
    """A weight that names its row: frame / 10 + track id / 1000."""
    return frames / 10.0 + track_ids / 1000.0


def test_set_weights_writes_to_the_right_rows() -> None:
    live = LiveTracks((0, 2), max_frames=100, min_rows=2)
    # Camera 2's track 3 ends at frame 3: its rows stay in the buffer until their frames leave.
    streams = {0: [[4, 1, 9], [9, 4, 1], [1, 4, 9, 6], [6, 9, 4, 1]],
               2: [[2, 3], [3, 2, 5], [5, 3, 2], [2, 5]]}
    for f in range(4):
        seen = {cam: np.array(s[f], dtype=np.int64) for cam, s in streams.items()}
        live.take_due(f, seen, leaving_before=0)
        for cam, s in streams.items():
            ids, xy, whiten = rows_of(s[f], f)
            live.add(f, cam, ids, xy, whiten, name(np.full(len(ids), f), ids))
    for cam in (0, 2):
        obs, weights, index = live.live_rows(cam)
        tracks = obs.xy[:, 1]
        # The first decisions (given to add) come back with their rows ...
        np.testing.assert_array_equal(weights, name(obs.frames, tracks))
        # ... and so do new ones.
        pick = np.arange(len(obs)) % 2 == 0
        live.set_weights(cam, index[pick], 1.0 + name(obs.frames, tracks)[pick])
        again, new_weights, _ = live.live_rows(cam)
        np.testing.assert_array_equal(again.frames, obs.frames)
        np.testing.assert_array_equal(again.xy, obs.xy)
        np.testing.assert_array_equal(new_weights, name(obs.frames, tracks) + pick)
    assert sorted(set(live.live_rows(2)[0].xy[:, 1].astype(int).tolist())) == [2, 5]
    # live_rows(cam, n): only pieces seen in at least n frames.
    obs, _, _ = live.live_rows(0, 3)
    assert sorted(set(obs.xy[:, 1].astype(int).tolist())) == [1, 4, 9]


def reference_pieces(streams: dict[int, list[list[int]]], window: int, max_frames: int
                     ) -> tuple[list[dict[int, list[tuple[int, int, int]]]],
                                dict[int, list[tuple[int, int, int]]]]:
    """What LiveTracks should commit: per take_due call, camera -> (piece, frame, track) rows
    of the pieces due (all their rows, before the min_rows filter), and what take_all commits.
    Piece ids are handed out in the order of ``add`` (cameras in the order of ``streams``)."""
    n_frames = len(next(iter(streams.values())))
    live: dict[int, dict[int, tuple[int, int]]] = {c: {} for c in streams}
    rows: dict[int, list[tuple[int, int, int]]] = {}
    next_piece = 0
    calls = []
    for f in range(n_frames):
        leaving_before = max(0, f - window)
        due_now: dict[int, list[tuple[int, int, int]]] = {}
        for cam, stream in streams.items():
            for tid, (piece, first) in list(live[cam].items()):
                # A camera that sees nothing in a frame ends no track.
                ended = bool(stream[f]) and tid not in stream[f]
                if ended or first < leaving_before or f - first >= max_frames:
                    due_now.setdefault(cam, []).extend(rows.pop(piece))
                    del live[cam][tid]
        calls.append(due_now)
        for cam, stream in streams.items():
            for tid in stream[f]:
                if tid not in live[cam]:
                    live[cam][tid] = (next_piece, f)
                    rows[next_piece] = []
                    next_piece += 1
                rows[live[cam][tid][0]].append((live[cam][tid][0], f, tid))
    final = {cam: [r for piece, _ in pieces.values() for r in rows[piece]]
             for cam, pieces in live.items()}
    return calls, final


def long_enough(rows: list[tuple[int, int, int]], min_rows: int) -> list[tuple[int, int, int]]:
    counts: dict[int, int] = {}
    for piece, _, _ in rows:
        counts[piece] = counts.get(piece, 0) + 1
    return sorted(r for r in rows if counts[r[0]] >= min_rows)


frame_ids = st.lists(st.integers(0, 5), unique=True, max_size=6)


@settings(max_examples=60, deadline=None)
@given(stream0=st.lists(frame_ids, min_size=1, max_size=14), data=st.data(),
       window=st.integers(1, 6), max_frames=st.integers(1, 7), min_rows=st.integers(1, 3))
def test_random_streams_commit_every_observation_exactly_once(
        stream0: list[list[int]], data: st.DataObject, window: int, max_frames: int,
        min_rows: int) -> None:
    stream2 = data.draw(st.lists(frame_ids, min_size=len(stream0), max_size=len(stream0)))
    streams = {0: stream0, 2: stream2}
    live = LiveTracks((0, 2), max_frames=max_frames, min_rows=min_rows)
    got: dict[int, list[tuple[int, int, int]]] = {0: [], 2: []}
    calls, final = reference_pieces(streams, window, max_frames)
    for f in range(len(stream0)):
        leaving_before = max(0, f - window)
        out = live.take_due(f, {c: np.asarray(s[f], dtype=np.int64) for c, s in streams.items()},
                            leaving_before)
        for cam in (0, 2):
            want = long_enough(calls[f].get(cam, []), min_rows)
            rows = sorted(committed(out[cam])) if cam in out else []
            assert rows == want, f"frame {f}, camera {cam}"
            assert (cam in out) == bool(want)  # no empty entries
            got[cam] += rows
        live.drop_frames_before(leaving_before)  # as the smoother does: all committed by now
        for cam, stream in streams.items():
            live.add(f, cam, *rows_of(stream[f], f))
    out = live.take_all()
    for cam in (0, 2):
        rows = sorted(committed(out[cam])) if cam in out else []
        assert rows == long_enough(final[cam], min_rows)
        got[cam] += rows
    assert live.take_all() == {}
    for cam, stream in streams.items():
        seen = [(f, tid) for f, ids in enumerate(stream) for tid in ids]
        pairs = [(f, tid) for _, f, tid in got[cam]]
        assert len(pairs) == len(set(pairs))  # each observation at most once
        if min_rows == 1:
            assert sorted(pairs) == sorted(seen)  # ... and every one of them
        else:
            assert set(pairs) <= set(seen)


# ================================================================= 2. the initial guess
def test_frame_poses_equal_forward_kinematics_and_their_derivatives(robot: Robot) -> None:
    rng = np.random.default_rng(5)
    base = random_pose(rng, 0.5, 0.3)
    for world_T_base in (None, base):
        for _ in range(3):
            th = rng.uniform(-1.0, 1.0, robot.n_segments)
            tips, derivs = frame_poses(th, PLANAR(robot), world_T_base)
            np.testing.assert_allclose(np.array(tips), robot.forward(th, None, world_T_base),
                                       atol=1e-12)
            h = 1e-6
            for j in range(robot.n_segments):
                step = np.zeros(robot.n_segments)
                step[j] = h
                plus, _ = frame_poses(th + step, PLANAR(robot), world_T_base)
                minus, _ = frame_poses(th - step, PLANAR(robot), world_T_base)
                for i in range(robot.n_segments):
                    numeric = (plus[i] - minus[i]) / (2 * h)
                    if j <= i:
                        assert derivs[i].shape == (i + 1, 4, 4)
                        np.testing.assert_allclose(derivs[i][j], numeric, atol=1e-7)
                    else:  # segment j is beyond tip i: no effect
                        np.testing.assert_allclose(numeric, 0.0, atol=1e-12)


def test_predict_is_constant_velocity_within_the_limits(robot: Robot) -> None:
    a, b = np.radians([10.0, -5.0, 59.0]), np.radians([8.0, -4.0, 50.0])
    np.testing.assert_allclose(predict(a, None, PLANAR(robot)), a)
    lim = np.array([s.theta_max for s in robot.segments])
    np.testing.assert_allclose(predict(a, b, PLANAR(robot)), np.clip(2 * a - b, -lim, lim))
    assert predict(a, b, PLANAR(robot))[2] == pytest.approx(lim[2])


@pytest.fixture(scope="module")
def pnp_sim(robot: Robot) -> Simulation:
    return room(robot, 12, 0.0, seed=2)


def frame_rows(sim: Simulation, f: int, noise_px: float = 0.0, outlier_fraction: float = 0.0,
               seed: int = 0, cameras: tuple[int, ...] | None = None, limit: int | None = None
               ) -> tuple[list[FrameRows], list[np.ndarray]]:
    """Frame f's observations with the true world points of their landmarks; optionally with
    pixel noise and a fraction of rows replaced by random pixels (and which rows those are)."""
    rng = np.random.default_rng(seed)
    robot = sim.sequence.robot
    rows, replaced = [], []
    for cam, trk in sim.sequence.tracks.items():
        if cameras is not None and cam not in cameras:
            continue
        camera = robot.cameras[cam]
        sel = np.flatnonzero(trk.frames == f)[:limit]
        uv = sim.clean_uv[cam][sel] + rng.normal(0.0, noise_px, (len(sel), 2))
        bad = np.zeros(len(sel), dtype=bool)
        bad[rng.choice(len(sel), int(round(outlier_fraction * len(sel))), replace=False)] = True
        uv[bad] = rng.uniform([0.0, 0.0], [camera.width, camera.height], (bad.sum(), 2))
        xy = camera.normalized(uv)
        whiten = camera.pixel_jacobian(xy) / max(noise_px, 1.0)
        rows.append(FrameRows(cam, sim.points_world[sim.landmarks[cam][sel]], xy, whiten))
        replaced.append(bad)
    return rows, replaced


OFFSET = np.radians([1.5, -2.0, 1.0])


def test_refine_recovers_the_true_angles_from_noise_free_pixels(pnp_sim: Simulation) -> None:
    f = 8
    truth = pnp_sim.sequence.thetas[f]
    rows, _ = frame_rows(pnp_sim, f)
    assert all(len(r.points) > 20 for r in rows)
    guess = refine_planar(truth + OFFSET, pnp_sim.sequence.robot, rows, 3.5)
    assert guess.refined
    # Measured: 1e-15 rad.
    np.testing.assert_allclose(guess.thetas, truth, atol=1e-6, rtol=0)
    assert [len(flags) for flags in guess.row_inliers] == [len(r.points) for r in rows]
    assert all(flags.all() for flags in guess.row_inliers)
    assert guess.inliers.tolist() == [len(r.points) for r in rows]


def test_refine_ignores_twenty_percent_random_pixels(pnp_sim: Simulation) -> None:
    f = 8
    truth = pnp_sim.sequence.thetas[f]
    rows, replaced = frame_rows(pnp_sim, f, noise_px=1.0, outlier_fraction=0.2, seed=3)
    guess = refine_planar(truth + OFFSET, pnp_sim.sequence.robot, rows, 3.5)
    assert guess.refined
    error = float(np.max(deg(np.abs(guess.thetas - truth))))
    # Measured 0.016: the noise floor (without the random pixels, noise seeds 0-5 give up to
    # 0.028 on this frame's 180-250 points per camera).
    assert error < 0.02, f"{error:.4f} deg"
    for flags, bad in zip(guess.row_inliers, replaced, strict=True):
        assert not flags[bad].any()  # every random pixel is flagged
        assert np.mean(flags[~bad]) > 0.98  # and nearly every true one kept (measured 1.0)
    assert guess.inliers.tolist() == [int(flags.sum()) for flags in guess.row_inliers]
    # The random pixels have no influence at all: the same angles as from the true rows alone
    # (measured 1e-12 rad apart).
    true_rows = [FrameRows(r.camera, r.points[~bad], r.xy[~bad], r.whiten[~bad])
                 for r, bad in zip(rows, replaced, strict=True)]
    oracle = refine_planar(truth + OFFSET, pnp_sim.sequence.robot, true_rows, 3.5)
    np.testing.assert_allclose(guess.thetas, oracle.thetas, atol=1e-9, rtol=0)


def test_rows_held_out_of_the_solve_are_still_judged_at_its_answer(pnp_sim: Simulation) -> None:
    """The smoother solves a frame's initial guess without the rows the model-free gate closed,
    then judges every row at the answer (``row_inliers``): a closed row a later frame reopens
    must not enter unchecked."""
    f = 8
    truth = pnp_sim.sequence.thetas[f]
    robot = pnp_sim.sequence.robot
    rows, replaced = frame_rows(pnp_sim, f, noise_px=1.0, outlier_fraction=0.2, seed=3)
    true_rows = [FrameRows(r.camera, r.points[~bad], r.xy[~bad], r.whiten[~bad])
                 for r, bad in zip(rows, replaced, strict=True)]
    guess = refine_planar(truth + OFFSET, robot, true_rows, 3.5)
    flags = row_inliers(guess.thetas, robot, PLANAR(robot), None, rows, 3.5)
    for got, bad in zip(flags, replaced, strict=True):
        assert not got[bad].any() and np.mean(got[~bad]) > 0.98
    # on the rows it solved with, the same decisions as refine's own
    again = row_inliers(guess.thetas, robot, PLANAR(robot), None, true_rows, 3.5)
    assert all(np.array_equal(a, b) for a, b in zip(again, guess.row_inliers, strict=True))
    assert row_inliers(guess.thetas, robot, PLANAR(robot), None, [], 3.5) == ()


def test_refine_keeps_the_prediction_without_enough_known_points(pnp_sim: Simulation) -> None:
    robot = pnp_sim.sequence.robot
    truth = pnp_sim.sequence.thetas[8]
    prediction = truth + OFFSET
    few, _ = frame_rows(pnp_sim, 8, limit=2)  # 2 rows per camera
    guess = refine_planar(prediction, robot, few[:2], 3.5, min_rows=6)  # 4 of 6 rows
    assert not guess.refined
    np.testing.assert_array_equal(guess.thetas, prediction)
    assert guess.thetas is not prediction
    # Only the camera on segment 1 (index 0) sees: segment 1 is refined, the others keep the
    # prediction.
    rows, _ = frame_rows(pnp_sim, 8, cameras=(0,))
    guess = refine_planar(prediction, robot, rows, 3.5)
    assert guess.refined
    assert abs(guess.thetas[0] - truth[0]) < 1e-6
    np.testing.assert_array_equal(guess.thetas[1:], prediction[1:])


def frame_pairs(seq: Sequence, a: int, b: int, outlier_fraction: float = 0.0,
                seed: int = 0) -> tuple[list[FramePairs], list[np.ndarray]]:
    """Every camera's correspondences between frames a and b; optionally a fraction of them
    with frame b's bearing replaced by a random direction in view (and which those are)."""
    rng = np.random.default_rng(seed)
    out, replaced = [], []
    for cam in seq.tracks:
        corr = seq.correspondences(cam, a, b)
        f_b = corr.f_b.copy()
        bad = np.zeros(len(f_b), dtype=bool)
        bad[rng.choice(len(f_b), int(round(outlier_fraction * len(f_b))), replace=False)] = True
        xy = rng.uniform(-0.6, 0.6, (bad.sum(), 2))
        f_b[bad] = np.column_stack([xy, np.ones(len(xy))]) / np.linalg.norm(
            np.column_stack([xy, np.ones(len(xy))]), axis=1, keepdims=True)
        out.append(FramePairs(cam, corr.f_a, f_b, np.arange(len(f_b))))
        replaced.append(bad)
    return out, replaced


def test_one_point_guess_recovers_the_next_frame_from_the_previous(pnp_sim: Simulation) -> None:
    """Noise-free bearings, the prediction degrees off: the 1-point front end returns the new
    frame's angles, segment by segment from the base; with 30% of the correspondences random
    it flags them and keeps the angles."""
    seq = pnp_sim.sequence
    robot = seq.robot
    a, b = 7, 8
    prediction = seq.thetas[a] + np.radians([3.0, -3.0, 3.0])
    pairs, _ = frame_pairs(seq, a, b)
    thetas, inliers = one_point_guess(seq.thetas[a], prediction, robot, None, None, pairs, 1.0)
    np.testing.assert_allclose(thetas, seq.thetas[b], atol=1e-6, rtol=0)
    assert sorted(inliers) == [0, 1, 2] and all(m.all() for m in inliers.values())
    noisy, replaced = frame_pairs(seq, a, b, outlier_fraction=0.3, seed=4)
    thetas, inliers = one_point_guess(seq.thetas[a], prediction, robot, None, None, noisy, 1.0)
    # Measured 1.5e-5 rad: random bearings that fall within the threshold of the true epipolar
    # curve pull the robust refinement a little.
    np.testing.assert_allclose(thetas, seq.thetas[b], atol=1e-4, rtol=0)
    for cam, bad in enumerate(replaced):
        # An epipolar check is one-dimensional: a random bearing near the true epipolar curve
        # passes it (measured: up to 2 of ~60 per camera).
        assert inliers[cam][bad].mean() < 0.05 and inliers[cam][~bad].mean() > 0.95


def test_one_point_guess_keeps_the_prediction_where_it_cannot_solve(pnp_sim: Simulation) -> None:
    seq = pnp_sim.sequence
    prediction = seq.thetas[7] + np.radians([3.0, -3.0, 3.0])
    pairs, _ = frame_pairs(seq, 7, 8)
    few = [FramePairs(p.camera, p.f_a[:3], p.f_b[:3], p.rows[:3]) if p.camera == 1 else p
           for p in pairs if p.camera != 2]
    thetas, inliers = one_point_guess(seq.thetas[7], prediction, seq.robot, None, None, few, 1.0)
    assert sorted(inliers) == [0]  # camera 1 has 3 pairs, camera 2 none
    assert abs(thetas[0] - seq.thetas[8, 0]) < 1e-6
    np.testing.assert_array_equal(thetas[1:], prediction[1:])


# ================================================================ 3. the projection smoother
def reference_committed(seq: Sequence, lag: float, min_rows: int, max_frames: int) -> int:
    """Observations the smoother should commit: every track cut into pieces where it ends,
    where its first frame leaves the window and at max_frames; pieces of min_rows or more."""
    t = seq.timestamps
    total = 0
    for trk in seq.tracks.values():
        by_frame = [set(trk.track_ids[trk.frames == f].tolist()) for f in range(seq.n_frames)]
        live: dict[int, list[int]] = {}  # track id -> [first frame, rows]
        for f in range(seq.n_frames):
            first_kept = int(np.sum(t[:f] < t[f] - lag))  # frames before this one leave
            for tid, (first, n) in list(live.items()):
                ended = bool(by_frame[f]) and tid not in by_frame[f]
                if ended or first < first_kept or f - first >= max_frames:
                    total += n if n >= min_rows else 0
                    del live[tid]
            for tid in by_frame[f]:
                live.setdefault(tid, [f, 0])[1] += 1
        total += sum(n for _, n in live.values() if n >= min_rows)
    return total


@pytest.fixture(scope="module")
def sim60(robot: Robot) -> Simulation:
    """60 frames (2 s) of the room scene, 1 px noise, no outliers."""
    return room(robot, 60, 1.0, seed=1)


QUICK = SmootherOptions(window=WindowOptions(uncertainty=False))
"""The smoother without marginal sigmas."""


def stream(seq: Sequence, frames: list[FrameObservations] | None = None, lag: float = 1.0,
           **kwargs: object) -> dict:
    """Feed the frames one by one, popping final frames after every update."""
    kwargs.setdefault("theta0", seq.thetas[0])
    smoother = FixedLagSmoother(seq.robot, lag=lag, **kwargs)  # type: ignore[arg-type]
    frames = [seq.frame(f) for f in range(seq.n_frames)] if frames is None else frames
    filtered, popped = [], []
    for obs in frames:
        filtered.append(smoother.update(obs))
        popped.append(smoother.pop_final())
    rest = smoother.finish()
    return {"smoother": smoother, "filtered": filtered, "popped": popped, "rest": rest,
            "final": [fr for pops in popped for fr in pops] + rest}


@pytest.fixture(scope="module")
def run60(sim60: Simulation) -> dict:
    out = stream(sim60.sequence, settings=QUICK)
    smoother = out["smoother"]
    out["committed"] = smoother.committed_observations
    out["again"] = smoother.finish()
    out["committed_again"] = smoother.committed_observations
    return out


def test_every_observation_is_committed_exactly_once(sim60: Simulation, run60: dict) -> None:
    seq = sim60.sequence
    smoother = run60["smoother"]
    assert smoother.recoveries == 0  # a restart forgets live tracks
    total = sum(len(trk.frames) for trk in seq.tracks.values())
    options = smoother.options
    expected = reference_committed(seq, 1.0, options.min_track_rows,
                                   options.max_track_frames or 10**9)
    # Measured: 23658 of 23705 observations; the 47 left out are one-row pieces: 33 tracks
    # seen once and 14 one-frame remainders of tracks cut where their first frame left the
    # window (so "total minus the tracks seen once" is not a lower bound).
    assert run60["committed"] == expected
    assert total - 0.01 * total <= run60["committed"] <= total
    assert run60["committed_again"] == run60["committed"]  # a second finish commits nothing
    assert [fr.frame for fr in run60["again"]] == [fr.frame for fr in run60["rest"]]
    np.testing.assert_array_equal(thetas(run60["again"]), thetas(run60["rest"]))
    assert 0 <= smoother.outlier_observations < 0.05 * run60["committed"]  # measured 589


def test_frames_leave_the_window_after_lag_seconds_once_and_in_order(sim60: Simulation,
                                                                     run60: dict) -> None:
    seq = sim60.sequence
    t = seq.timestamps
    done: list[int] = []
    for f, pops in enumerate(run60["popped"]):
        frames = [fr.frame for fr in pops]
        # Exactly the frames older than lag seconds that had not left yet.
        assert frames == [g for g in range(f) if t[g] < t[f] - 1.0 and g not in done], f
        done += frames
    assert len(done) > 20  # measured: 29 frames left during the stream
    rest = [fr.frame for fr in run60["rest"]]
    assert done + rest == list(range(seq.n_frames))
    for fr in run60["final"]:
        assert fr.timestamp == t[fr.frame] and fr.thetas.shape == (3,)
    assert [fr.frame for fr in run60["filtered"]] == list(range(seq.n_frames))


def compare_with_bound(sim: Simulation, final: np.ndarray) -> np.ndarray:
    """RMS / the sequence's Cramer-Rao bound, per segment."""
    seq = sim.sequence
    rms = np.sqrt(np.mean((final - seq.thetas) ** 2, axis=0))
    return rms / sequence_bound(sim, 1.0, math.radians(0.1)).rms()


def test_one_pixel_noise_comes_close_to_the_cramer_rao_bound(sim60: Simulation,
                                                             run60: dict) -> None:
    to_bound = compare_with_bound(sim60, thetas(run60["final"]))
    # Measured (seed 1): RMS 0.071, 0.118, 0.047 = 0.63, 1.34, 0.52x the bound (the retired
    # epipolar smoother was at 1.05, 1.76, 2.08x).
    assert np.all(to_bound < 2.0), to_bound


@pytest.mark.parametrize("seed", [3, 5])
def test_the_first_frames_follow_the_robot(robot: Robot, seed: int) -> None:
    """Each frame's filtered estimate over the first 20 frames (30 fps, 10% outliers), before
    any track is four frames long: the tracks the 1-point front end accepted join the graph
    from their second frame. Without them these seeds strayed 3.1 and 5.4 deg."""
    seq = simulate(robot, 20, noise_px=1.0, outlier_fraction=0.1, seed=seed, fps=30.0,
                   scene="room", n_points=4000).sequence
    smoother = FixedLagSmoother(robot, theta0=seq.thetas[0])
    filtered = np.array([smoother.update(seq.frame(f)).thetas for f in range(20)])
    assert np.degrees(np.abs(filtered - seq.thetas)).max() < 1.0


def test_one_pixel_noise_on_another_seed(robot: Robot) -> None:
    """Seed 3 used to keep segment 3 about 0.5 deg off through the whole sequence (RMS 0.65 deg,
    5.3x the bound) when frames 1-3 had no vision and started from the previous frame's
    angles; the 1-point front end now starts them."""
    sim = room(robot, 60, 1.0, seed=3)
    out = stream(sim.sequence, settings=QUICK)
    to_bound = compare_with_bound(sim, thetas(out["final"]))
    # Measured (seed 3): RMS 0.097, 0.126, 0.036 deg = 0.95, 1.12, 0.30x the bound.
    assert np.all(to_bound < 2.0), to_bound


@pytest.fixture(scope="module")
def sim30_clean(robot: Robot) -> Simulation:
    return room(robot, 30, 0.0, seed=1)


def test_noise_free_sequence_without_motion_prior_recovers_the_truth(
        sim30_clean: Simulation) -> None:
    """Without noise and without the motion prior the truth is the optimum of the graph.

    Fails at db21306 (71 deg, 9239 of 11146 observations judged outliers): frames 1-3 had no
    vision (pieces join the live factor at 4 observations), so the first outlier decisions were
    taken at angles 1.4-4.5 deg off. The 1-point front end now starts those frames."""
    seq = sim30_clean.sequence
    options = GraphOptions(motion_sigma=None, theta0_sigma=1e-6)
    out = stream(seq, lag=1.0, options=options, settings=QUICK)
    error = float(np.max(deg(np.abs(thetas(out["final"]) - seq.thetas))))
    # Measured: 1.3e-14 deg, no observation judged an outlier.
    assert error < 1e-6, (f"{error:.3g} deg; {out['smoother'].outlier_observations} of "
                          f"{out['smoother'].committed_observations} judged outliers")
    assert out["smoother"].outlier_observations == 0


def test_noise_free_sequence_reaches_the_optimum_with_the_motion_prior(
        sim30_clean: Simulation) -> None:
    """The motion prior moves the optimum off the truth (the batch, started at the truth: 0.0015
    deg); the smoother reaches that optimum."""
    seq = sim30_clean.sequence
    options = GraphOptions()
    out = stream(seq, lag=1.0, options=options, settings=QUICK)
    optimum = batch_estimate(seq, theta0=seq.thetas[0], initial=seq.thetas, options=options,
                             marginals=False)
    final = thetas(out["final"])
    # Measured: 2.4e-4 from the batch, 1.7e-3 from the truth.
    assert np.max(deg(np.abs(final - optimum.thetas))) < 1e-3
    assert np.max(deg(np.abs(final - seq.thetas))) < 5e-3


def test_a_frame_without_tracks_is_carried(sim60: Simulation, run60: dict) -> None:
    seq = sim60.sequence
    gap, n = 30, 45
    frames = [seq.frame(f) for f in range(n)]
    frames[gap] = blank(frames[gap])
    out = stream(seq, frames, settings=QUICK)
    assert np.all(np.isfinite(thetas(out["filtered"])))
    assert np.all(np.isfinite(thetas(out["final"])))
    assert [fr.frame for fr in out["final"]] == list(range(n))
    assert list(out["filtered"][gap].status) == ["predicted"] * 3
    error = deg(np.abs(thetas(out["final"]) - seq.thetas[:n])).max(axis=1)
    clean = deg(np.abs(thetas(run60["final"][:n]) - seq.thetas[:n])).max(axis=1)
    # Without the blank frame every final estimate is within 0.2 deg. With it the blank frame
    # should hold the last angles (one frame's motion, about 1.5 deg) and the frames after it
    # recover once the cameras see again. Measured: every track restarts a piece after the
    # blank frame and pieces join the window at 4 observations, so frames 30-34 have no vision
    # (filtered error 1.4 -> 5.5 deg); the new pieces' outlier decisions are taken at those
    # angles, the estimate runs off (12-77 deg), gtsam raises "indeterminate system" at frame
    # 41 (1 recovery); final estimates from the blank frame on are 39-77 deg off.
    report = (f"recoveries {out['smoother'].recoveries}; max error after the blank frame "
              f"{error[gap:].max():.2f} deg (without it {clean[gap:].max():.2f})")
    assert error[gap] < 3.0, report
    assert np.all(error[gap + 5:] < np.maximum(0.5, 2 * clean[gap + 5:])), report
    assert out["smoother"].recoveries == 0, report
    assert np.all(error[:gap] < np.maximum(0.5, 2 * clean[:gap])), report


def test_a_frame_without_tracks_without_the_motion_prior(robot: Robot) -> None:
    """No motion prior: the loose prior at the initial guess alone holds the blank frame, and a
    0.2 s window marginalises it."""
    seq = room(robot, 20, 1.0, seed=1).sequence
    frames = [seq.frame(f) for f in range(seq.n_frames)]
    frames[10] = blank(frames[10])
    smoother = FixedLagSmoother(robot, lag=0.2, options=GraphOptions(motion_sigma=None),
                                theta0=seq.thetas[0])
    filtered = [smoother.update(obs) for obs in frames]
    final = smoother.pop_final() + smoother.finish()
    assert [fr.frame for fr in final] == list(range(seq.n_frames))
    assert np.all(np.isfinite(thetas(filtered))) and np.all(np.isfinite(thetas(final)))
    assert list(filtered[10].status) == ["predicted"] * 3
    # Nothing but the loose prior (30 deg) holds it.
    np.testing.assert_allclose(filtered[10].sigmas, smoother.window.loose_sigma, rtol=1e-3)
    assert np.all(np.isfinite(filtered[11].sigmas))


class _FailOnce:
    """gtsam's smoother, raising ``error`` at its next ``update``."""

    def __init__(self, inner: object, error: Exception) -> None:
        self.inner, self.error = inner, error

    def update(self, *args: object) -> None:
        if self.error is not None:
            error, self.error = self.error, None
            raise error
        self.inner.update(*args)  # type: ignore[attr-defined]

    def __getattr__(self, name: str) -> object:
        return getattr(self.inner, name)


@pytest.mark.parametrize("error", [IndexError("no clique"), RuntimeError("indeterminate")])
def test_a_gtsam_failure_restarts_the_smoother_and_it_goes_on(sim60: Simulation,
                                                             error: Exception) -> None:
    """gtsam's marginalisation helper can lose a variable's clique (IndexError) and iSAM2 can
    find the system indeterminate (RuntimeError): the smoother warns, restarts from its last
    estimate and keeps every frame."""
    seq = sim60.sequence
    smoother = FixedLagSmoother(seq.robot, theta0=seq.thetas[0],
                                settings=QUICK)
    for f in range(30):
        smoother.update(seq.frame(f))
    smoother._smoother = _FailOnce(smoother._smoother, error)
    with pytest.warns(RestartWarning, match="frame 30"):
        out = smoother.update(seq.frame(30))
    assert smoother.recoveries == 1
    assert list(out.status) == ["recovered"] * 3
    for f in range(31, 60):
        smoother.update(seq.frame(f))
    final = smoother.finish()
    assert [fr.frame for fr in final] == list(range(60))
    err = deg(np.abs(thetas(final) - seq.thetas))
    # The frames before the failure keep their estimates (measured 0.12 deg at most). After it
    # the window holds the restart frame and its observations, which start new track pieces:
    # the last 10 final estimates are within 0.31 deg. When the restart also forgot the restart
    # frame's observations, no vision reached frames 31-34, the new pieces' outlier decisions
    # were taken at predictions 1-3 deg off, and the stream ran 37 deg away.
    assert err[:25].max() < 0.3, err[:25].max()
    assert err[-10:].max() < 0.6, err[-10:].max()


# --------------------------------------------------------------------------- validation
@pytest.fixture(scope="module")
def seq_short(robot: Robot) -> Sequence:
    return room(robot, 20, 1.0, seed=1).sequence


def test_non_increasing_timestamps_are_refused(seq_short: Sequence) -> None:
    smoother = FixedLagSmoother(seq_short.robot, theta0=seq_short.thetas[0],
                                settings=QUICK)
    smoother.update(seq_short.frame(0))
    smoother.update(seq_short.frame(1))
    second = seq_short.frame(1)
    for t in (second.timestamp, second.timestamp - 0.01, float("nan"), float("inf")):
        with pytest.raises(ValueError, match=r"frame 2: timestamp"):
            smoother.update(replace(second, timestamp=t))
    assert smoother.n_frames == 2  # nothing was added
    smoother.update(seq_short.frame(2))
    assert smoother.n_frames == 3


def test_observations_of_a_segment_without_camera_are_refused(robot: Robot,
                                                              seq_short: Sequence) -> None:
    one_camera = Robot(robot.segments, [robot.cameras[0], None, None])
    smoother = FixedLagSmoother(one_camera, theta0=seq_short.thetas[0])
    with pytest.raises(ValueError, match=r"frame 0: observations of camera 1.*no camera"):
        smoother.update(seq_short.frame(0))
    assert smoother.n_frames == 0
    with pytest.raises(ValueError, match="camera 7"):
        FixedLagSmoother(robot).update(
            FrameObservations(0.0, {7: (np.arange(3), np.zeros((3, 2)))}))


@pytest.mark.parametrize(("options", "message"), [
    ({"lag": 0.0}, "lag"), ({"lag": -1.0}, "lag"), ({"lag": float("nan")}, "lag"),
    ({"lag": float("inf")}, "lag"),
    ({"theta0": [0.0, 0.0]}, r"theta0 has shape \(2,\)"),
    ({"theta0": np.zeros((1, 3))}, "theta0"), ({"theta0": [0.0, float("nan"), 0.0]}, "theta0"),
    ({"settings": {"min_live_rows": 1}}, "TrackOptions.min_live_rows"),
])
def test_bad_smoother_arguments_are_refused(robot: Robot, options: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        if "settings" in options:
            options = {"settings": SmootherOptions(tracks=TrackOptions(**options["settings"]))}
        FixedLagSmoother(robot, **options)


def test_a_robot_is_required() -> None:
    with pytest.raises(ValueError, match="Robot"):
        FixedLagSmoother("planar_three")  # type: ignore[arg-type]


# ------------------------------------------------------------------------ estimate() entry
def test_estimate_with_the_smoother(seq_short: Sequence) -> None:
    quick = QUICK
    est = apcc_graph.estimate(seq_short, method="smoother", theta0=seq_short.thetas[0],
                              settings=quick)
    assert est.method == "smoother"
    F = seq_short.n_frames
    assert est.thetas.shape == est.sigmas.shape == est.status.shape == (F, 3)
    np.testing.assert_array_equal(est.timestamps, seq_short.timestamps)
    assert np.all(np.isfinite(est.thetas))
    assert est.status[0].tolist() == ["initial"] * 3
    direct = smoother_estimate(seq_short, theta0=seq_short.thetas[0], settings=quick)
    np.testing.assert_allclose(est.thetas, direct.thetas, atol=1e-12, rtol=0)
    assert apcc_graph.FixedLagSmoother is FixedLagSmoother
    # self-calibration is the batch's option: the smoother's record has no such field
    with pytest.raises(TypeError, match="expected SmootherOptions for method 'smoother', got "
                       "BatchOptions \\(the options of method 'batch'\\)"):
        apcc_graph.estimate(seq_short, method="smoother", theta0=seq_short.thetas[0],
                            settings=BatchOptions(calibrate=True))


# ------------------------------------------------------------------------------ landmarks
@pytest.fixture(scope="module")
def sim200(robot: Robot) -> Simulation:
    """200 frames of the room scene, 1 px noise, seed 2: cut tracks let this one drift."""
    return room(robot, 200, 1.0, seed=2)


def test_landmarks_keep_the_smoother_near_the_bound(sim200: Simulation) -> None:
    """Cutting tracks that outlive the window loses what their old observations said about
    their points; with landmarks the smoother stays near the bound where the cut one drifts.
    The cut one cuts at the window's edge (no staggered cuts: staggering the first cohort's
    cuts also slows its drift, to 0.58 / 1.07 / 0.67 times the bound here)."""
    seq = sim200.sequence
    bound = sequence_bound(sim200, 1.0, math.radians(0.1))
    ratios = {}
    for landmarks in (False, True):
        out = stream(seq, settings=SmootherOptions(
            window=WindowOptions(uncertainty=False), tracks=TrackOptions(stagger_cuts=landmarks),
            landmarks=LandmarkOptions(enabled=landmarks)))
        error = thetas(out["final"]) - seq.thetas
        ratios[landmarks] = np.sqrt(np.mean(error**2, axis=0)) / bound.rms()
        assert out["smoother"].recoveries == 0
    # Measured: cut 1.10 / 1.55 / 0.86, landmarks 0.27 / 0.45 / 1.15 times the bound (over
    # 300 frames the cut smoother reaches 1.98 / 4.63 / 1.91, landmarks 0.24 / 0.49 / 1.08).
    assert np.all(ratios[True] < 1.5), ratios
    assert ratios[False][1] > 2.5 * ratios[True][1], ratios
    assert ratios[False][0] > 2.5 * ratios[True][0], ratios


def test_smoother_equals_the_batch_on_a_sequence_shorter_than_the_lag(robot: Robot) -> None:
    """25 frames (0.83 s) in a 2 s window: the smoother's graph holds every observation once,
    as the batch's does, so their answers agree far below the error itself."""
    sim = room(robot, 25, 1.0, seed=4)
    seq = sim.sequence
    out = stream(seq, lag=2.0, settings=QUICK)
    batch = batch_estimate(seq, theta0=seq.thetas[0], init="chain", marginals=False)
    final = thetas(out["final"])
    difference = float(np.max(deg(np.abs(final - batch.thetas))))
    error = float(np.max(deg(np.sqrt(np.mean((batch.thetas - seq.thetas) ** 2, axis=0)))))
    assert out["smoother"].recoveries == 0
    # Measured: 0.0057 deg apart; the batch's RMS error is 0.030-0.054 deg per segment.
    assert difference < 0.3 * error, (difference, error)


def _cut_frames(live: LiveTracks, ids: list[int], frames: int, window: int) -> dict[int, int]:
    """Feed ``ids`` seen in every frame, the window ``window`` frames long; track id -> the
    frame at which its first piece was cut (its first frame then about to leave, or earlier)."""
    cut: dict[int, int] = {}
    for f in range(frames):
        out = live.take_due(f, {0: np.array(ids)}, leaving_before=max(f - window, 0),
                            window=window)
        for _, _, tid in committed(out[0]) if 0 in out else []:
            cut.setdefault(tid, f)
        live.add(f, 0, *rows_of(ids, f))
    return cut


def test_tracks_born_together_are_cut_at_staggered_frames_but_only_with_stagger() -> None:
    ids = list(range(40))
    together = _cut_frames(LiveTracks((0,), max_frames=100, min_rows=2), ids, 40, 20)
    # without stagger every piece is cut when its first frame, 0, leaves: all together
    assert set(together.values()) == {21}
    staggered = _cut_frames(LiveTracks((0,), max_frames=100, min_rows=2, stagger=True), ids,
                            40, 20)
    assert len(staggered) == 40
    # each cut within the last half window before frame 0 leaves, spread over it
    assert min(staggered.values()) >= 21 - 10 and max(staggered.values()) <= 21
    assert len(set(staggered.values())) >= 6
    # the continuations are born apart: no cohort, so the next cuts stay spread
    assert max(np.bincount(list(staggered.values()))) <= 0.25 * 40


def test_stagger_leaves_pieces_born_apart_whole() -> None:
    live = LiveTracks((0,), max_frames=100, min_rows=2, stagger=True)
    cut: dict[int, int] = {}
    born = {tid: tid for tid in range(12)}  # track t first seen in frame t: no cohort
    for f in range(40):
        seen = [t for t, b in born.items() if b <= f]
        out = live.take_due(f, {0: np.array(seen)}, leaving_before=max(f - 20, 0),
                            window=20)
        for _, _, tid in committed(out[0]) if 0 in out else []:
            cut.setdefault(tid, f)
        live.add(f, 0, *rows_of(seen, f))
    # each piece is cut exactly when its first frame is about to leave the window
    assert cut == {tid: tid + 21 for tid in range(12) if tid + 21 < 40}
