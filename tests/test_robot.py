"""Robot.forward: the chained product of segment transforms, vectorised, with cameras and a base."""

from __future__ import annotations

import math

import gtsam
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from apcc_graph import Robot, Segment, TipCamera
from apcc_graph.model.kinematics import apcc_transform
from apcc_graph.model.robot import _CHUNK

SEGMENTS = [
    Segment(0.3, k=0.2, delta_max=0.1, theta_max=1.0),
    Segment(0.25),
    Segment(0.2, k=0.3, delta_max=-0.2, theta_max=1.5),
]


def random_pose(rng: np.random.Generator) -> np.ndarray:
    rot = gtsam.Rot3.Expmap(rng.normal(size=3))
    return gtsam.Pose3(rot, rng.normal(size=3)).matrix()


def chained(thetas: np.ndarray, psis: np.ndarray, base: np.ndarray) -> np.ndarray:
    """Reference: multiply 4x4 segment transforms frame by frame."""
    out = np.empty(thetas.shape + (4, 4))
    for f in range(len(thetas)):
        T = base[f] if base.ndim == 3 else base
        for i, seg in enumerate(SEGMENTS):
            T = T @ apcc_transform(thetas[f, i], seg, psis[f, i])
            out[f, i] = T
    return out


@pytest.mark.parametrize("spatial", [False, True])
@pytest.mark.parametrize("per_frame_base", [None, False, True])
def test_forward_equals_chained_transforms(spatial: bool, per_frame_base: bool | None) -> None:
    rng = np.random.default_rng(3)
    robot = Robot(SEGMENTS)
    n = 50
    thetas = rng.uniform(-1.5, 1.5, (n, 3))
    psis = rng.uniform(-math.pi, math.pi, (n, 3)) if spatial else np.zeros((n, 3))
    if per_frame_base is None:
        base, arg = np.eye(4), None
    elif per_frame_base:
        base = np.stack([random_pose(rng) for _ in range(n)])
        arg = base
    else:
        base = arg = random_pose(rng)
    got = robot.forward(thetas, psis if spatial else None, arg)
    np.testing.assert_allclose(got, chained(thetas, psis, base), atol=1e-13)


def test_forward_across_chunks_and_threads() -> None:
    """Frame counts that span several blocks (the threaded path) give the same per-frame result."""
    rng = np.random.default_rng(4)
    robot = Robot(SEGMENTS)
    n = 5 * _CHUNK + 17
    thetas = rng.uniform(-1, 1, (n, 3))
    psis = rng.uniform(-3, 3, (n, 3))
    full = robot.forward(thetas, psis)
    picks = rng.choice(n, 40, replace=False)
    np.testing.assert_allclose(full[picks], chained(thetas[picks], psis[picks], np.eye(4)),
                               atol=1e-13)
    np.testing.assert_allclose(robot.forward(thetas), robot.forward(thetas, np.zeros_like(psis)),
                               atol=1e-14)


def test_forward_shapes_and_broadcasting() -> None:
    robot = Robot(SEGMENTS)
    assert robot.forward(np.zeros(3)).shape == (3, 4, 4)
    assert robot.forward(np.zeros((7, 3))).shape == (7, 3, 4, 4)
    assert robot.forward(np.zeros((2, 5, 3))).shape == (2, 5, 3, 4, 4)
    # One configuration seen from 4 base poses broadcasts to 4 frames.
    bases = np.stack([np.eye(4)] * 4)
    bases[:, 0, 3] = np.arange(4)
    out = robot.forward(np.full(3, 0.2), world_T_base=bases)
    assert out.shape == (4, 3, 4, 4)
    np.testing.assert_allclose(out[:, -1, 0, 3] - out[0, -1, 0, 3], np.arange(4), atol=1e-15)
    # Straight robot: the last tip is at the total length along z.
    np.testing.assert_allclose(robot.forward(np.zeros(3))[-1, :3, 3], [0, 0, 0.75], atol=1e-15)


@settings(max_examples=50, deadline=None)
@given(thetas=arrays(np.float64, (4, 3), elements=st.floats(-3.0, 3.0)),
       psis=arrays(np.float64, (4, 3), elements=st.floats(-3.2, 3.2)))
def test_forward_returns_rigid_transforms(thetas: np.ndarray, psis: np.ndarray) -> None:
    out = Robot(SEGMENTS).forward(thetas, psis)
    rot = out[..., :3, :3]
    np.testing.assert_allclose(np.swapaxes(rot, -1, -2) @ rot, np.broadcast_to(np.eye(3),
                                                                               rot.shape),
                               atol=1e-13)
    np.testing.assert_allclose(np.linalg.det(rot), 1.0, atol=1e-13)
    np.testing.assert_array_equal(out[..., 3, :], np.broadcast_to([0, 0, 0, 1.0],
                                                                  out[..., 3, :].shape))
    # Consecutive tips differ by exactly that segment's transform.
    rel = np.linalg.inv(out[:, 0]) @ out[:, 1]
    np.testing.assert_allclose(rel, apcc_transform(thetas[:, 1], SEGMENTS[1], psis[:, 1]),
                               atol=1e-12)


def test_camera_poses_ride_on_their_segments() -> None:
    rng = np.random.default_rng(5)
    mount = random_pose(rng)
    cam = TipCamera(500, 500, 320, 240, 640, 480, tip_T_cam=mount)
    robot = Robot(SEGMENTS, [cam, None, cam])
    assert robot.camera_segments == (0, 2)
    thetas = rng.uniform(-1, 1, (6, 3))
    poses = robot.camera_poses(thetas)
    assert sorted(poses) == [0, 2]
    tips = robot.forward(thetas)
    np.testing.assert_allclose(poses[2], tips[:, 2] @ mount, atol=1e-14)
    np.testing.assert_allclose(poses[0], tips[:, 0] @ mount, atol=1e-14)


@pytest.mark.parametrize(
    ("call", "fragment"),
    [
        (lambda r: r.forward(np.zeros(2)), "expected (..., 3)"),
        (lambda r: r.forward(0.0), "expected (..., 3)"),
        (lambda r: r.forward(np.zeros((4, 3)), np.zeros((4, 2))), "psis"),
        (lambda r: r.forward(np.zeros(3), world_T_base=np.eye(3)), "world_T_base"),
    ],
)
def test_forward_rejects_bad_shapes(call, fragment: str) -> None:
    with pytest.raises(ValueError, match=fragment.replace("(", r"\(").replace(")", r"\)")
                       .replace(".", r"\.")):
        call(Robot(SEGMENTS))


def test_robot_validation() -> None:
    with pytest.raises(ValueError, match="at least one segment"):
        Robot([])
    with pytest.raises(ValueError, match=r"Robot.segments\[1\]"):
        Robot([SEGMENTS[0], "segment"])  # type: ignore[list-item]
    with pytest.raises(ValueError, match="one per segment"):
        Robot(SEGMENTS, [None])
    with pytest.raises(ValueError, match=r"Robot.cameras\[0\]"):
        Robot(SEGMENTS[:1], ["camera"])  # type: ignore[list-item]
    robot = Robot(SEGMENTS)
    assert robot.cameras == (None, None, None) and robot.n_segments == 3
    assert robot == Robot(list(SEGMENTS)) and robot != Robot(SEGMENTS[:2])
