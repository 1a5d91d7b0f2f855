"""Every gtsam key in one module (apcc_graph.factors.keys): kinds never collide, each key is
described back as what it stands for, and the elimination groups put points first and frame
vectors last."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from apcc_graph.factors import keys

frames = st.integers(0, 10**6)
small = st.integers(0, keys.MAX_SEGMENTS - 1)


@given(frames, small, st.integers(0, 2**31))
def test_keys_of_different_kinds_never_collide(frame: int, j: int, n: int) -> None:
    made = [keys.frame_key(frame), keys.tip_key(frame, j), keys.camera_pose_key(frame, j),
            keys.point_key(j, n), keys.calibration_key(j), keys.mount_key(j)]
    assert len(set(made)) == len(made)
    assert [keys.kind(k) for k in made] == ["x", "t", "p", "l", "c", "m"]


@given(frames, small)
def test_a_key_is_described_as_what_it_stands_for(frame: int, j: int) -> None:
    assert keys.describe(keys.frame_key(frame)) == f"frame {frame}'s bends"
    assert keys.describe(keys.tip_key(frame, j)) == f"frame {frame}'s segment {j + 1} tip"
    assert keys.describe(keys.camera_pose_key(frame, j)) == f"frame {frame}'s camera {j + 1} pose"
    assert keys.describe(keys.point_key(j, frame)) == f"camera {j + 1}'s point {frame}"


def test_out_of_range_indices_are_refused() -> None:
    with pytest.raises(ValueError, match="segment 64"):
        keys.tip_key(0, 64)
    with pytest.raises(ValueError, match="camera 64"):
        keys.camera_pose_key(0, 64)
    with pytest.raises(ValueError, match="point"):
        keys.point_key(0, 2**32)


def test_points_are_eliminated_first_and_frame_vectors_last() -> None:
    groups = [keys.elimination_group(k) for k in
              (keys.point_key(1, 5), keys.tip_key(3, 1), keys.camera_pose_key(3, 1),
               keys.frame_key(3))]
    assert groups == [0, 1, 1, 2]
