"""Tests of the tip camera: validation, projection, bearings, image bounds, equality."""

from __future__ import annotations

import dataclasses
import math

import gtsam
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from apcc_graph.model.camera import OPENCV_DISTORTION_SIZES, TipCamera, is_rigid, validate_pose

DISTORTION = (-0.2, 0.05, 1e-3, -1e-3)
BASE = {"fx": 500.0, "fy": 510.0, "cx": 320.0, "cy": 240.0, "width": 640, "height": 480}


def _camera(**changes: object) -> TipCamera:
    return TipCamera(**{**BASE, **changes})


def _rigid(angles: tuple[float, float, float], translation: tuple[float, float, float]):
    pose = np.eye(4)
    pose[:3, :3] = gtsam.Rot3.RzRyRx(*angles).matrix()
    pose[:3, 3] = translation
    return pose


def _scaled_rotation() -> np.ndarray:
    pose = np.eye(4)
    pose[:3, :3] *= 1.01
    return pose


def _bad_bottom_row() -> np.ndarray:
    pose = np.eye(4)
    pose[3] = [0.0, 0.0, 1.0, 1.0]
    return pose


def _nan_translation() -> np.ndarray:
    pose = np.eye(4)
    pose[0, 3] = math.nan
    return pose


def _points_seen(camera: TipCamera, n: int, seed: int, margin: float = 0.0) -> np.ndarray:
    """3-D points in front of ``camera`` whose undistorted pixels fall inside the image."""
    rng = np.random.default_rng(seed)
    u = rng.uniform(margin, camera.width - margin, n)
    v = rng.uniform(margin, camera.height - margin, n)
    depth = rng.uniform(0.05, 20.0, n)
    xy = np.column_stack([(u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy])
    return np.column_stack([xy, np.ones(n)]) * depth[:, None]


def _unit(points: np.ndarray) -> np.ndarray:
    return points / np.linalg.norm(points, axis=1, keepdims=True)


# ---------------------------------------------------------------------------------- validation
@pytest.mark.parametrize(
    ("changes", "field"),
    [
        pytest.param({"fx": 0.0}, "fx", id="fx-zero"),
        pytest.param({"fy": -500.0}, "fy", id="fy-negative"),
        pytest.param({"fx": math.inf}, "fx", id="fx-inf"),
        pytest.param({"cx": math.nan}, "cx", id="cx-nan"),
        pytest.param({"cy": "240"}, "cy", id="cy-string"),
        pytest.param({"fx": True}, "fx", id="fx-bool"),
        pytest.param({"width": 0}, "width", id="width-zero"),
        pytest.param({"width": -640}, "width", id="width-negative"),
        pytest.param({"width": 640.0}, "width", id="width-float"),
        pytest.param({"height": True}, "height", id="height-bool"),
        pytest.param({"distortion": (-0.2, 0.05, 1e-3)}, "distortion", id="distortion-3"),
        pytest.param({"distortion": (0.1,) * 6}, "distortion", id="distortion-6"),
        pytest.param({"distortion": (-0.2, math.nan, 0.0, 0.0)}, "distortion", id="dist-nan"),
        pytest.param({"distortion": (-0.2, 0.0, math.inf, 0.0)}, "distortion", id="dist-inf"),
        pytest.param({"tip_T_cam": np.eye(3)}, "tip_T_cam", id="pose-3x3"),
        pytest.param({"tip_T_cam": np.eye(4)[:3]}, "tip_T_cam", id="pose-3x4"),
        pytest.param({"tip_T_cam": _scaled_rotation()}, "tip_T_cam", id="pose-scaled"),
        pytest.param({"tip_T_cam": np.diag([1.0, 1.0, -1.0, 1.0])}, "tip_T_cam", id="reflection"),
        pytest.param({"tip_T_cam": _bad_bottom_row()}, "tip_T_cam", id="bottom-row"),
        pytest.param({"tip_T_cam": _nan_translation()}, "tip_T_cam", id="pose-nan"),
    ],
)
def test_invalid_fields_raise_value_error_naming_them(changes: dict, field: str) -> None:
    with pytest.raises(ValueError, match=rf"^TipCamera\.{field}"):
        _camera(**changes)


def test_valid_fields_are_normalised_to_plain_types() -> None:
    cam = _camera(
        fx=500, cy=np.float32(240.0), width=np.int64(640), distortion=[np.float64(-0.2), 0, 0, 0]
    )
    assert type(cam.fx) is float and type(cam.cy) is float
    assert type(cam.width) is int and cam.width == 640
    assert cam.distortion == (-0.2, 0.0, 0.0, 0.0)
    assert all(type(d) is float for d in cam.distortion)
    np.testing.assert_array_equal(cam.tip_T_cam, np.eye(4))


@pytest.mark.parametrize("size", OPENCV_DISTORTION_SIZES)
def test_every_opencv_distortion_size_is_accepted(size: int) -> None:
    cam = _camera(distortion=(0.01,) * size)
    assert cam.distortion_coefficients.shape == (size,)


def test_rotation_within_tolerance_is_accepted_and_bottom_row_cleaned() -> None:
    pose = _rigid((0.3, -0.2, 1.0), (0.1, 0.2, 0.3))
    pose[3, 3] = 1.0 + 1e-9
    cleaned = validate_pose("pose", pose)
    np.testing.assert_array_equal(cleaned[3], [0.0, 0.0, 0.0, 1.0])
    np.testing.assert_array_equal(cleaned[:3], pose[:3])


def test_bottom_row_tolerance_is_absolute() -> None:
    """1e-5 off in the bottom row is outside the 1e-6 tolerance (numpy's allclose would add a
    relative 1e-5 of the expected 1 and let it through; is_rigid never did)."""
    pose = np.eye(4)
    pose[3, 3] = 1.0 + 1e-5
    with pytest.raises(ValueError, match="bottom row"):
        validate_pose("pose", pose)
    assert not is_rigid(pose)


@settings(max_examples=200, deadline=None)
@given(st.tuples(*[st.floats(-math.pi, math.pi)] * 3), st.tuples(*[st.floats(-5.0, 5.0)] * 3),
       st.integers(0, 15), st.sampled_from([0.0, 1e-9, 1e-7, 1e-5, 0.1, 1.0, math.nan]))
def test_is_rigid_answers_as_validate_pose(angles, translation, entry: int,
                                           change: float) -> None:
    """The fast check agrees with the full one on rigid transforms and on each of them with
    one entry changed (well inside or well outside the 1e-6 tolerance)."""
    pose = _rigid(angles, translation)
    assert is_rigid(pose)
    pose[divmod(entry, 4)] += change
    try:
        validate_pose("pose", pose)
        valid = True
    except ValueError:
        valid = False
    if not 1e-7 < change < 1e-5:  # the two measure the tolerance a little differently
        assert is_rigid(pose) == valid
    assert not is_rigid(np.eye(3)) and not is_rigid(np.zeros((4, 4)))


# ---------------------------------------------------------------------------------- projection
def test_intrinsic_matrix() -> None:
    cam = _camera(fx=400.0, fy=410.0, cx=300.5, cy=200.25)
    np.testing.assert_array_equal(
        cam.intrinsic_matrix, [[400.0, 0.0, 300.5], [0.0, 410.0, 200.25], [0.0, 0.0, 1.0]]
    )
    assert cam.distortion_coefficients.shape == (0,)


def test_project_of_known_points() -> None:
    cam = _camera()
    pixels = cam.project([[0.1, -0.2, 2.0], [0.0, 0.0, 5.0]])
    np.testing.assert_allclose(pixels, [[345.0, 189.0], [320.0, 240.0]], rtol=0, atol=1e-12)
    # A single point is accepted as a flat triple.
    np.testing.assert_allclose(cam.project([0.1, -0.2, 2.0]), [[345.0, 189.0]], atol=1e-12)


def test_project_with_distortion_matches_the_opencv_model() -> None:
    k1, k2, p1, p2 = DISTORTION
    cam = _camera(distortion=DISTORTION)
    x, y = 0.3, -0.2
    r2 = x * x + y * y
    radial = 1 + k1 * r2 + k2 * r2 * r2
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    expected = [cam.fx * xd + cam.cx, cam.fy * yd + cam.cy]
    np.testing.assert_allclose(cam.project([[2 * x, 2 * y, 2.0]]), [expected], atol=1e-9)


@settings(max_examples=50, deadline=None)
@given(
    fx=st.floats(50.0, 5000.0),
    fy=st.floats(50.0, 5000.0),
    cx=st.floats(-50.0, 1000.0),
    cy=st.floats(-50.0, 1000.0),
    seed=st.integers(0, 2**32 - 1),
)
def test_bearings_invert_project_without_distortion(
    fx: float, fy: float, cx: float, cy: float, seed: int
) -> None:
    cam = TipCamera(fx, fy, cx, cy, 1280, 960)
    points = _points_seen(cam, 50, seed)
    bearings = cam.bearings(cam.project(points))
    np.testing.assert_allclose(np.linalg.norm(bearings, axis=1), 1.0, atol=1e-12)
    assert np.all(bearings[:, 2] > 0.0)
    np.testing.assert_allclose(bearings, _unit(points), rtol=0, atol=1e-9)


@pytest.mark.parametrize("distortion", [DISTORTION, DISTORTION + (0.01,)], ids=["4", "5"])
def test_bearings_invert_project_with_distortion_near_the_centre(distortion: tuple) -> None:
    cam = _camera(distortion=distortion)
    points = _points_seen(cam, 2000, seed=7, margin=150.0)
    pixels = cam.project(points)
    assert np.all(cam.in_image(pixels))
    bearings = cam.bearings(pixels)
    np.testing.assert_allclose(np.linalg.norm(bearings, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(bearings, _unit(points), rtol=0, atol=1e-6)


def test_bearings_invert_project_with_distortion_over_the_whole_image() -> None:
    cam = _camera(distortion=DISTORTION)
    rng = np.random.default_rng(11)
    n = 4000
    points = np.column_stack([rng.uniform(-0.7, 0.7, n), rng.uniform(-0.55, 0.55, n), np.ones(n)])
    pixels = cam.project(points)
    inside = cam.in_image(pixels)
    assert inside.sum() > n // 2
    bearings = cam.bearings(pixels[inside])
    np.testing.assert_allclose(bearings, _unit(points[inside]), rtol=0, atol=1e-6)


def test_project_and_bearings_ignore_the_mounting() -> None:
    """Both work in the camera frame: tip_T_cam must not enter them."""
    mounted = _camera(distortion=DISTORTION, tip_T_cam=_rigid((0.4, 0.2, -1.0), (0.1, 0, 0.2)))
    plain = _camera(distortion=DISTORTION)
    points = _points_seen(plain, 20, seed=3, margin=100.0)
    np.testing.assert_array_equal(mounted.project(points), plain.project(points))
    pixels = plain.project(points)
    np.testing.assert_array_equal(mounted.bearings(pixels), plain.bearings(pixels))


# ---------------------------------------------------------------------------------- image mask
def test_in_image_at_the_borders() -> None:
    cam = _camera()
    eps = 1e-9
    pixels = [
        [0.0, 0.0],
        [640.0 - eps, 480.0 - eps],
        [640.0, 0.0],
        [0.0, 480.0],
        [-eps, 10.0],
        [10.0, -eps],
        [320.0, 240.0],
        [639.5, 479.5],
    ]
    np.testing.assert_array_equal(
        cam.in_image(pixels), [True, True, False, False, False, False, True, True]
    )


def test_empty_input_gives_empty_outputs() -> None:
    for cam in (_camera(), _camera(distortion=DISTORTION)):
        assert cam.project(np.zeros((0, 3))).shape == (0, 2)
        assert cam.bearings(np.zeros((0, 2))).shape == (0, 3)
        assert cam.in_image(np.zeros((0, 2))).shape == (0,)


# ------------------------------------------------------------------------- equality and hashing
def test_equal_cameras_are_equal_and_hash_alike() -> None:
    pose = _rigid((0.1, 0.2, 0.3), (0.01, 0.02, 0.03))
    a = _camera(distortion=DISTORTION, tip_T_cam=pose)
    b = TipCamera(500, 510, 320, 240, 640, 480, list(DISTORTION), pose.tolist())
    assert a == b
    assert hash(a) == hash(b)
    assert len({a, b}) == 1


@pytest.mark.parametrize(
    "changes",
    [
        {"fx": 501.0},
        {"cy": 241.0},
        {"height": 481},
        {"distortion": DISTORTION[:3] + (0.0,)},
        {"distortion": DISTORTION + (0.0,)},
        {"tip_T_cam": _rigid((0.0, 0.0, 0.0), (0.0, 0.0, 1e-9))},
    ],
    ids=["fx", "cy", "height", "distortion-value", "distortion-length", "tip_T_cam"],
)
def test_cameras_differing_in_one_field_are_not_equal(changes: dict) -> None:
    base = _camera(distortion=DISTORTION)
    other = dataclasses.replace(base, **changes)
    assert base != other
    assert base == dataclasses.replace(base)


def test_camera_is_not_equal_to_other_types() -> None:
    cam = _camera()
    assert cam != "camera"
    assert cam.__eq__(42) is NotImplemented


def test_tip_T_cam_is_read_only_and_a_copy() -> None:
    pose = _rigid((0.1, 0.2, 0.3), (0.0, 0.0, 0.05))
    cam = _camera(tip_T_cam=pose)
    with pytest.raises(ValueError, match="read-only"):
        cam.tip_T_cam[0, 3] = 1.0
    pose[0, 3] = 5.0  # the caller's array is not shared
    assert cam.tip_T_cam[0, 3] == 0.0
    with pytest.raises(dataclasses.FrozenInstanceError):
        cam.fx = 1.0  # type: ignore[misc]
