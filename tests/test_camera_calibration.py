"""Camera calibration files of other tools (OpenCV, Kalibr) read into a tip camera, OpenCV's
fisheye model in :class:`TipCamera`, and ``apcc-graph robot import-camera``."""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from apcc_graph.cli import main
from apcc_graph.io.camera_calibration import read_camera_file
from apcc_graph.io.robot_file import load_markers, load_robot, save_robot
from apcc_graph.model.camera import TipCamera
from apcc_graph.model.robot import Robot

ROOT = Path(__file__).resolve().parents[1]
ROBOT = ROOT / "data" / "robots" / "planar_three.toml"
FISHEYE = (-0.01, 0.02, -0.003, 0.001)

KALIBR = """\
cam0:
  T_cam_imu:
  - [0.0148655429818, -0.999880929698, 0.00414029679422, -0.0216401454975]
  - [0.999557249008, 0.0149672133247, 0.025715529948, -0.064676986768]
  - [-0.0257744366974, 0.00375618835797, 0.999660727178, 0.00981073058949]
  - [0.0, 0.0, 0.0, 1.0]
  cam_overlaps: [1]
  camera_model: pinhole
  distortion_coeffs: [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05]
  distortion_model: radtan
  intrinsics: [458.654, 457.296, 367.215, 248.375]
  resolution: [752, 480]
  rostopic: /cam0/image_raw
cam1:
  camera_model: pinhole
  distortion_coeffs: [-0.01, 0.02, -0.003, 0.001]
  distortion_model: equidistant
  intrinsics: [457.587, 456.134, 379.999, 255.238]
  resolution: [752, 480]
  rostopic: /cam1/image_raw
cam2:
  camera_model: pinhole
  distortion_model: none
  intrinsics: [400.0, 401.0, 320.0, 240.0]
  resolution: [640, 480]
"""


def _equidistant(xy: np.ndarray, k: tuple[float, ...]) -> np.ndarray:
    """OpenCV's fisheye distortion of normalised points, written out."""
    r = np.linalg.norm(xy, axis=1)
    th = np.arctan(r)
    thd = th * (1 + k[0] * th**2 + k[1] * th**4 + k[2] * th**6 + k[3] * th**8)
    return xy * (thd / np.where(r > 0, r, 1.0))[:, None]


# ------------------------------------------------------------------------ the fisheye model
@settings(max_examples=30, deadline=None)
@given(st.lists(st.floats(-0.05, 0.05), min_size=4, max_size=4),
       st.integers(0, 2**31 - 1))
def test_the_fisheye_model_is_opencvs_equidistant_and_inverts(k: list[float], seed: int) -> None:
    cam = TipCamera(300.0, 310.0, 320.0, 240.0, 640, 480, tuple(k), model="fisheye")
    xy = np.random.default_rng(seed).uniform(-1.0, 1.0, (40, 2))
    uv = cam.project(np.column_stack([xy, np.ones(len(xy))]))
    expected = _equidistant(xy, tuple(k)) * [300.0, 310.0] + [320.0, 240.0]
    np.testing.assert_allclose(uv, expected, atol=1e-9)
    np.testing.assert_allclose(cam.normalized(uv), xy, atol=1e-9)
    # the pixel Jacobian: derivatives of the written-out model
    h, J = 1e-6, cam.pixel_jacobian(xy[:5])
    for axis in range(2):
        step = np.zeros(2)
        step[axis] = h
        num = (_equidistant(xy[:5] + step, tuple(k)) - _equidistant(xy[:5] - step, tuple(k))) / (
            2 * h) * [300.0, 310.0]
        np.testing.assert_allclose(J[:, :, axis], num, rtol=1e-5, atol=1e-3)


def test_the_camera_model_is_checked_and_compared() -> None:
    with pytest.raises(ValueError, match="fisheye model takes 4"):
        TipCamera(300.0, 300.0, 320.0, 240.0, 640, 480, (0.1, 0.0, 0.0, 0.0, 0.0),
                  model="fisheye")
    with pytest.raises(ValueError, match="TipCamera.model = 'omni'"):
        TipCamera(300.0, 300.0, 320.0, 240.0, 640, 480, model="omni")
    a = TipCamera(300.0, 300.0, 320.0, 240.0, 640, 480, FISHEYE, model="fisheye")
    b = TipCamera(300.0, 300.0, 320.0, 240.0, 640, 480, FISHEYE)
    assert a != b and len({a, b}) == 2
    assert np.abs(a.project([[0.5, 0.5, 1.0]]) - b.project([[0.5, 0.5, 1.0]])).max() > 1.0


def test_robot_toml_keeps_the_model(tmp_path: Path) -> None:
    robot = load_robot(ROBOT)
    fish = TipCamera(300.0, 300.0, 320.0, 240.0, 640, 480, FISHEYE, robot.cameras[1].tip_T_cam,
                     "fisheye")
    path = tmp_path / "robot.toml"
    save_robot(Robot(robot.segments, [robot.cameras[0], fish, robot.cameras[2]]), path)
    again = load_robot(path)
    assert again.cameras[1] == fish and again.cameras[0].model == "pinhole"
    assert path.read_text().count("model =") == 1  # pinhole cameras are written as before
    path.write_text(path.read_text().replace('model = "fisheye"', 'model = "fish"'))
    with pytest.raises(ValueError, match=r"robot\.toml.*model.*'fish'"):
        load_robot(path)


# ------------------------------------------------------------------------------ the files
@pytest.mark.parametrize("suffix", [".yaml", ".xml", ".json"])
def test_an_opencv_calibration_of_each_storage_kind(tmp_path: Path, suffix: str) -> None:
    path = tmp_path / f"ost{suffix}"
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    fs.write("image_width", 640)
    fs.write("image_height", 480)
    fs.write("camera_matrix", np.array([[500.0, 0, 321.5], [0, 510.0, 239.5], [0, 0, 1]]))
    fs.write("distortion_coefficients", np.array([[0.1, -0.2, 0.001, 0.002, 0.05]]))
    fs.release()
    found = read_camera_file(path)
    assert (found.fx, found.fy, found.cx, found.cy) == (500.0, 510.0, 321.5, 239.5)
    assert (found.width, found.height, found.model) == (640, 480, "pinhole")
    np.testing.assert_allclose(found.distortion, [0.1, -0.2, 0.001, 0.002, 0.05])


def test_an_old_opencv_file_and_other_spellings(tmp_path: Path) -> None:
    old = tmp_path / "old.yml"
    old.write_text("%YAML:1.0\nimageSize: [ 752, 480 ]\nK: !!opencv-matrix\n   rows: 3\n"
                   "   cols: 3\n   dt: d\n   data: [ 458., 0., 367., 0., 457., 248., 0., 0., 1. ]"
                   "\nD: !!opencv-matrix\n   rows: 4\n   cols: 1\n   dt: d\n"
                   "   data: [ -0.01, 0.02, -0.003, 0.001 ]\ndistortion_model: equidistant\n")
    found = read_camera_file(old)
    assert (found.width, found.height, found.model) == (752, 480, "fisheye")
    assert found.distortion == FISHEYE and found.camera().model == "fisheye"
    with pytest.raises(ValueError, match="leave out --camera"):
        read_camera_file(old, "cam0")


def test_a_kalibr_camchain(tmp_path: Path) -> None:
    path = tmp_path / "camchain.yaml"
    path.write_text(KALIBR)
    radtan = read_camera_file(path, "cam0")
    assert (radtan.fx, radtan.fy, radtan.cx, radtan.cy) == (458.654, 457.296, 367.215, 248.375)
    assert (radtan.width, radtan.height, radtan.model) == (752, 480, "pinhole")
    assert radtan.distortion == (-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05)
    fish = read_camera_file(path, "cam1")
    assert fish.model == "fisheye" and fish.distortion == FISHEYE
    plain = read_camera_file(path, "cam2")
    assert plain.distortion == () and plain.source.endswith("cam2")
    with pytest.raises(ValueError, match="holds cameras cam0, cam1, cam2: say which"):
        read_camera_file(path)
    with pytest.raises(ValueError, match="no camera 'cam7'"):
        read_camera_file(path, "cam7")


@pytest.mark.parametrize(("change", "message"), [
    (("distortion_model: equidistant", "distortion_model: fov"),
     r"cam1\.distortion_model = 'fov': expected radtan"),
    (("cam1:\n  camera_model: pinhole", "cam1:\n  camera_model: omni"),
     r"cam1\.camera_model = 'omni'"),
    (("intrinsics: [457.587, 456.134, 379.999, 255.238]", "intrinsics: [457.587, 456.134]"),
     r"cam1\.intrinsics = \[457\.587, 456\.134\]: expected 4 numbers"),
    (("intrinsics: [457.587, 456.134, 379.999, 255.238]", "intrinsics: [-4.0, 456.134, 1, 2]"),
     r"cam1: TipCamera\.fx = -4\.0"),
])
def test_a_camera_it_cannot_map_is_refused_by_name(tmp_path: Path, change: tuple[str, str],
                                                  message: str) -> None:
    path = tmp_path / "camchain.yaml"
    assert change[0] in KALIBR
    path.write_text(KALIBR.replace(*change))
    with pytest.raises(ValueError, match=message):
        read_camera_file(path, "cam1")
    assert str(path) in _message(path)


def _message(path: Path) -> str:
    try:
        read_camera_file(path, "cam1")
    except ValueError as exc:
        return str(exc)
    return ""


def test_files_that_are_not_calibrations(tmp_path: Path) -> None:
    cases = {"none.yaml": ("width: 3\n", "no camera matrix"),
             "list.yaml": ("- 1\n- 2\n", "expected a YAML mapping"),
             "bad.yaml": ("a: [1, 2\n", "not a YAML file"),
             "size.yaml": ("K: [[500, 0, 320], [0, 500, 240], [0, 0, 1]]\n", "no image size"),
             "k.yaml": ("K: [[500, 0], [0, 500]]\nimage_size: [640, 480]\n", "3x3")}
    for name, (text, message) in cases.items():
        (tmp_path / name).write_text(text)
        with pytest.raises(ValueError, match=message):
            read_camera_file(tmp_path / name)
    with pytest.raises(ValueError, match="cannot read it"):
        read_camera_file(tmp_path / "missing.yaml")


# ------------------------------------------------------------------------------ the command
def test_import_camera_replaces_one_camera_and_keeps_the_rest(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    chain = tmp_path / "camchain.yaml"
    chain.write_text(KALIBR)
    robot = load_robot(ROBOT)
    mount = np.eye(4)
    mount[:3, 3] = [0.01, 0.0, 0.02]
    start = tmp_path / "robot.toml"
    cams = list(robot.cameras)
    cams[1] = TipCamera(500.0, 500.0, 320.0, 240.0, 640, 480, tip_T_cam=mount)
    save_robot(Robot(robot.segments, cams), start, {0.3: np.eye(4)})
    out = tmp_path / "new.toml"
    assert main(["robot", "import-camera", str(chain), "--camera", "cam1", "--robot",
                 str(start), "--segment", "2", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "fisheye model" in text and "mount (tip_T_cam): kept" in text
    new = load_robot(out)
    assert new.cameras[1].model == "fisheye" and new.cameras[1].distortion == FISHEYE
    np.testing.assert_array_equal(new.cameras[1].tip_T_cam, mount)
    assert new.cameras[0] == robot.cameras[0] and new.cameras[2] == robot.cameras[2]
    assert new.segments == robot.segments and list(load_markers(out)) == [0.3]
    # nothing overwritten without --force, and a bad file leaves no output
    assert main(["robot", "import-camera", str(chain), "--camera", "cam0", "--robot",
                 str(start), "--segment", "2", "--out", str(out)]) == 1
    assert "exists" in capsys.readouterr().err and load_robot(out) == new
    bad = tmp_path / "bad.yaml"
    bad.write_text(KALIBR.replace("radtan", "fov"))
    assert main(["robot", "import-camera", str(bad), "--camera", "cam0", "--robot",
                 str(start), "--segment", "1", "--out", str(tmp_path / "x.toml")]) == 1
    assert "fov" in capsys.readouterr().err and not (tmp_path / "x.toml").exists()


def test_a_fisheye_robot_is_estimated_like_a_pinhole_one() -> None:
    """The simulator and the estimators see the camera only through its model: a robot whose
    cameras are fisheye is estimated as well as the same robot's pinhole one."""
    from apcc_graph.estimation.methods import estimate
    from apcc_graph.simulation.simulator import simulate

    robot = load_robot(ROBOT)
    fish = Robot(robot.segments, [
        TipCamera(c.fx, c.fy, c.cx, c.cy, c.width, c.height, (0.05, -0.02, 0.01, -0.002),
                  c.tip_T_cam, "fisheye") for c in robot.cameras if c is not None])
    errors = []
    for r in (robot, fish):
        seq = simulate(r, 40, noise_px=0.5, outlier_fraction=0.0, seed=3, scene="room").sequence
        est = estimate(seq, method="batch", theta0=seq.thetas[0], noise_px=0.5, progress=False)
        errors.append(np.degrees(est.rms(seq.thetas)))
    assert np.all(errors[1] < 2.0 * errors[0] + 0.05), errors
    assert math.isfinite(float(np.max(errors[1])))


def test_a_fisheye_image_is_undistorted_by_its_model() -> None:
    """Marker detection undistorts a fisheye side camera's image with ``cv2.fisheye``: a smooth
    pinhole image distorted by the fisheye model comes back (inside the border)."""
    from apcc_graph.calibration.marker_detection import undistorted_image
    from apcc_graph.simulation.marker_drawing import distort_image

    cam = TipCamera(300.0, 300.0, 160.0, 120.0, 320, 240, (0.08, -0.03, 0.01, -0.002),
                    model="fisheye")
    v, u = np.mgrid[0:240, 0:320].astype(np.float32)
    pinhole = 128 + 60 * np.sin(u / 17.0) * np.cos(v / 13.0)
    distorted = np.clip(np.round(distort_image(pinhole.astype(np.float32), cam)), 0, 255)
    back, plain = undistorted_image(distorted.astype(np.uint8), cam)
    assert plain.model == "pinhole" and plain.distortion == ()
    inner = (slice(30, 210), slice(40, 280))
    assert np.abs(back[inner].astype(float) - pinhole[inner]).mean() < 2.0
    # with the pinhole model's maps instead, it would not come back
    wrong = TipCamera(300.0, 300.0, 160.0, 120.0, 320, 240, (0.08, -0.03, 0.01, -0.002))
    off, _ = undistorted_image(distorted.astype(np.uint8), wrong)
    assert np.abs(off[inner].astype(float) - pinhole[inner]).mean() > 4.0
