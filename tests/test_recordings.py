"""Recordings besides image folders: ROS 1 and ROS 2 bags (written here with ``rosbags`` from
a rendered sequence) and video files, matched to common frames by time and tracked into the
same tracks as the image folder of the same images."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from apcc_graph.cli import main
from apcc_graph.frontend.recordings import match_frames
from apcc_graph.io.robot_file import load_robot
from apcc_graph.io.sequence_folder import load_sequence, save_sequence
from apcc_graph.model.sequence import Sequence

rosbags = pytest.importorskip("rosbags")

ROBOT = Path(__file__).resolve().parents[1] / "data/robots/planar_three.toml"
FRAMES = 8
TOPICS = ["/tip1/image", "/tip2/image", "/tip3/image"]


def _images() -> list[list[np.ndarray]]:
    """Per camera, FRAMES rendered 640x480 grey images: the simulator's robot moving through
    its textured room (procedural textures, so the test needs no image package)."""
    from apcc_graph.simulation.render import render_images, textured_room
    from apcc_graph.simulation.simulator import simulate

    robot = load_robot(ROBOT)
    sim = simulate(robot, FRAMES, noise_px=0.0, outlier_fraction=0.0, seed=2, scene="room")
    room = textured_room(sim.scene_centre, sim.room_half_size, texture_source="procedural")
    return [list(render_images(room, robot.cameras[cam], sim.world_T_cam[cam], seed=cam))
            for cam in robot.camera_segments]


@pytest.fixture(scope="module")
def images() -> list[list[np.ndarray]]:
    return _images()


@pytest.fixture(scope="module")
def folder_tracks(images: list[list[np.ndarray]], tmp_path_factory: pytest.TempPathFactory
                  ) -> Sequence:
    """The image folder of the same images, tracked."""
    from apcc_graph.frontend.tracking import track_sequence

    tmp = tmp_path_factory.mktemp("folder")
    files = {}
    for cam, frames in enumerate(images):
        (tmp / f"src{cam}").mkdir()
        files[cam] = {}
        for f, image in enumerate(frames):
            path = tmp / f"src{cam}" / f"{f:06d}.png"
            cv2.imwrite(str(path), image)
            files[cam][f] = path
    save_sequence(Sequence(load_robot(ROBOT), np.arange(FRAMES) / 30.0, images=files),
                  tmp / "seq")
    track_sequence(tmp / "seq")
    return load_sequence(tmp / "seq")


def _message(ts: object, kind: str, image: np.ndarray, t: float, ros1: bool) -> object:
    types = ts.types  # type: ignore[attr-defined]
    sec, nanosec = int(t), int(round((t - int(t)) * 1e9))
    stamp = types["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec)
    header = (types["std_msgs/msg/Header"](seq=0, stamp=stamp, frame_id="tip") if ros1
              else types["std_msgs/msg/Header"](stamp=stamp, frame_id="tip"))
    if kind == "compressed":
        ok, png = cv2.imencode(".png", image)
        assert ok
        return types["sensor_msgs/msg/CompressedImage"](header=header, format="png",
                                                         data=png.ravel())
    if kind == "bgr8":
        image = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
    h, w = image.shape[:2]
    return types["sensor_msgs/msg/Image"](
        header=header, height=h, width=w, encoding=kind, is_bigendian=0,
        step=w * (3 if kind == "bgr8" else 1), data=image.ravel())


def write_bag(path: Path, images: list[list[np.ndarray]], kind: str, version: str,
              times: list[np.ndarray] | None = None) -> Path:
    """A bag of one image topic per camera (``kind``: mono8, bgr8 or compressed; ``version``:
    ros1, sqlite3 or mcap)."""
    from rosbags.rosbag1 import Writer as Writer1
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    ros1 = version == "ros1"
    ts = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    msgtype = ("sensor_msgs/msg/CompressedImage" if kind == "compressed"
               else "sensor_msgs/msg/Image")
    times = times or [100.0 + np.arange(FRAMES) / 30.0 for _ in images]
    if ros1:
        writer = Writer1(path)
    else:
        writer = Writer(path, version=8, storage_plugin=StoragePlugin.MCAP if version == "mcap"
                        else StoragePlugin.SQLITE3)
    with writer:
        conns = [writer.add_connection(topic, msgtype, typestore=ts) for topic in TOPICS]
        events = sorted((t, cam, f) for cam, stamps in enumerate(times)
                        for f, t in enumerate(stamps))
        for t, cam, f in events:
            msg = _message(ts, kind, images[cam][f], t, ros1)
            data = ts.serialize_ros1(msg, msgtype) if ros1 else ts.serialize_cdr(msg, msgtype)
            writer.write(conns[cam], int(t * 1e9), data)
    return path


@pytest.mark.parametrize(("kind", "version"), [("mono8", "sqlite3"), ("bgr8", "mcap"),
                                               ("compressed", "ros1"), ("mono8", "ros1")])
def test_a_bag_gives_the_tracks_of_the_image_folder(
        images: list[list[np.ndarray]], folder_tracks: Sequence, tmp_path: Path, kind: str,
        version: str, capsys: pytest.CaptureFixture[str]) -> None:
    bag = write_bag(tmp_path / ("run.bag" if version == "ros1" else "run"), images, kind, version)
    out = tmp_path / "seq"
    assert main(["track", str(bag), "--robot", str(ROBOT), "--out", str(out),
                 "--topics", ",".join(TOPICS)]) == 0
    assert f"{FRAMES} frames" in capsys.readouterr().out
    seq = load_sequence(out)
    np.testing.assert_allclose(seq.timestamps, np.arange(FRAMES) / 30.0, atol=1e-6)
    for cam in range(3):
        got, want = seq.tracks[cam], folder_tracks.tracks[cam]
        assert len(want) > 100
        np.testing.assert_array_equal(got.frames, want.frames)
        np.testing.assert_array_equal(got.track_ids, want.track_ids)
        np.testing.assert_allclose(got.uv, want.uv, atol=1e-4)  # the CSV's rounding


def test_unsynchronised_cameras_are_matched_and_what_was_dropped_is_counted(
        images: list[list[np.ndarray]], tmp_path: Path,
        capsys: pytest.CaptureFixture[str]) -> None:
    """Camera 2 runs 4 ms late, camera 3 lost its image of frame 5: frame 5 is dropped, and
    the topics' order comes from the bag when there is one image topic per camera."""
    base = 100.0 + np.arange(FRAMES) / 30.0
    times = [base, base + 0.004, np.delete(base, 5) - 0.003]
    imgs = [images[0], images[1], [im for f, im in enumerate(images[2]) if f != 5]]
    bag = write_bag(tmp_path / "run", imgs, "mono8", "sqlite3", times)
    out = tmp_path / "seq"
    assert main(["track", str(bag), "--robot", str(ROBOT), "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert f"{FRAMES - 1} frames (1 of the first camera's images had no match" in text
    assert f"{bag}:/tip2/image: {FRAMES} images, 1 dropped" in text
    assert f"{bag}:/tip3/image: {FRAMES - 1} images, 0 dropped" in text
    seq = load_sequence(out)
    assert seq.n_frames == FRAMES - 1 and seq.timestamps[5] == pytest.approx(6 / 30.0)


def test_the_topics_can_be_named_in_robot_toml(
        images: list[list[np.ndarray]], folder_tracks: Sequence, tmp_path: Path,
        capsys: pytest.CaptureFixture[str]) -> None:
    """Each camera's ``topic`` in robot.toml replaces --topics (here in reverse name order, so
    the bag's sorted topics would be wrong); a camera without one is named."""
    bag = write_bag(tmp_path / "run", images[::-1], "mono8", "sqlite3")  # /tip1 holds camera 3
    text = ROBOT.read_text()
    parts = text.split("[segments.camera]")
    assert len(parts) == 4
    named = parts[0] + "".join(f'[segments.camera]\ntopic = "{TOPICS[2 - i]}"' + p
                               for i, p in enumerate(parts[1:]))
    robot_file = tmp_path / "robot.toml"
    robot_file.write_text(named)
    assert main(["track", str(bag), "--robot", str(robot_file), "--out", str(tmp_path / "s")]) == 0
    seq = load_sequence(tmp_path / "s")
    for cam in range(3):
        np.testing.assert_allclose(seq.tracks[cam].uv, folder_tracks.tracks[cam].uv, atol=1e-4)
    robot_file.write_text(named.replace(f'topic = "{TOPICS[0]}"', "", 1))
    assert main(["track", str(bag), "--robot", str(robot_file), "--out",
                 str(tmp_path / "t")]) == 1
    assert "cameras of segments [3] name no topic" in capsys.readouterr().err


def test_match_frames() -> None:
    t = np.arange(10) * 0.1
    found = match_frames([t, t + 0.02, np.r_[t[:4], t[5:]] - 0.01])
    assert found.tolerance == pytest.approx(0.05) and found.unmatched == 1
    np.testing.assert_array_equal(found.indices[2], [0, 1, 2, 3, 4, 5, 6, 7, 8])
    np.testing.assert_array_equal(found.indices[0], [0, 1, 2, 3, 5, 6, 7, 8, 9])
    assert found.dropped == (1, 1, 0)
    # a camera at half the rate: its images are not used twice
    half = match_frames([t, t[::2]], tolerance=0.2)
    assert np.all(np.diff(half.indices[1]) > 0) and half.indices.shape[1] == 5
    with pytest.raises(ValueError, match="camera 2: image times go back"):
        match_frames([t, t[::-1]])
    with pytest.raises(ValueError, match="never within"):
        match_frames([t, t + 5.0])


def test_bags_that_cannot_be_read_are_refused_by_name(
        images: list[list[np.ndarray]], tmp_path: Path,
        capsys: pytest.CaptureFixture[str]) -> None:
    bag = write_bag(tmp_path / "run.bag", images, "mono8", "ros1")
    args = ["--robot", str(ROBOT), "--out", str(tmp_path / "seq")]
    assert main(["track", str(bag), *args, "--topics", "/tip1/image,/nope,/tip3/image"]) == 1
    err = capsys.readouterr().err
    assert "no image topic '/nope'" in err and "/tip2/image" in err
    truncated = tmp_path / "cut.bag"
    truncated.write_bytes(bag.read_bytes()[: bag.stat().st_size // 2])
    assert main(["track", str(truncated), *args]) == 1
    assert str(truncated) in capsys.readouterr().err
    assert main(["track", str(tmp_path / "absent.bag"), *args]) == 1
    assert "absent.bag: no such sequence folder or ROS bag" in capsys.readouterr().err
    assert not (tmp_path / "seq").exists()


def test_videos_of_different_lengths(images: list[list[np.ndarray]], tmp_path: Path,
                                     capsys: pytest.CaptureFixture[str]) -> None:
    """One video per camera; the third is shorter: the frames end with it."""
    files = []
    for cam, frames in enumerate(images):
        path = tmp_path / f"cam{cam}.avi"
        writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 30.0, (640, 480),
                                 False)
        assert writer.isOpened()
        for image in frames[: FRAMES - 2 if cam == 2 else FRAMES]:
            writer.write(image)
        writer.release()
        files.append(str(path))
    out = tmp_path / "seq"
    assert main(["track", "--video", ",".join(files), "--robot", str(ROBOT), "--out",
                 str(out)]) == 0
    text = capsys.readouterr().out
    assert f"{FRAMES - 2} frames (2 of the first camera's images had no match" in text
    seq = load_sequence(out)
    assert seq.n_frames == FRAMES - 2
    np.testing.assert_allclose(np.diff(seq.timestamps), 1 / 30.0, atol=1e-3)
    corr = seq.correspondences(0, 0, FRAMES - 3)
    assert len(corr) > 50  # tracks run through the frames of the shorter video
    assert main(["track", "--video", files[0], "--robot", str(ROBOT), "--out",
                 str(tmp_path / "x")]) == 1
    assert "--video names 1 files for 3 cameras" in capsys.readouterr().err
