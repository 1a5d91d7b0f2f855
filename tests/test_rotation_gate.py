"""The smoother's model-free outlier gate (apcc_graph/estimation/rotation_gate.py).

Each observation is judged against its neighbours in time by the rotation that relates one
camera's bearings in two consecutive frames, never by the residual at the current estimate.
"""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from apcc_graph.estimation.live_tracks import LiveTracks
from apcc_graph.estimation.robust import enough_rows
from apcc_graph.estimation.rotation_gate import (
    NOT_JUDGED,
    combine,
    gate_weights,
    judge_pair,
)


def _scene(rng: np.random.Generator, n: int, turn: float
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``n`` points 1-3 m in front of a camera that turns by ``turn`` rad (no translation):
    normalised coordinates in both frames, and the rotation ``a ~ R b``."""
    p = np.column_stack([rng.uniform(-0.5, 0.5, (n, 2)), np.ones(n)]) * rng.uniform(1, 3, (n, 1))
    axis = rng.normal(size=3)
    R = Rotation.from_rotvec(turn * axis / np.linalg.norm(axis)).as_matrix()
    q = p @ R  # the same points in the turned camera: q = R^T p
    return p[:, :2] / p[:, 2:], q[:, :2] / q[:, 2:], R


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10_000), turn=st.floats(0.0, 0.2))
def test_the_pair_judgement_finds_the_wrong_associations(seed: int, turn: float) -> None:
    rng = np.random.default_rng(seed)
    a, b, _ = _scene(rng, 60, turn)
    b = b + rng.normal(0, 1e-3, b.shape)  # about a pixel at a 500 px focal length
    wrong = rng.choice(60, 12, replace=False)
    b[wrong] = rng.uniform(-0.5, 0.5, (12, 2))  # re-associated anywhere in the image
    ids = np.arange(100, 160)
    found = judge_pair(ids, a, ids[::-1], b[::-1], 0.02, (seed, 0))
    assert found is not None
    i_before, i_now, agree = found
    # Rows are matched by track id, whatever their order in each frame.
    assert np.array_equal(ids[i_before], ids[::-1][i_now])
    outlier = np.isin(ids[i_before], ids[wrong])
    # A re-associated point lands within 0.02 rad of the rotated bearing only by chance (an
    # area of pi 0.02^2 in a 1 x 1 image: about 0.1% each).
    assert agree[outlier].sum() <= 1
    assert agree[~outlier].mean() > 0.95


def test_too_few_common_tracks_judge_nothing() -> None:
    rng = np.random.default_rng(0)
    a, b, _ = _scene(rng, 5, 0.05)
    assert judge_pair(np.arange(5), a, np.arange(3, 8), b, 0.02, (0,)) is None  # 2 common
    assert judge_pair(np.arange(5), a, np.arange(5), b, 0.02, (0,)) is not None


def test_the_same_frames_give_the_same_verdicts() -> None:
    rng = np.random.default_rng(3)
    a, b, _ = _scene(rng, 40, 0.1)
    b[:15] = rng.uniform(-0.5, 0.5, (15, 2))
    ids = np.arange(40)
    one = judge_pair(ids, a, ids, b, 0.02, (7, 1))
    two = judge_pair(ids, a, ids, b, 0.02, (7, 1))
    assert one is not None and two is not None
    assert all(np.array_equal(x, y) for x, y in zip(one, two, strict=True))


@given(st.lists(st.booleans(), min_size=1, max_size=6))
def test_a_verdict_is_agreement_with_some_neighbour_that_judged(judgements: list[bool]) -> None:
    v = np.array([NOT_JUDGED], dtype=np.int8)
    assert gate_weights(v)[0] == 1.0  # not judged: left to the residual test
    for j in judgements:
        v = combine(v, np.array([j]))
    assert gate_weights(v)[0] == float(any(judgements))


def test_live_rows_weigh_residual_decisions_by_the_gate_and_a_later_frame_lifts_it() -> None:
    live = LiveTracks((0,), max_frames=100, min_rows=2)
    xy, whiten = np.zeros((3, 2)), np.tile(np.eye(2), (3, 1, 1))
    ids = np.array([1, 2, 3])
    for f in range(3):
        live.take_due(f, {0: ids}, leaving_before=0)
        verdicts = np.array([1, 0, NOT_JUDGED], dtype=np.int8) if f == 1 else None
        live.add(f, 0, ids, xy, whiten, None, verdicts)
    found = live.live_rows(0)
    assert found is not None
    obs, weights, index = found
    track = obs.ids[obs.tracks]
    w = {(int(p), int(g)): float(x) for p, g, x in zip(track, obs.frames, weights, strict=True)}
    piece = {t: int(p) for t, p in zip(ids, live.piece_ids(0, ids), strict=True)}
    assert w[piece[2], 1] == 0.0 and w[piece[1], 1] == 1.0 and w[piece[3], 1] == 1.0
    # A residual decision of 1 does not lift the gate ...
    live.set_weights(0, index, np.ones(len(index)))
    assert live.live_rows(0)[1][(obs.frames == 1) & (track == piece[2])] == 0.0
    # ... the frame after agreeing does; and a later disagreement of a vouched row does not
    # undo it, while a first disagreement of a row not judged yet gates it.
    live.judge(1, 0, np.array([2, 1, 3]), np.array([True, False, False]))
    _, weights, _ = live.live_rows(0)
    at1 = {int(t): float(x) for t, x, g in zip(track, weights, obs.frames, strict=True)
           if g == 1}
    assert at1 == {piece[1]: 1.0, piece[2]: 1.0, piece[3]: 0.0}
    # gates() reads the same verdicts for observations handed out by take_due / take_all.
    committed = live.take_all()[0]
    gate = live.gates(committed)
    rows = committed.frames == 1
    got = {int(p): float(x) for p, x in zip(committed.ids[committed.tracks][rows], gate[rows],
                                            strict=True)}
    assert got == at1
    assert np.all(gate[~rows] == 1.0)


def test_enough_rows_needs_three_open_rows_or_all_of_a_short_track() -> None:
    starts = np.array([0, 4, 6, 9])  # tracks of 4, 2 and 3 rows
    tracks = np.repeat(np.arange(3), np.diff(starts))
    gate = np.array([0, 0, 1, 1,  1, 1,  1, 0, 1], dtype=float)
    assert enough_rows(gate, tracks, starts, 3).tolist() == [False] * 4 + [True] * 2 + [False] * 3
    gate[0] = 1.0
    assert enough_rows(gate, tracks, starts, 3)[:4].all()
    # never fewer than two open rows, whatever is asked
    assert not enough_rows(np.array([1.0, 0.0]), np.array([0, 0]), np.array([0, 2]), 1).any()


def test_a_live_piece_is_decided_only_once_the_gate_leaves_it_three_rows() -> None:
    """A track that began with wrong associations: its first rows all disagree with their
    neighbours. Triangulated from them, a wrong point would judge every later row (on the
    reliability bench such a piece pulled segment 3 by 17 degrees); it waits instead."""
    import gtsam

    from apcc_graph.bench.smoother import FPS, N_POINTS, ROBOT_FILE
    from apcc_graph.estimation.smoother import FixedLagSmoother
    from apcc_graph.io.robot_file import load_robot
    from apcc_graph.simulation.simulator import simulate

    robot = load_robot(ROBOT_FILE)
    sim = simulate(robot, 8, noise_px=1.0, outlier_fraction=0.0, seed=3, fps=FPS, scene="room",
                   n_points=N_POINTS)
    seq = sim.sequence
    smoother = FixedLagSmoother(robot, theta0=seq.thetas[0])
    for f in range(6):
        smoother.update(seq.frame(f))
    tracks = smoother._model.tracks  # type: ignore[attr-defined]
    cam = robot.camera_segments[0]
    # A new track (id 10**6) copying an existing track's rows in frames 1..4.
    t = seq.tracks[cam]
    tid = next(i for i in np.unique(t.track_ids)
               if set(range(1, 5)) <= set(t.frames[t.track_ids == i].tolist()))
    new = np.array([10**6])
    for g in range(1, 5):
        rows = tracks.live.frame_rows(g)[cam]
        k = int(np.flatnonzero(rows[0] == tid)[0])
        tracks.live.add(g, cam, new, rows[1][k:k + 1], rows[2][k:k + 1], None,
                        np.zeros(1, dtype=np.int8))
    piece = int(tracks.live.piece_ids(cam, new)[0])

    def in_live_factor() -> bool:
        found = tracks.live_factors(gtsam.NonlinearFactorGraph())
        return any(piece in factor.obs.ids.tolist() for _, c, factor in found if c == cam)

    assert not in_live_factor() and piece not in tracks.live.points(cam)
    tracks.live.judge(2, cam, new, np.array([True]))
    tracks.live.judge(3, cam, new, np.array([True]))
    assert not in_live_factor()  # two open rows of four: still waiting
    tracks.live.judge(4, cam, new, np.array([True]))
    assert in_live_factor() and piece in tracks.live.points(cam)


def test_the_smoothers_gate_does_not_depend_on_its_estimate() -> None:
    """Two smoothers on the same frames, one started 3 degrees off: the same verdicts, and
    those of the offline test (agreement with the frame before or after) for almost every
    observation (each pair's RANSAC draws its own samples)."""
    from apcc_graph.bench.smoother import FPS, N_POINTS, ROBOT_FILE
    from apcc_graph.estimation.smoother import FixedLagSmoother
    from apcc_graph.estimation.smoother_options import FaultOptions, SmootherOptions
    from apcc_graph.frontend.rotation_pairs import pair_inliers
    from apcc_graph.io.robot_file import load_robot
    from apcc_graph.simulation.simulator import simulate

    robot = load_robot(ROBOT_FILE)
    sim = simulate(robot, 20, noise_px=1.0, outlier_fraction=0.15, seed=4, fps=FPS,
                   scene="room", n_points=N_POINTS)
    seq = sim.sequence
    verdicts = []
    for offset in (0.0, np.radians(3.0)):
        smoother = FixedLagSmoother(robot, theta0=seq.thetas[0] + offset,
                                    settings=SmootherOptions(faults=FaultOptions(rotation_gate=0.02)))
        for f in range(seq.n_frames):
            smoother.update(seq.frame(f))
        verdicts.append({(cam, r.frame, int(i)): int(v)
                         for cam, state in smoother._model.tracks.live._cams.items()  # type: ignore[attr-defined]
                         for r in state.rows for i, v in zip(r.ids, r.verdicts, strict=True)})
    assert verdicts[0] == verdicts[1]
    last = seq.n_frames - 1  # its verdicts wait for the frame after
    agree, total, outliers_open = 0, 0, 0
    for cam, t in seq.tracks.items():
        order = np.lexsort((t.frames, t.track_ids))
        xy = robot.cameras[cam].normalized(t.uv[order])
        offline = pair_inliers(t.frames[order], t.track_ids[order],
                               np.column_stack([xy, np.ones(len(xy))]))
        wrong = sim.outliers[cam][order]
        for k, (f, i) in enumerate(zip(t.frames[order], t.track_ids[order], strict=True)):
            v = verdicts[0].get((cam, int(f), int(i)))
            if v is None or f == last or v == -1:
                continue
            total += 1
            agree += int((v == 1) == offline[k])
            outliers_open += int(v == 1 and wrong[k])
    assert total > 3000
    assert agree / total > 0.98, agree / total
    assert outliers_open <= 0.003 * total
