"""The in-memory sequence: validation, per-frame observations and correspondences."""

from __future__ import annotations

import numpy as np
import pytest

from apcc_graph import Robot, Segment, TipCamera
from apcc_graph.model.sequence import Sequence, Tracks

CAM = TipCamera(500.0, 500.0, 320.0, 240.0, 640, 480)
DISTORTED = TipCamera(480.0, 490.0, 315.0, 245.0, 640, 480, distortion=(-0.2, 0.05, 1e-3, -1e-3))


def robot(cameras=(CAM, None, DISTORTED)) -> Robot:
    return Robot([Segment(0.3)] * 3, list(cameras))


def random_tracks(rng: np.random.Generator, n_frames: int, n_ids: int = 40,
                  keep: float = 0.6) -> Tracks:
    """Each id seen in a random subset of frames, rows shuffled."""
    frames, ids = np.nonzero(rng.random((n_frames, n_ids)) < keep)
    order = rng.permutation(len(frames))
    uv = rng.uniform([0, 0], [640, 480], (len(frames), 2))
    return Tracks(frames[order], ids[order], uv[order])


def test_tracks_sort_by_frame_then_id_and_keep_rows_together() -> None:
    tracks = Tracks([2, 0, 2, 1], [5, 7, 1, 7], [[1, 1], [2, 2], [3, 3], [4, 4]])
    np.testing.assert_array_equal(tracks.frames, [0, 1, 2, 2])
    np.testing.assert_array_equal(tracks.track_ids, [7, 7, 1, 5])
    np.testing.assert_array_equal(tracks.uv[:, 0], [2, 4, 3, 1])
    np.testing.assert_array_equal(tracks.offsets(4), [0, 1, 2, 4, 4])
    with pytest.raises(ValueError):
        tracks.uv[0, 0] = 9.0  # read-only


@pytest.mark.parametrize(
    ("frames", "ids", "uv", "fragment"),
    [
        ([0, 0], [3, 3], [[1, 1], [2, 2]], "appears twice in frame 0"),
        ([0, 1], [3], [[1, 1], [2, 2]], "same N observations"),
        ([0, -1], [3, 4], [[1, 1], [2, 2]], "non-negative integers"),
        ([0, 1.5], [3, 4], [[1, 1], [2, 2]], "non-negative integers"),
        ([0, 1], [3, 4], [[1, np.nan], [2, 2]], "finite pixel"),
    ],
)
def test_tracks_validation(frames, ids, uv, fragment: str) -> None:
    with pytest.raises(ValueError, match=fragment):
        Tracks(frames, ids, uv)


@pytest.mark.parametrize(
    ("kwargs", "fragment"),
    [
        ({"timestamps": []}, "expected \\(F,\\)"),
        ({"timestamps": [0.0, 0.1, 0.1]}, "frame 2 .* is not after frame 1"),
        ({"timestamps": [0.0, np.inf]}, "finite"),
        ({"tracks": {1: Tracks([0], [0], [[1, 1]])}}, "has no camera"),
        ({"tracks": {0: Tracks([5], [0], [[1, 1]])}}, "frame 5 but the sequence has 3"),
        ({"world_T_base": np.eye(4)}, "world_T_base has shape"),
        ({"world_T_base": np.stack([np.eye(4), np.eye(4), 2 * np.eye(4)])},
         "world_T_base\\[2\\]"),
        ({"thetas": np.zeros((3, 2))}, "thetas has shape"),
        ({"psis": np.full((3, 3), np.nan)}, "psis: expected finite"),
    ],
)
def test_sequence_validation(kwargs: dict, fragment: str) -> None:
    args = {"timestamps": [0.0, 0.1, 0.2]} | kwargs
    with pytest.raises(ValueError, match=fragment):
        Sequence(robot(), **args)


def test_observations_are_the_rows_of_that_frame() -> None:
    rng = np.random.default_rng(0)
    tracks = random_tracks(rng, 12)
    seq = Sequence(robot(), np.arange(12) / 30.0, {0: tracks})
    total = 0
    for f in range(12):
        ids, uv = seq.observations(0, f)
        rows = tracks.frames == f
        np.testing.assert_array_equal(ids, tracks.track_ids[rows])
        np.testing.assert_array_equal(uv, tracks.uv[rows])
        assert np.all(np.diff(ids) > 0)
        total += len(ids)
    assert total == len(tracks)
    # A camera with no tracks sees nothing; a segment without a camera is an error.
    ids, uv = seq.observations(2, 3)
    assert ids.shape == (0,) and uv.shape == (0, 2)
    with pytest.raises(KeyError):
        seq.observations(1, 0)
    with pytest.raises(IndexError):
        seq.observations(0, 12)


@pytest.mark.parametrize("cam", [0, 2])
def test_correspondences_match_a_brute_force_join(cam: int) -> None:
    rng = np.random.default_rng(1)
    tracks = random_tracks(rng, 10)
    seq = Sequence(robot(), np.arange(10) / 30.0, {cam: tracks})
    camera = seq.robot.cameras[cam]
    for a, b in [(0, 1), (2, 9), (5, 5)]:
        corr = seq.correspondences(cam, a, b)
        in_a = {i: uv for i, uv in zip(*seq.observations(cam, a), strict=True)}
        in_b = {i: uv for i, uv in zip(*seq.observations(cam, b), strict=True)}
        common = sorted(set(in_a) & set(in_b))
        np.testing.assert_array_equal(corr.track_ids, common)
        np.testing.assert_array_equal(corr.uv_a, [in_a[i] for i in common])
        np.testing.assert_array_equal(corr.uv_b, [in_b[i] for i in common])
        np.testing.assert_allclose(corr.f_a, camera.bearings(corr.uv_a), atol=1e-15)
        np.testing.assert_allclose(corr.f_b, camera.bearings(corr.uv_b), atol=1e-15)
        np.testing.assert_allclose(np.linalg.norm(corr.f_b, axis=1), 1.0, atol=1e-15)
        assert len(corr) == len(common)


def test_bearings_honour_distortion() -> None:
    """The distorted camera's bearings differ from a pinhole reading of the same pixels."""
    uv = np.array([[20.0, 30.0], [600.0, 450.0]])
    seq = Sequence(robot(), [0.0], {2: Tracks([0, 0], [0, 1], uv)})
    pinhole = np.column_stack([(uv - [315.0, 245.0]) / [480.0, 490.0], np.ones(2)])
    pinhole /= np.linalg.norm(pinhole, axis=1, keepdims=True)
    assert np.max(np.abs(seq.bearings(2) - pinhole)) > 1e-2
    np.testing.assert_allclose(DISTORTED.project(seq.bearings(2)), uv, atol=1e-9)


def test_equals_compares_everything() -> None:
    rng = np.random.default_rng(2)
    tracks = random_tracks(rng, 5)
    seq = Sequence(robot(), np.arange(5.0), {0: tracks}, thetas=np.zeros((5, 3)))
    same = Sequence(robot(), np.arange(5.0), {0: Tracks(tracks.frames, tracks.track_ids,
                                                        tracks.uv)}, thetas=np.zeros((5, 3)))
    assert seq.equals(same)
    assert not seq.equals(Sequence(robot(), np.arange(5.0), {0: tracks}))
    moved = tracks.uv.copy()
    moved[0, 0] += 1e-9
    assert not seq.equals(Sequence(robot(), np.arange(5.0),
                                   {0: Tracks(tracks.frames, tracks.track_ids, moved)},
                                   thetas=np.zeros((5, 3))))
