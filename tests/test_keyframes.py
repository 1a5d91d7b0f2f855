"""The keyframe rule on constructed motion: still, slow, fast, pure rotation, lost tracks."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from apcc_graph.estimation.keyframes import (
    KeyframeRule,
    keyframe_reasons,
    rotation_angle,
    view_change,
)

RULE = KeyframeRule(max_interval=0.2, rotation=0.05, parallax=0.01, survival=0.6)


def _scene(rng: np.random.Generator, n: int = 60) -> np.ndarray:
    """Points 1-3 m in front of the keyframe's camera (its frame)."""
    return np.column_stack([rng.uniform(-1.0, 1.0, (n, 2)), rng.uniform(1.0, 3.0, n)])


def _seen(points: np.ndarray, k_T_n: np.ndarray) -> np.ndarray:
    """The points' bearings from a camera at ``k_T_n`` (in the keyframe's camera frame)."""
    local = (points - k_T_n[:3, 3]) @ k_T_n[:3, :3]
    return local / np.linalg.norm(local, axis=1, keepdims=True)


def _change(rng: np.random.Generator, omega: np.ndarray, t: np.ndarray, keep: int = 60):
    points = _scene(rng)
    pose = gtsam.Pose3(gtsam.Rot3.Expmap(omega), t).matrix()
    return view_change(points[:keep], _seen(points, pose)[:keep], pose[:3, :3], 60)


def test_a_still_camera_waits_for_the_interval() -> None:
    change = _change(np.random.default_rng(0), np.zeros(3), np.zeros(3))
    assert change.rotation == 0.0 and change.parallax < 1e-12 and change.survival == 1.0
    assert keyframe_reasons(RULE, 0.1, {0: change}) == []
    assert keyframe_reasons(RULE, 0.2, {0: change}) == ["time"]


def test_slow_motion_waits_and_fast_motion_does_not() -> None:
    rng = np.random.default_rng(1)
    slow = _change(rng, np.array([0.0, 0.002, 0.0]), np.array([0.002, 0.0, 0.0]))
    assert keyframe_reasons(RULE, 0.05, {0: slow}) == []
    fast = _change(rng, np.array([0.0, 0.01, 0.0]), np.array([0.04, 0.0, 0.01]))
    assert fast.parallax > RULE.parallax
    assert keyframe_reasons(RULE, 0.05, {0: slow, 2: fast}) == ["parallax of camera 2"]


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_wrong_associations_in_both_frames_do_not_make_parallax(seed: int) -> None:
    """35% of the rows of each frame replaced by random bearings: more than half the pairs are
    wrong, and a still camera still has no parallax (the median would measure the jumps)."""
    rng = np.random.default_rng(seed)
    points = _scene(rng)
    now = _seen(points, np.eye(4))
    key = points / np.linalg.norm(points, axis=1, keepdims=True)
    for bearings in (key, now):
        wrong = rng.random(len(points)) < 0.35
        bearings[wrong] = _seen(_scene(rng, int(wrong.sum())), np.eye(4))
    change = view_change(key, now, np.eye(3), len(points))
    angles = np.arccos(np.clip(np.sum(key * now, axis=1), -1.0, 1.0))
    assert np.median(angles) > RULE.parallax  # what the median would have said
    assert change.parallax < 1e-9
    assert keyframe_reasons(RULE, 0.05, {0: change}) == []


def test_pure_rotation_has_no_parallax_but_makes_a_keyframe() -> None:
    change = _change(np.random.default_rng(2), np.array([0.03, -0.05, 0.01]), np.zeros(3))
    assert change.parallax < 1e-9  # the rotation explains every bearing
    np.testing.assert_allclose(change.rotation, np.linalg.norm([0.03, -0.05, 0.01]), rtol=1e-9)
    assert keyframe_reasons(RULE, 0.01, {1: change}) == ["rotation of camera 1"]


def test_lost_tracks_make_a_keyframe_and_too_few_have_no_parallax() -> None:
    rng = np.random.default_rng(3)
    half = _change(rng, np.zeros(3), np.array([0.001, 0.0, 0.0]), keep=30)
    assert half.survival == 0.5
    assert keyframe_reasons(RULE, 0.01, {0: half}) == ["tracks of camera 0"]
    few = _change(rng, np.zeros(3), np.array([0.2, 0.0, 0.0]), keep=3)
    assert np.isnan(few.parallax)


@settings(max_examples=50, deadline=None)
@given(omega=st.lists(st.floats(-3.0, 3.0), min_size=3, max_size=3))
def test_rotation_angle_is_the_norm_of_the_rotation_vector(omega: list[float]) -> None:
    w = np.array(omega)
    if np.linalg.norm(w) >= np.pi:
        w = w / np.linalg.norm(w) * 3.0
    R = gtsam.Rot3.Expmap(w).matrix()
    assert rotation_angle(R) == pytest.approx(np.linalg.norm(w), abs=1e-9)


def test_bad_rules_and_shapes_are_named() -> None:
    with pytest.raises(ValueError, match="KeyframeRule.parallax"):
        KeyframeRule(parallax=0.0)
    with pytest.raises(ValueError, match="KeyframeRule.survival"):
        KeyframeRule(survival=1.5)
    with pytest.raises(ValueError, match="same"):
        view_change(np.ones((4, 3)), np.ones((3, 3)), np.eye(3), 4)
