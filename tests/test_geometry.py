"""Two-view geometry of a tip camera: relative pose, essential matrix, Sampson error, derivative."""

from __future__ import annotations

import math

import gtsam
import numpy as np
import pytest
from helpers import random_pose

from apcc_graph.frontend.geometry import (
    SegmentTwoView,
    epipolar_errors,
    essential_matrix,
    relative_camera_pose,
    sampson_error,
    skew,
)
from apcc_graph.model.camera import TipCamera
from apcc_graph.model.kinematics import apcc_transform
from apcc_graph.model.robot import Robot
from apcc_graph.model.segment import Segment

FOCAL = 500.0


# ------------------------------------------------------------------------------------ helpers


def random_segment(rng: np.random.Generator) -> Segment:
    theta_max = math.radians(rng.uniform(10.0, 80.0))
    delta_max = math.radians(rng.uniform(-10.0, 10.0)) * min(1.0, theta_max / math.radians(12.0))
    return Segment(rng.uniform(0.1, 0.5), rng.uniform(0.05, 0.45), delta_max, theta_max)


def random_case(rng: np.random.Generator, moving_base: bool, spatial: bool = True) -> dict:
    """A segment, two angles a few degrees apart, a mounting, a base motion and psi."""
    seg = random_segment(rng)
    step = math.radians(rng.uniform(0.5, 5.0)) * rng.choice([-1.0, 1.0])
    theta_a = rng.uniform(-seg.theta_max + abs(step), seg.theta_max - abs(step))
    return {
        "segment": seg,
        "theta_a": theta_a,
        "theta_b": theta_a + step,
        "tip_T_cam": random_pose(rng, 0.2, 0.02),
        "baseA_T_baseB": random_pose(rng, 0.03, 0.01) if moving_base else None,
        "psi": rng.uniform(-math.pi, math.pi) if spatial else 0.0,
    }


def pose_of(case: dict, theta_b: float | np.ndarray | None = None) -> np.ndarray:
    return relative_camera_pose(
        case["theta_a"], case["theta_b"] if theta_b is None else theta_b, case["segment"],
        case["tip_T_cam"], case["baseA_T_baseB"], case["psi"])


def bearings(rng: np.random.Generator, camA_T_camB: np.ndarray, n: int,
             noise_px: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Bearings of n random points (z in 2..8 m, in a 640x480 f = 500 view) in cameras A, B."""
    z = rng.uniform(2.0, 8.0, n)
    P = np.column_stack([rng.uniform(-0.64, 0.64, n) * z, rng.uniform(-0.48, 0.48, n) * z, z])
    R, t = camA_T_camB[:3, :3], camA_T_camB[:3, 3]
    P_b = (P - t) @ R
    f_a = P / np.linalg.norm(P, axis=1, keepdims=True)
    f_b = P_b / np.linalg.norm(P_b, axis=1, keepdims=True)
    if noise_px:
        f_a, f_b = (add_pixel_noise(rng, f, noise_px) for f in (f_a, f_b))
    return f_a, f_b


def add_pixel_noise(rng: np.random.Generator, f: np.ndarray, noise_px: float) -> np.ndarray:
    xy = f[:, :2] / f[:, 2:3] + rng.normal(0.0, noise_px / FOCAL, (len(f), 2))
    rays = np.column_stack([xy, np.ones(len(f))])
    return rays / np.linalg.norm(rays, axis=1, keepdims=True)


def unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


# ------------------------------------------------------------------------ relative pose
@pytest.mark.parametrize("seed", range(6))
def test_relative_pose_is_camA_inverse_times_camB_from_world_poses(seed: int) -> None:
    rng = np.random.default_rng(seed)
    seg = random_segment(rng)
    theta_a, psi = rng.uniform(-seg.theta_max, seg.theta_max), rng.uniform(-math.pi, math.pi)
    theta_b = rng.uniform(-seg.theta_max, seg.theta_max, 5)
    tip_T_cam = random_pose(rng, 0.5, 0.05)
    world_T_baseA, world_T_baseB = random_pose(rng, 1.0, 1.0), random_pose(rng, 1.0, 1.0)
    baseA_T_baseB = np.linalg.inv(world_T_baseA) @ world_T_baseB

    world_T_camA = world_T_baseA @ apcc_transform(theta_a, seg, psi) @ tip_T_cam
    world_T_camB = world_T_baseB @ apcc_transform(theta_b, seg, psi) @ tip_T_cam
    expected = np.linalg.inv(world_T_camA) @ world_T_camB

    got = relative_camera_pose(theta_a, theta_b, seg, tip_T_cam, baseA_T_baseB, psi)
    assert got.shape == (5, 4, 4)
    np.testing.assert_allclose(got, expected, atol=1e-12)
    scalar = relative_camera_pose(theta_a, theta_b[2], seg, tip_T_cam, baseA_T_baseB, psi)
    assert scalar.shape == (4, 4)
    np.testing.assert_allclose(scalar, expected[2], atol=1e-12)


def test_relative_pose_matches_robot_camera_poses_for_an_outer_segment() -> None:
    """Segment 2's base moves with segment 1: the base motion is segment 1's tip motion."""
    rng = np.random.default_rng(11)
    segs = [Segment(0.3, 0.22, 0.1, 1.0), Segment(0.25, 0.3, -0.05, 0.9)]
    tip_T_cam = random_pose(rng, 0.3, 0.02)
    cam = TipCamera(FOCAL, FOCAL, 320.0, 240.0, 640, 480, tip_T_cam=tip_T_cam)
    robot = Robot(segs, [None, cam])
    thetas = np.array([[0.3, -0.2], [0.35, -0.17]])
    world_T_base = np.stack([random_pose(rng, 0.1, 0.1), random_pose(rng, 0.1, 0.1)])
    tips = robot.forward(thetas, world_T_base=world_T_base)
    cams = robot.camera_poses(thetas, world_T_base=world_T_base)[1]
    base_motion = np.linalg.inv(tips[0, 0]) @ tips[1, 0]
    got = relative_camera_pose(thetas[0, 1], thetas[1, 1], segs[1], tip_T_cam, base_motion)
    np.testing.assert_allclose(got, np.linalg.inv(cams[0]) @ cams[1], atol=1e-12)


@pytest.mark.parametrize("seed", range(4))
def test_relative_pose_is_identity_without_motion(seed: int) -> None:
    rng = np.random.default_rng(100 + seed)
    seg = random_segment(rng)
    theta = rng.uniform(-seg.theta_max, seg.theta_max)
    tip_T_cam = random_pose(rng, 0.5, 0.05)
    for base in (None, np.eye(4)):
        pose = relative_camera_pose(theta, theta, seg, tip_T_cam, base, psi=rng.uniform(-3, 3))
        np.testing.assert_allclose(pose, np.eye(4), atol=1e-14)
    # ... but not when the base moved.
    moved = relative_camera_pose(theta, theta, seg, tip_T_cam, random_pose(rng, 0.05, 0.01))
    assert np.max(np.abs(moved - np.eye(4))) > 1e-4


def test_relative_pose_rejects_non_4x4_transforms() -> None:
    seg = Segment(0.3)
    with pytest.raises(ValueError, match="4x4"):
        relative_camera_pose(0.1, 0.2, seg, tip_T_cam=np.eye(3))
    with pytest.raises(ValueError, match="4x4"):
        relative_camera_pose(0.1, 0.2, seg, baseA_T_baseB=np.eye(4)[:3])


# --------------------------------------------------------------------- essential matrix
@pytest.mark.parametrize("seed", range(8))
def test_essential_matrix_annihilates_noise_free_correspondences(seed: int) -> None:
    rng = np.random.default_rng(200 + seed)
    case = random_case(rng, moving_base=bool(seed % 2))
    pose = pose_of(case)
    f_a, f_b = bearings(rng, pose, 100)
    E = essential_matrix(pose)
    residual = np.einsum("ni,ij,nj->n", f_a, E, f_b)
    assert np.max(np.abs(residual)) < 1e-12
    # ... and it is not trivially small: the wrong angle violates it clearly.
    E_wrong = essential_matrix(pose_of(case, case["theta_b"] + 0.05))
    assert np.median(np.abs(np.einsum("ni,ij,nj->n", f_a, E_wrong, f_b))) > 1e-6


def test_essential_matrix_is_skew_t_times_R_and_broadcasts() -> None:
    rng = np.random.default_rng(3)
    poses = np.stack([random_pose(rng, 1.0, 1.0) for _ in range(4)]).reshape(2, 2, 4, 4)
    E = essential_matrix(poses)
    assert E.shape == (2, 2, 3, 3)
    for idx in np.ndindex(2, 2):
        R, t = poses[idx][:3, :3], poses[idx][:3, 3]
        tx = np.array([[0.0, -t[2], t[1]], [t[2], 0.0, -t[0]], [-t[1], t[0], 0.0]])
        np.testing.assert_allclose(E[idx], tx @ R, atol=1e-15)
        v = rng.normal(size=3)
        np.testing.assert_allclose(E[idx] @ v, np.cross(t, R @ v), atol=1e-14)
    np.testing.assert_allclose(skew(np.array([1.0, 2.0, 3.0])) @ np.array([4.0, 5.0, 6.0]),
                               np.cross([1.0, 2.0, 3.0], [4.0, 5.0, 6.0]))


# ------------------------------------------------------------------------- Sampson error
def sampson_gradients(f_a: np.ndarray, f_b: np.ndarray, E: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray]:
    """Tangent-plane gradients of ``f_a^T E f_b``: ``P_a E f_b`` and ``P_b E^T f_a``."""
    Efb, Etfa = f_b @ E.T, f_a @ E
    g_a = Efb - np.sum(f_a * Efb, axis=1, keepdims=True) * f_a
    g_b = Etfa - np.sum(f_b * Etfa, axis=1, keepdims=True) * f_b
    return g_a, g_b


@pytest.mark.parametrize("seed", range(6))
def test_sampson_error_is_zero_on_noise_free_data(seed: int) -> None:
    rng = np.random.default_rng(300 + seed)
    case = random_case(rng, moving_base=bool(seed % 2))
    pose = pose_of(case)
    f_a, f_b = bearings(rng, pose, 200)
    e = sampson_error(f_a, f_b, essential_matrix(pose))
    assert e.shape == (200,)
    assert np.max(np.abs(e)) < 1e-9
    # A wrong angle (1 degree off) gives errors far above zero (weakly: the bend's rotation moves
    # points mostly along their epipolar lines, docs/estimation.md, "Two frames").
    e_wrong = sampson_error(f_a, f_b, essential_matrix(pose_of(case, case["theta_b"] + 0.02)))
    assert np.median(np.abs(e_wrong)) > 0.1 / FOCAL


@pytest.mark.parametrize("seed", range(6))
def test_sampson_error_is_first_order_geometric_distance_in_radians(seed: int) -> None:
    """Moving both bearings by a total tangent-plane angle eps off the constraint gives |e| = eps.

    The Sampson error is the first-order distance to the constraint in the joint tangent space of
    both bearings. Moving only f_b by eps perpendicular to its epipolar plane therefore gives
    ``|e| = eps |P_b E^T f_a| / sqrt(|P_a E f_b|^2 + |P_b E^T f_a|^2) <= eps``, which is eps only
    when the other bearing cannot absorb part of the correction.
    """
    rng = np.random.default_rng(400 + seed)
    case = random_case(rng, moving_base=bool(seed % 2))
    pose = pose_of(case)
    E = essential_matrix(pose)
    f_a, f_b = bearings(rng, pose, 200)
    eps = 1e-4
    g_a, g_b = sampson_gradients(f_a, f_b, E)
    norm = np.sqrt(np.sum(g_a**2, axis=1) + np.sum(g_b**2, axis=1))
    keep = norm > 1e-3 * np.median(norm)  # points far from the epipoles
    f_a, f_b, g_a, g_b, norm = f_a[keep], f_b[keep], g_a[keep], g_b[keep], norm[keep]
    assert len(f_a) > 150

    # Joint move: a rotation of each bearing on its tangent plane, total angle eps.
    steps_a = eps * g_a / norm[:, None]
    steps_b = eps * g_b / norm[:, None]
    np.testing.assert_allclose(np.sqrt(np.sum(steps_a**2 + steps_b**2, axis=1)), eps, rtol=1e-12)
    moved_a = rotate_towards(f_a, steps_a)
    moved_b = rotate_towards(f_b, steps_b)
    e = sampson_error(moved_a, moved_b, E)
    np.testing.assert_allclose(np.abs(e), eps, rtol=1e-2)

    # f_b alone, perpendicular to its epipolar plane (the plane through f_b and the epipole).
    normal_b = unit(f_a @ E)  # E^T f_a: the epipolar plane's normal in camera B
    assert np.max(np.abs(np.sum(normal_b * f_b, axis=1))) < 1e-9  # already on the tangent plane
    e_b = sampson_error(f_a, rotate_towards(f_b, eps * normal_b), E)
    expected = eps * np.linalg.norm(g_b, axis=1) / norm
    np.testing.assert_allclose(np.abs(e_b), expected, rtol=1e-2)
    assert np.all(np.abs(e_b) <= eps * (1 + 1e-2))


def rotate_towards(f: np.ndarray, step: np.ndarray) -> np.ndarray:
    """Rotate unit f by |step| radians toward the tangent vector step (perpendicular to f)."""
    angle = np.linalg.norm(step, axis=1, keepdims=True)
    direction = step / np.where(angle > 0, angle, 1.0)
    return np.cos(angle) * f + np.sin(angle) * direction


def test_sampson_error_in_pixels_for_a_pixel_shift() -> None:
    """A 1-pixel shift of f_b across its epipolar line reads as at most 1/f radians."""
    rng = np.random.default_rng(7)
    case = random_case(rng, moving_base=False)
    case["theta_b"] = case["theta_a"] + math.radians(3.0)
    pose = pose_of(case)
    E = essential_matrix(pose)
    f_a, f_b = bearings(rng, pose, 100)
    normal_b = unit(f_a @ E)
    shifted = rotate_towards(f_b, normal_b / FOCAL)
    e = np.abs(sampson_error(f_a, shifted, E))
    assert np.all(e <= 1.0 / FOCAL * 1.01)
    assert np.median(e) > 0.3 / FOCAL
    # The algebraic residual, by contrast, scales with the translation.
    alg = np.abs(np.einsum("ni,ij,nj->n", f_a, E, shifted))
    assert np.median(alg) < 0.1 * np.median(e)


@pytest.mark.parametrize("scale", [1e-6, 0.37, 12.0, -1.0, -4.5, -1e-8])
def test_sampson_error_is_invariant_to_scaling_E(scale: float) -> None:
    rng = np.random.default_rng(8)
    case = random_case(rng, moving_base=True)
    pose = pose_of(case)
    E = essential_matrix(pose)
    f_a, f_b = bearings(rng, pose, 50, noise_px=1.0)
    e = sampson_error(f_a, f_b, E)
    e_scaled = sampson_error(f_a, f_b, scale * E)
    assert np.median(np.abs(e)) > 1e-4  # the noise gives non-trivial errors to compare
    np.testing.assert_allclose(np.abs(e_scaled), np.abs(e), rtol=1e-10)
    np.testing.assert_allclose(e_scaled, np.sign(scale) * e, rtol=1e-10)


def test_sampson_error_is_zero_without_motion_never_nan() -> None:
    rng = np.random.default_rng(9)
    f_a, f_b = unit(rng.normal(size=(20, 3))), unit(rng.normal(size=(20, 3)))
    with np.errstate(all="raise"):
        e = sampson_error(f_a, f_b, np.zeros((3, 3)))
        assert e.shape == (20,)
        np.testing.assert_array_equal(e, 0.0)
        Es = np.stack([np.zeros((3, 3)), essential_matrix(random_pose(rng, 0.1, 0.1))])
        e2, de2 = sampson_error(f_a, f_b, Es, dE=np.ones((2, 3, 3)))
    assert e2.shape == de2.shape == (2, 20)
    np.testing.assert_array_equal(e2[0], 0.0)
    np.testing.assert_array_equal(de2[0], 0.0)
    assert np.all(np.isfinite(e2)) and np.all(np.abs(e2[1]) > 0)


def test_sampson_error_shapes_for_many_essential_matrices() -> None:
    rng = np.random.default_rng(10)
    f_a, f_b = unit(rng.normal(size=(7, 3))), unit(rng.normal(size=(7, 3)))
    Es = essential_matrix(np.stack([random_pose(rng, 0.3, 0.3) for _ in range(4)]))
    e = sampson_error(f_a, f_b, Es)
    assert e.shape == (4, 7)
    for m in range(4):
        single = sampson_error(f_a, f_b, Es[m])
        assert single.shape == (7,)
        np.testing.assert_allclose(e[m], single, rtol=1e-13, atol=1e-16)
    # The closed form for unit bearings equals the projector form of the module docstring.
    for m in range(4):
        g_a, g_b = sampson_gradients(f_a, f_b, Es[m])
        num = np.einsum("ni,ij,nj->n", f_a, Es[m], f_b)
        direct = num / np.sqrt(np.sum(g_a**2, axis=1) + np.sum(g_b**2, axis=1))
        np.testing.assert_allclose(e[m], direct, rtol=1e-10)


# ----------------------------------------------------------------- epipolar errors + derivative
@pytest.mark.parametrize("seed", range(10))
def test_epipolar_error_derivative_matches_central_differences(seed: int) -> None:
    rng = np.random.default_rng(500 + seed)
    case = random_case(rng, moving_base=bool(seed % 2), spatial=seed != 0)
    assert seed == 0 or case["psi"] != 0.0
    view = SegmentTwoView.build(case["theta_a"], case["segment"], case["tip_T_cam"],
                                case["baseA_T_baseB"], case["psi"])
    f_a, f_b = bearings(rng, pose_of(case), 40, noise_px=1.0)
    # Hypotheses around the truth, away from theta_a (where E -> 0 and e is not smooth).
    hyps = case["theta_b"] + rng.uniform(-0.05, 0.05, 6)
    hyps = hyps[np.abs(hyps - case["theta_a"]) > 0.005]
    e, de = epipolar_errors(f_a, f_b, view, hyps, derivative=True)
    assert e.shape == de.shape == (len(hyps), 40)
    np.testing.assert_array_equal(e, epipolar_errors(f_a, f_b, view, hyps))
    h = 1e-6
    numeric = (epipolar_errors(f_a, f_b, view, hyps + h)
               - epipolar_errors(f_a, f_b, view, hyps - h)) / (2 * h)
    np.testing.assert_allclose(de, numeric, rtol=1e-6, atol=1e-6 * np.max(np.abs(de)))
    # Scalar hypothesis: (N,) shapes.
    e1, de1 = epipolar_errors(f_a, f_b, view, float(hyps[0]), derivative=True)
    assert e1.shape == de1.shape == (40,)
    np.testing.assert_allclose(de1, de[0], rtol=1e-12, atol=1e-15)


def test_epipolar_errors_vanish_at_the_true_angle_only() -> None:
    rng = np.random.default_rng(12)
    case = random_case(rng, moving_base=True)
    view = SegmentTwoView.build(case["theta_a"], case["segment"], case["tip_T_cam"],
                                case["baseA_T_baseB"], case["psi"])
    f_a, f_b = bearings(rng, pose_of(case), 60)
    e = epipolar_errors(f_a, f_b, view, np.array([case["theta_b"], case["theta_b"] + 0.01]))
    assert np.max(np.abs(e[0])) < 1e-9
    assert np.median(np.abs(e[1])) > 0.1 / FOCAL


# ------------------------------------------------------------------------ SegmentTwoView
def test_segment_two_view_fixed_base_flag() -> None:
    seg = Segment(0.3, 0.2, 0.05, 1.0)
    rng = np.random.default_rng(13)
    tip = random_pose(rng, 0.3, 0.02)
    assert SegmentTwoView.build(0.2, seg).fixed_base
    assert SegmentTwoView.build(0.2, seg, tip, None).fixed_base
    assert SegmentTwoView.build(0.2, seg, tip, np.eye(4)).fixed_base
    assert SegmentTwoView.build(0.2, seg, tip, np.eye(4).tolist()).fixed_base
    assert not SegmentTwoView.build(0.2, seg, tip, random_pose(rng, 0.01, 0.001)).fixed_base
    shifted = np.eye(4)
    shifted[0, 3] = 1e-6
    assert not SegmentTwoView.build(0.2, seg, tip, shifted).fixed_base
    turned = gtsam.Pose3(gtsam.Rot3.Rz(1e-6), np.zeros(3)).matrix()
    assert not SegmentTwoView.build(0.2, seg, tip, turned).fixed_base


def test_segment_two_view_pose_and_derivative() -> None:
    rng = np.random.default_rng(14)
    case = random_case(rng, moving_base=True)
    view = SegmentTwoView.build(case["theta_a"], case["segment"], case["tip_T_cam"],
                                case["baseA_T_baseB"], case["psi"])
    assert view.theta_a == case["theta_a"] and view.psi == case["psi"]
    thetas = np.array([-0.2, 0.0, 0.3])
    np.testing.assert_allclose(view.relative_pose(thetas), pose_of(case, thetas), atol=1e-14)
    h = 1e-6
    numeric = (view.relative_pose(thetas + h) - view.relative_pose(thetas - h)) / (2 * h)
    np.testing.assert_allclose(view.relative_pose_derivative(thetas), numeric, atol=1e-8)
