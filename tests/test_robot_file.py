"""Tests of the ``robot.toml`` file: loading, saving, validation messages and atomic writes."""

from __future__ import annotations

import math
import os
from pathlib import Path

import gtsam
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from apcc_graph.io import atomic as atomic_write
from apcc_graph.io.robot_file import ROBOT_FORMAT, load_robot, robot_to_toml, save_robot
from apcc_graph.model.camera import TipCamera
from apcc_graph.model.robot import Robot
from apcc_graph.model.segment import Segment

REPO = Path(__file__).resolve().parents[1]
PAPER_SINGLE = REPO / "data" / "robots" / "paper_single.toml"
PLANAR_THREE = REPO / "data" / "robots" / "planar_three.toml"


def _pose(rotation: np.ndarray, translation: tuple[float, float, float]) -> np.ndarray:
    pose = np.eye(4)
    pose[:3, :3] = rotation
    pose[:3, 3] = translation
    return pose


def _camera(distortion: tuple[float, ...] = (), tip_T_cam: np.ndarray | None = None) -> TipCamera:
    return TipCamera(
        fx=500.0,
        fy=502.5,
        cx=319.5,
        cy=239.5,
        width=640,
        height=480,
        distortion=distortion,
        tip_T_cam=np.eye(4) if tip_T_cam is None else tip_T_cam,
    )


def _mixed_robot() -> Robot:
    """Four segments: 4 and 5 distortion coefficients, negative delta_max, one without camera.

    The cameras' mountings are exactly representable in the file (a translation, a half turn
    about x), so the round trip must give back the very same floats.
    """
    half_turn_x = _pose(np.diag([1.0, -1.0, -1.0]), (0.01, -0.02, 0.05))
    segments = [
        Segment(0.5, 0.25, 0.0, math.radians(60.0)),
        Segment(0.3, 0.2, math.radians(-7.5), math.radians(80.0)),
        Segment(0.25, 0.31, math.radians(3.0), math.radians(45.0)),
        Segment(0.2, 0.22, math.radians(-12.0), math.radians(180.0)),
    ]
    cameras = [
        _camera(),
        _camera((-0.2, 0.05, 1e-3, -1e-3), _pose(np.eye(3), (0.0, 0.0, 0.012))),
        None,
        _camera((-0.2, 0.05, 1e-3, -1e-3, 0.01), half_turn_x),
    ]
    return Robot(segments, cameras)


def _rotated_robot(angles: tuple[float, float, float]) -> Robot:
    rotation = gtsam.Rot3.RzRyRx(*angles).matrix()
    return Robot([Segment(0.5)], [_camera((-0.1, 0.01, 0.0, 0.0), _pose(rotation, (0.1, 0, 0)))])


# ------------------------------------------------------------------------------ shipped robots
def test_paper_single_loads_with_its_values() -> None:
    robot = load_robot(PAPER_SINGLE)
    assert robot.n_segments == 1
    seg = robot.segments[0]
    assert seg.length == 0.5
    assert seg.k == 0.25
    assert seg.delta_max == 0.0
    assert seg.theta_max == math.radians(60.0)
    cam = robot.cameras[0]
    assert cam is not None
    assert (cam.fx, cam.fy, cam.cx, cam.cy) == (500.0, 500.0, 320.0, 240.0)
    assert (cam.width, cam.height) == (640, 480)
    assert cam.distortion == ()
    np.testing.assert_array_equal(cam.tip_T_cam, np.eye(4))


def test_planar_three_loads_with_a_camera_on_every_segment() -> None:
    robot = load_robot(PLANAR_THREE)
    assert robot.n_segments == 3
    assert robot.camera_segments == (0, 1, 2)
    assert [seg.length for seg in robot.segments] == [0.3, 0.3, 0.3]
    assert [seg.k for seg in robot.segments] == [0.22, 0.24, 0.25]
    assert [seg.delta_max for seg in robot.segments] == pytest.approx(
        [math.radians(6.0), math.radians(3.0), 0.0], rel=1e-15, abs=0.0
    )
    for cam in robot.cameras:
        assert cam is not None
        assert (cam.width, cam.height, cam.fx) == (640, 480, 500.0)


def test_the_public_and_file_module_loaders_agree() -> None:
    from apcc_graph.io import robot_file

    assert robot_file.load_robot(PLANAR_THREE) == load_robot(PLANAR_THREE)


# ---------------------------------------------------------------------------------- round trip
def test_round_trip_gives_an_equal_robot(tmp_path: Path) -> None:
    robot = _mixed_robot()
    path = tmp_path / "robot.toml"
    save_robot(robot, path)
    loaded = load_robot(path)
    assert loaded == robot
    assert hash(loaded) == hash(robot)
    assert loaded.cameras[2] is None
    assert loaded.cameras[1].distortion == (-0.2, 0.05, 1e-3, -1e-3)
    assert len(loaded.cameras[3].distortion) == 5
    assert loaded.segments[1].delta_max < 0.0


def test_save_load_save_is_byte_identical(tmp_path: Path) -> None:
    first, second = tmp_path / "first.toml", tmp_path / "second.toml"
    save_robot(_mixed_robot(), first)
    save_robot(load_robot(first), second)
    assert first.read_bytes() == second.read_bytes()
    assert first.read_text(encoding="utf-8").startswith(f'format = "{ROBOT_FORMAT}"')


@pytest.mark.parametrize("path", [PAPER_SINGLE, PLANAR_THREE], ids=lambda p: p.name)
def test_shipped_robots_survive_a_save(tmp_path: Path, path: Path) -> None:
    robot = load_robot(path)
    first, second = tmp_path / "first.toml", tmp_path / "second.toml"
    save_robot(robot, first)
    assert load_robot(first) == robot
    save_robot(load_robot(first), second)
    assert first.read_bytes() == second.read_bytes()


def test_rotated_camera_mounting_round_trips_closely(tmp_path: Path) -> None:
    robot = _rotated_robot((0.5, -0.3, 1.2))
    path = tmp_path / "robot.toml"
    save_robot(robot, path)
    loaded = load_robot(path)
    np.testing.assert_allclose(loaded.cameras[0].tip_T_cam, robot.cameras[0].tip_T_cam, atol=1e-12)
    # The quaternion written is the rotation's, with w >= 0.
    quat = robot_to_toml(robot)["segments"][0]["camera"]["tip_T_cam"]["quaternion_wxyz"]
    q = gtsam.Rot3.RzRyRx(0.5, -0.3, 1.2).toQuaternion()
    expected = np.array([q.w(), q.x(), q.y(), q.z()]) * np.sign(q.w())
    np.testing.assert_allclose(quat, expected, atol=1e-12)
    assert quat[0] >= 0.0


def test_save_load_save_is_byte_identical_with_rotated_camera(tmp_path: Path) -> None:
    first, second = tmp_path / "first.toml", tmp_path / "second.toml"
    rng = np.random.default_rng(3)
    angles = [(0.5, 0.5, 0.5), (1.0, 0.2, -0.7)] + [tuple(rng.uniform(-3, 3, 3)) for _ in range(8)]
    for a in angles:
        save_robot(_rotated_robot(a), first)
        save_robot(load_robot(first), second)
        assert first.read_bytes() == second.read_bytes(), f"RzRyRx{a} changes on a second save"


def test_delta_max_just_below_theta_max_round_trips(tmp_path: Path) -> None:
    theta_max = 1.0
    robot = Robot([Segment(0.5, 0.25, math.nextafter(theta_max, 0.0), theta_max)])
    path = tmp_path / "robot.toml"
    save_robot(robot, path)
    loaded = load_robot(path)
    assert loaded.segments[0].delta_max < loaded.segments[0].theta_max


@st.composite
def _segments(draw: st.DrawFn) -> Segment:
    length = draw(st.floats(1e-3, 10.0))
    k = draw(st.floats(1e-6, 0.5, exclude_max=True))
    theta_max = draw(st.one_of(st.just(math.pi), st.floats(1e-3, math.pi)))
    fraction = draw(st.floats(-0.999, 0.999))
    return Segment(length, k, fraction * theta_max, theta_max)


@st.composite
def _cameras(draw: st.DrawFn) -> TipCamera | None:
    if draw(st.booleans()):
        return None
    angles = draw(st.tuples(*[st.floats(-math.pi, math.pi)] * 3))
    translation = draw(st.tuples(*[st.floats(-1.0, 1.0)] * 3))
    n_dist = draw(st.sampled_from([0, 4, 5, 8]))
    if n_dist == 0:
        return TipCamera(
            fx=draw(st.floats(1.0, 5000.0)),
            fy=draw(st.floats(1.0, 5000.0)),
            cx=draw(st.floats(-100.0, 2000.0)),
            cy=draw(st.floats(-100.0, 2000.0)),
            width=draw(st.integers(1, 8000)),
            height=draw(st.integers(1, 8000)),
            tip_T_cam=_pose(gtsam.Rot3.RzRyRx(*angles).matrix(), translation),
        )
    # a distortion must be invertible over the image: a lens of at most ~110 deg with a
    # barrel distortion up to a wide-angle one's, the principal point in the image
    width, height = draw(st.integers(1, 8000)), draw(st.integers(1, 8000))
    scale = draw(st.floats(0.0, 1.0))
    return TipCamera(
        fx=draw(st.floats(max(width, height), 10000.0)),
        fy=draw(st.floats(max(width, height), 10000.0)),
        cx=draw(st.floats(0.0, width)),
        cy=draw(st.floats(0.0, height)),
        width=width,
        height=height,
        distortion=tuple(scale * v for v in (-0.3, 0.1, 0.001, -0.001, 0.0, 0.0, 0.0, 0.0)
                         [:n_dist]),
        tip_T_cam=_pose(gtsam.Rot3.RzRyRx(*angles).matrix(), translation),
    )


@settings(
    max_examples=50,
    deadline=None,
    # the file is overwritten by every example, so sharing tmp_path between them is fine
    suppress_health_check=[HealthCheck.function_scoped_fixture],
)
@given(st.lists(st.tuples(_segments(), _cameras()), min_size=1, max_size=3))
def test_round_trip_of_random_segments(tmp_path: Path, parts: list) -> None:
    robot = Robot([seg for seg, _ in parts], [cam for _, cam in parts])
    path = tmp_path / "robot.toml"
    save_robot(robot, path)
    loaded = load_robot(path)
    assert loaded.n_segments == robot.n_segments
    assert loaded.camera_segments == robot.camera_segments
    for got, want in zip(loaded.segments, robot.segments, strict=True):
        assert got.length == want.length
        assert got.k == want.k
        assert got.theta_max == pytest.approx(want.theta_max, rel=1e-12, abs=0.0)
        assert got.delta_max == pytest.approx(want.delta_max, rel=1e-12, abs=0.0)
    for got, want in zip(loaded.cameras, robot.cameras, strict=True):
        if want is None:
            assert got is None
            continue
        assert (got.fx, got.fy, got.cx, got.cy) == (want.fx, want.fy, want.cx, want.cy)
        assert (got.width, got.height, got.distortion) == (want.width, want.height, want.distortion)
        np.testing.assert_allclose(got.tip_T_cam, want.tip_T_cam, rtol=0.0, atol=1e-12)


# ---------------------------------------------------------------------------------- validation
def _replace_nth(text: str, old: str, new: str, n: int = 0) -> str:
    """``text`` with the n-th (0-based) occurrence of ``old`` replaced by ``new``."""
    start = -1
    for _ in range(n + 1):
        start = text.index(old, start + 1)
    return text[:start] + new + text[start + len(old) :]


def _edit(source: Path, old: str, new: str, n: int = 0):
    def make(tmp_path: Path) -> Path:
        path = tmp_path / "broken.toml"
        path.write_text(_replace_nth(source.read_text(encoding="utf-8"), old, new, n))
        return path

    return make


def _text(content: str):
    def make(tmp_path: Path) -> Path:
        path = tmp_path / "broken.toml"
        path.write_text(content)
        return path

    return make


_FORMAT_LINE = f'format = "{ROBOT_FORMAT}"'
_QUAT = "quaternion_wxyz = [1.0, 0.0, 0.0, 0.0]"

# (id, how to make the broken file, the key the message must name)
_BROKEN = [
    (
        "unknown-top-key",
        _edit(PAPER_SINGLE, _FORMAT_LINE, _FORMAT_LINE + '\ncolour = "red"'),
        "colour",
    ),
    (
        "unknown-segment-key",
        _edit(PAPER_SINGLE, "theta_max_deg = 60.0", "theta_max_deg = 60.0\nstiffness = 2.0"),
        "segments[0].stiffness",
    ),
    (
        "unknown-camera-key",
        _edit(PLANAR_THREE, "fx = 500.0", "fx = 500.0\nskew = 0.0", 1),
        "segments[1].camera.skew",
    ),
    (
        "unknown-tip_T_cam-key",
        _edit(PAPER_SINGLE, _QUAT, _QUAT + ", scale = 1.0"),
        "segments[0].camera.tip_T_cam.scale",
    ),
    ("missing-length", _edit(PAPER_SINGLE, "length = 0.5\n", ""), "segments[0].length"),
    ("missing-format", _edit(PAPER_SINGLE, _FORMAT_LINE, ""), "format"),
    (
        "wrong-format",
        _edit(PAPER_SINGLE, _FORMAT_LINE, 'format = "apcc-graph/robot@9"'),
        "format",
    ),
    ("format-not-a-string", _edit(PAPER_SINGLE, _FORMAT_LINE, "format = 1"), "format"),
    ("k-too-large", _edit(PAPER_SINGLE, "\nk = 0.25", "\nk = 0.7"), "segments[0].k"),
    ("k-zero", _edit(PLANAR_THREE, "\nk = 0.25", "\nk = 0.0"), "segments[2].k"),
    ("negative-length", _edit(PAPER_SINGLE, "length = 0.5", "length = -0.5"), "segments[0].length"),
    (
        "theta_max-190",
        _edit(PAPER_SINGLE, "theta_max_deg = 60.0", "theta_max_deg = 190.0"),
        "segments[0].theta_max_deg",
    ),
    (
        "delta_max-equals-theta_max",
        _edit(PAPER_SINGLE, "delta_max_deg = 0.0", "delta_max_deg = 60.0"),
        "segments[0].delta_max_deg",
    ),
    (
        "delta_max-below-minus-theta_max",
        _edit(PLANAR_THREE, "delta_max_deg = 3.0", "delta_max_deg = -75.0"),
        "segments[1].delta_max_deg",
    ),
    ("string-for-number", _edit(PAPER_SINGLE, "\nk = 0.25", '\nk = "0.25"'), "segments[0].k"),
    (
        "bool-for-number",
        _edit(PLANAR_THREE, "fx = 500.0", "fx = true", 1),
        "segments[1].camera.fx",
    ),
    ("nan-length", _edit(PAPER_SINGLE, "length = 0.5", "length = nan"), "segments[0].length"),
    (
        "inf-cx",
        _edit(PAPER_SINGLE, "cx = 320.0", "cx = inf"),
        "segments[0].camera.cx",
    ),
    (
        "non-unit-quaternion",
        _edit(PAPER_SINGLE, _QUAT, "quaternion_wxyz = [1.0, 0.1, 0.0, 0.0]"),
        "segments[0].camera.tip_T_cam.quaternion_wxyz",
    ),
    (
        "quaternion-of-three",
        _edit(PAPER_SINGLE, _QUAT, "quaternion_wxyz = [1.0, 0.0, 0.0]"),
        "segments[0].camera.tip_T_cam.quaternion_wxyz",
    ),
    (
        "translation-of-two",
        _edit(PAPER_SINGLE, "translation = [0.0, 0.0, 0.0]", "translation = [0.0, 0.0]"),
        "segments[0].camera.tip_T_cam.translation",
    ),
    (
        "distortion-of-three",
        _edit(PAPER_SINGLE, "distortion = []", "distortion = [-0.2, 0.05, 0.001]"),
        "segments[0].camera.distortion",
    ),
    (
        "distortion-nan",
        _edit(PAPER_SINGLE, "distortion = []", "distortion = [-0.2, nan, 0.0, 0.0]"),
        "segments[0].camera.distortion[1]",
    ),
    (
        "width-fraction",
        _edit(PAPER_SINGLE, "width = 640", "width = 640.5"),
        "segments[0].camera.width",
    ),
    ("width-zero", _edit(PAPER_SINGLE, "width = 640", "width = 0"), "segments[0].camera.width"),
    (
        "height-bool",
        _edit(PAPER_SINGLE, "height = 480", "height = true"),
        "segments[0].camera.height",
    ),
    ("fx-zero", _edit(PAPER_SINGLE, "fx = 500.0", "fx = 0.0"), "segments[0].camera.fx"),
    (
        "fy-negative",
        _edit(PLANAR_THREE, "fy = 500.0", "fy = -500.0", 2),
        "segments[2].camera.fy",
    ),
    (
        "missing-camera-key",
        _edit(PAPER_SINGLE, "cy = 240.0\n", ""),
        "segments[0].camera.cy",
    ),
    ("empty-segments", _text(_FORMAT_LINE + "\nsegments = []\n"), "segments"),
    ("no-segments", _text(_FORMAT_LINE + "\n"), "segments"),
]


@pytest.mark.parametrize(("make", "key"), [pytest.param(m, k, id=i) for i, m, k in _BROKEN])
def test_validation_error_names_the_file_and_the_key(tmp_path: Path, make, key: str) -> None:
    path = make(tmp_path)
    with pytest.raises(ValueError) as info:
        load_robot(path)
    message = str(info.value)
    assert str(path) in message
    assert message.startswith(f"{path}: {key}:"), message


def test_camera_not_a_table_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "robot.toml"
    text = PAPER_SINGLE.read_text(encoding="utf-8")
    path.write_text(text.split("[segments.camera]")[0] + "camera = 5\n")
    with pytest.raises(ValueError, match=r"segments\[0\]\.camera: expected a table") as info:
        load_robot(path)
    assert str(info.value).startswith(f"{path}: ")


def test_invalid_toml_syntax_names_the_file(tmp_path: Path) -> None:
    path = tmp_path / "robot.toml"
    path.write_text(PAPER_SINGLE.read_text(encoding="utf-8").replace("\nk = 0.25", "\nk = "))
    with pytest.raises(ValueError, match="not valid TOML") as info:
        load_robot(path)
    assert str(info.value).startswith(f"{path}: ")


def test_missing_file_names_the_file(tmp_path: Path) -> None:
    path = tmp_path / "nowhere" / "robot.toml"
    with pytest.raises(ValueError, match="no such file") as info:
        load_robot(path)
    assert str(info.value).startswith(f"{path}: ")


def test_folder_instead_of_file_names_the_folder(tmp_path: Path) -> None:
    folder = tmp_path / "robot.toml"
    folder.mkdir()
    with pytest.raises(ValueError, match="is a folder") as info:
        load_robot(folder)
    assert str(info.value).startswith(f"{folder}: ")


def test_integers_are_accepted_where_numbers_are_expected(tmp_path: Path) -> None:
    path = tmp_path / "robot.toml"
    text = PAPER_SINGLE.read_text(encoding="utf-8").replace("fx = 500.0", "fx = 500")
    path.write_text(text.replace("theta_max_deg = 60.0", "theta_max_deg = 60"))
    robot = load_robot(path)
    assert robot == load_robot(PAPER_SINGLE)
    assert isinstance(robot.cameras[0].fx, float)


def test_missing_optional_camera_fields_take_their_defaults(tmp_path: Path) -> None:
    path = tmp_path / "robot.toml"
    text = PAPER_SINGLE.read_text(encoding="utf-8")
    text = text.replace("distortion = []\n", "")
    text = text.replace("tip_T_cam = { translation = [0.0, 0.0, 0.0], " + _QUAT + " }\n", "")
    path.write_text(text)
    assert load_robot(path) == load_robot(PAPER_SINGLE)


# -------------------------------------------------------------------------------- atomic save
def _failing_replace(src: str | os.PathLike, dst: str | os.PathLike) -> None:
    raise OSError(28, "No space left on device", str(dst))


def test_failed_save_keeps_the_old_file_and_leaves_no_temporary(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = tmp_path / "robot.toml"
    save_robot(load_robot(PAPER_SINGLE), path)
    old = path.read_bytes()
    monkeypatch.setattr(atomic_write.os, "replace", _failing_replace)
    with pytest.raises(OSError, match=f"(?i)no space left on device.*{path.name}"):
        save_robot(_mixed_robot(), path)
    assert path.read_bytes() == old
    assert sorted(p.name for p in tmp_path.iterdir()) == ["robot.toml"]


def test_failed_save_of_a_new_file_leaves_nothing(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(atomic_write.os, "replace", _failing_replace)
    with pytest.raises(OSError):
        save_robot(_mixed_robot(), tmp_path / "robot.toml")
    assert list(tmp_path.iterdir()) == []


def test_save_replaces_an_existing_file_and_leaves_no_temporary(tmp_path: Path) -> None:
    path = tmp_path / "robot.toml"
    save_robot(load_robot(PLANAR_THREE), path)
    save_robot(_mixed_robot(), path)
    assert load_robot(path) == _mixed_robot()
    assert [p.name for p in tmp_path.iterdir()] == ["robot.toml"]


def test_save_creates_missing_parent_folders(tmp_path: Path) -> None:
    path = tmp_path / "a" / "b" / "robot.toml"
    save_robot(_mixed_robot(), str(path))
    assert path.is_file()
    assert load_robot(path) == _mixed_robot()
