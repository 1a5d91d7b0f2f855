"""Landmarks for the fixed-lag smoother: the camera-pose tie and its Jacobians against central
differences, gtsam's projection factors at the truth, the keys, and LiveTracks handing over the
tracks that outlive the window."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest
from helpers import random_pose
from hypothesis import given, settings
from hypothesis import strategies as st

from apcc_graph import Segment
from apcc_graph.estimation.live_tracks import LiveTracks
from apcc_graph.factors.camera_chain import CameraChain
from apcc_graph.factors.keys import camera_pose_key, frame_key, point_key
from apcc_graph.factors.landmark import (
    camera_pose_factor,
    camera_pose_residual,
    observation_factors,
)
from apcc_graph.model.parameterisation import Bending

SEGMENTS = (Segment(0.3, k=0.2, delta_max=0.1, theta_max=1.0),
            Segment(0.3, k=0.3, delta_max=-0.05, theta_max=1.0),
            Segment(0.25, k=0.25, delta_max=0.03, theta_max=1.0))


def _chain(rng: np.random.Generator, n: int, frames: int = 5) -> CameraChain:
    bases = np.stack([random_pose(rng, 0.3, 0.2) for _ in range(frames)])
    return CameraChain(Bending.fixed(SEGMENTS[:n]), random_pose(rng, 0.3, 0.05), bases)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), cam=st.integers(0, 2))
def test_camera_pose_jacobians_match_central_differences(seed: int, cam: int) -> None:
    rng = np.random.default_rng(seed)
    chain = _chain(rng, cam + 1)
    frame = 3
    thetas = rng.uniform(-0.8, 0.8, 3)
    T = chain.poses(thetas[None, :], frame, False)[0][0]
    X = gtsam.Pose3(T).retract(rng.normal(0.0, 0.05, 6))  # near, not at, the chain's pose
    r, H_theta, H_X = camera_pose_residual(X, thetas, chain, frame)
    h = 1e-6
    for j in range(cam + 1):
        plus, minus = thetas.copy(), thetas.copy()
        plus[j] += h
        minus[j] -= h
        numeric = (camera_pose_residual(X, plus, chain, frame, False)[0]
                   - camera_pose_residual(X, minus, chain, frame, False)[0]) / (2 * h)
        np.testing.assert_allclose(H_theta[:, j], numeric, atol=1e-7)
    for d in range(6):
        step = np.zeros(6)
        step[d] = h
        numeric = (camera_pose_residual(X.retract(step), thetas, chain, frame, False)[0]
                   - camera_pose_residual(X.retract(-step), thetas, chain, frame, False)[0]) / (
            2 * h)
        np.testing.assert_allclose(H_X[:, d], numeric, atol=1e-7)
    # At the chain's own pose the residual vanishes.
    np.testing.assert_allclose(camera_pose_residual(gtsam.Pose3(T), thetas, chain, frame,
                                                    False)[0], 0.0, atol=1e-12)


def test_camera_pose_factor_blocks_pad_the_segments_above_the_camera() -> None:
    rng = np.random.default_rng(3)
    chain = _chain(rng, 2)
    factor = camera_pose_factor(2, 1, chain, 3, 1e-3)
    assert list(factor.keys()) == [frame_key(2), camera_pose_key(2, 1)]
    values = gtsam.Values()
    thetas = np.array([0.2, -0.3, 0.4])
    values.insert(frame_key(2), thetas)
    T = chain.poses(thetas[None, :], 2, False)[0][0]
    values.insert(camera_pose_key(2, 1), gtsam.Pose3(T).retract(np.full(6, 0.01)))
    A = factor.linearize(values).jacobian()[0]
    assert A.shape == (6, 9)
    np.testing.assert_array_equal(A[:, 2], 0.0)  # segment 3 does not move camera 2
    assert np.all(np.abs(A[:, :2]).max(axis=0) > 0.0)


def test_keys_are_distinct() -> None:
    keys = {camera_pose_key(f, c) for f in range(50) for c in range(3)}
    keys |= {point_key(0, i) for i in range(150)} | {frame_key(f) for f in range(50)}
    assert len(keys) == 50 * 3 + 150 + 50
    with pytest.raises(ValueError, match="camera"):
        camera_pose_key(0, 64)


def test_projection_factors_vanish_at_the_truth() -> None:
    rng = np.random.default_rng(5)
    K = gtsam.Cal3_S2(500.0, 480.0, 0.0, 320.0, 240.0)
    pose = gtsam.Pose3(random_pose(rng, 0.3, 0.2))
    points = [pose.transformFrom(np.array([x, y, z])) for x, y, z in
              rng.uniform([-1, -1, 2], [1, 1, 4], (6, 3))]
    xy = np.array([pose.transformTo(p)[:2] / pose.transformTo(p)[2] for p in points])
    factors = observation_factors(np.full(6, 4), 2, np.arange(6), xy, K, 1.0)
    values = gtsam.Values()
    values.insert(camera_pose_key(4, 2), pose)
    for i, p in enumerate(points):
        values.insert(point_key(2, i), gtsam.Point3(*p))
    assert [f.keys()[0] for f in factors] == [camera_pose_key(4, 2)] * 6
    assert max(f.error(values) for f in factors) < 1e-18
    values.update(point_key(2, 0), gtsam.Point3(*(points[0] + np.array([0.01, 0.0, 0.0]))))
    assert factors[0].error(values) > 0.1  # a shifted point shows in pixels (~2 px)


def _ids(*values: int) -> np.ndarray:
    return np.array(values, dtype=np.int64)


def _add(tracks: LiveTracks, frame: int, ids: np.ndarray) -> None:
    n = len(ids)
    tracks.add(frame, 0, ids, np.zeros((n, 2)), np.tile(np.eye(2), (n, 1, 1)))


def test_take_continuing_hands_over_tracks_that_outlive_the_window() -> None:
    tracks = LiveTracks((0,), max_frames=100)
    for f in range(4):
        _add(tracks, f, _ids(1, 2, 3) if f < 3 else _ids(1, 2))
    # Track 4 starts at frame 2: younger.
    _add(tracks, 2, _ids(4))
    _add(tracks, 3, _ids(4))
    seen = {0: _ids(1, 2, 4)}
    # Frames before 1 leave: tracks 1 and 2 (first frame 0, still seen) are handed over,
    # track 3 (ended at frame 2) is not, nor track 4 (first frame 2).
    out = tracks.take_continuing(seen, leaving_before=1, limit={0: 1})
    obs, handed = out[0]
    assert list(handed) == [1]  # the limit: the oldest first (ties by piece)
    assert sorted(set(obs.frames.tolist())) == [0, 1, 2, 3] and obs.n_tracks == 1
    out = tracks.take_continuing(seen, leaving_before=1)
    assert list(out[0][1]) == [2]
    # Handed-over tracks left the live ones: take_due commits track 3 only (ended), and a
    # later observation of track 1 starts a new piece.
    due = tracks.take_due(4, seen, leaving_before=1)
    assert due[0].n_tracks == 1 and len(due[0]) == 3
    _add(tracks, 4, _ids(1, 2, 4))
    assert all(p >= 0 for p in tracks.piece_ids(0, _ids(1, 2, 4)).tolist())
    # A blind camera hands over nothing.
    assert tracks.take_continuing({0: _ids()}, leaving_before=10) == {}
