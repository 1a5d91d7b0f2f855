"""Tests of the sequence folder format (docs/formats.md): apcc_graph.io.sequence_folder.

Round trips (equality and byte-for-byte stability), the shipped sample and its seeded
regeneration, every validation error (file, line and column named), dropped pixels, atomic and
guarded saving, images, and bad paths.
"""

from __future__ import annotations

import shutil
import warnings
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
import pytest

from apcc_graph.cli import main
from apcc_graph.io import atomic as atomic_write
from apcc_graph.io.robot_file import load_robot
from apcc_graph.io.sequence_folder import SequenceWarning, load_sequence, save_sequence
from apcc_graph.model.robot import Robot
from apcc_graph.model.sequence import Sequence, Tracks
from apcc_graph.simulation.simulator import simulate_sequence

REPO = Path(__file__).resolve().parents[1]
ROBOT_FILE = REPO / "data" / "robots" / "planar_three.toml"
SAMPLE = REPO / "data" / "sequences" / "planar_three"
N_FRAMES = 20
TRACK_HEADER = "frame,track_id,u,v\n"


# ------------------------------------------------------------------------------------ helpers
@pytest.fixture(scope="module")
def robot() -> Robot:
    return load_robot(ROBOT_FILE)


def _files(folder: Path) -> dict[str, bytes]:
    """Every file under ``folder``, by path relative to it."""
    return {p.relative_to(folder).as_posix(): p.read_bytes()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def _lines(path: Path) -> list[str]:
    return path.read_text(encoding="utf-8").splitlines()


def _write_lines(path: Path, lines: list[str]) -> None:
    path.write_text("".join(line + "\n" for line in lines), encoding="utf-8")


def _set_field(path: Path, line: int, column: str, value: str) -> None:
    """Replace the field ``column`` of the 1-based file ``line`` (the header is line 1)."""
    lines = _lines(path)
    index = lines[0].split(",").index(column)
    fields = lines[line - 1].split(",")
    fields[index] = value
    lines[line - 1] = ",".join(fields)
    _write_lines(path, lines)


def _field(path: Path, line: int, column: str) -> str:
    lines = _lines(path)
    return lines[line - 1].split(",")[lines[0].split(",").index(column)]


def _assert_round_trip_stable(seq: Sequence, tmp_path: Path) -> Sequence:
    """save -> load -> save gives the same bytes in every file; returns the loaded sequence."""
    first, second = tmp_path / "first", tmp_path / "second"
    save_sequence(seq, first)
    loaded = load_sequence(first)
    save_sequence(loaded, second)
    files_first, files_second = _files(first), _files(second)
    assert files_first.keys() == files_second.keys()
    assert {"robot.toml", "frames.csv"} <= files_first.keys()
    for name, data in files_first.items():
        assert files_second[name] == data, f"{name} changed on save -> load -> save"
    assert load_sequence(second).equals(loaded)
    return loaded


@pytest.fixture(scope="module")
def template(robot: Robot, tmp_path_factory: pytest.TempPathFactory) -> tuple[Sequence, Path]:
    """A saved valid sequence: moving base (base columns), ground truth, pixels to 0.001."""
    seq = simulate_sequence(robot, N_FRAMES, seed=7, moving_base=True, decimals=3)
    folder = tmp_path_factory.mktemp("template") / "seq"
    save_sequence(seq, folder)
    return seq, folder


@pytest.fixture()
def folder(template: tuple[Sequence, Path], tmp_path: Path) -> Path:
    """A fresh copy of the template folder, to break."""
    copy = tmp_path / "seq"
    shutil.copytree(template[1], copy)
    return copy


# -------------------------------------------------------------------------------- round trips
def test_round_trip_plain_planar(robot: Robot, tmp_path: Path) -> None:
    seq = simulate_sequence(robot, N_FRAMES, seed=1)
    assert seq.world_T_base is None and seq.psis is None and seq.thetas is not None
    loaded = _assert_round_trip_stable(seq, tmp_path)
    assert loaded.equals(seq)
    header = _lines(tmp_path / "first" / "frames.csv")[0]
    assert header == "frame,timestamp,theta_1,theta_2,theta_3"
    assert sorted(_files(tmp_path / "first")) == [
        "frames.csv", "robot.toml", "tracks/cam_1.csv", "tracks/cam_2.csv", "tracks/cam_3.csv"]


def test_round_trip_moving_base_spatial(robot: Robot, tmp_path: Path) -> None:
    seq = simulate_sequence(robot, N_FRAMES, seed=2, moving_base=True, spatial=True)
    assert seq.world_T_base is not None and seq.psis is not None
    loaded = _assert_round_trip_stable(seq, tmp_path)
    header = _lines(tmp_path / "first" / "frames.csv")[0].split(",")
    assert header == (["frame", "timestamp", "base_x", "base_y", "base_z", "base_qw", "base_qx",
                       "base_qy", "base_qz"] + [f"theta_{i}" for i in (1, 2, 3)]
                      + [f"psi_{i}" for i in (1, 2, 3)])
    # Everything but the base rotations is exact; rotations go through a quaternion written to
    # 15 decimals (pose_io), so they come back within ~1e-15 and are exact from then on.
    assert loaded.robot == seq.robot
    assert np.array_equal(loaded.timestamps, seq.timestamps)
    assert np.array_equal(loaded.thetas, seq.thetas)
    assert np.array_equal(loaded.psis, seq.psis)
    assert loaded.tracks.keys() == seq.tracks.keys()
    assert all(loaded.tracks[c].equals(seq.tracks[c]) for c in seq.tracks)
    assert loaded.world_T_base is not None
    assert np.array_equal(loaded.world_T_base[:, :3, 3], seq.world_T_base[:, :3, 3])
    np.testing.assert_allclose(loaded.world_T_base, seq.world_T_base, rtol=0, atol=1e-14)
    assert not np.allclose(loaded.world_T_base[0], np.eye(4))  # the base really moves


def test_round_trip_decimals(robot: Robot, tmp_path: Path) -> None:
    seq = simulate_sequence(robot, N_FRAMES, seed=3, decimals=3)
    loaded = _assert_round_trip_stable(seq, tmp_path)
    assert loaded.equals(seq)
    rows = _lines(tmp_path / "first" / "tracks" / "cam_1.csv")[1:]
    assert rows
    for row in rows:
        for text in row.split(",")[2:]:
            assert len(text.split(".")[1]) <= 3, row  # written in the shortest exact form


def _partly_blind(robot: Robot) -> Sequence:
    """A 3-camera robot whose middle camera (cam_2) saw nothing."""
    sim = simulate_sequence(robot, N_FRAMES, seed=4)
    return Sequence(robot, sim.timestamps, {0: sim.tracks[0], 2: sim.tracks[2]},
                    thetas=sim.thetas)


def test_round_trip_camera_that_saw_nothing(robot: Robot, tmp_path: Path) -> None:
    seq = _partly_blind(robot)
    assert robot.camera_segments == (0, 1, 2)
    loaded = _assert_round_trip_stable(seq, tmp_path)
    assert (tmp_path / "first" / "tracks" / "cam_2.csv").read_text() == TRACK_HEADER
    assert len(loaded.tracks.get(1, Tracks([], [], np.zeros((0, 2))))) == 0
    for frame in range(N_FRAMES):
        ids, uv = loaded.observations(1, frame)
        assert len(ids) == 0 and uv.shape == (0, 2)
    for cam in (0, 2):
        assert loaded.tracks[cam].equals(seq.tracks[cam])
    assert np.array_equal(loaded.thetas, seq.thetas)


def test_round_trip_camera_that_saw_nothing_is_equal(robot: Robot, tmp_path: Path) -> None:
    seq = _partly_blind(robot)
    save_sequence(seq, tmp_path / "seq")
    loaded = load_sequence(tmp_path / "seq")
    assert loaded.equals(seq)
    assert loaded.cameras == seq.cameras


def test_unsorted_track_rows_load_sorted(template: tuple[Sequence, Path], folder: Path) -> None:
    seq = template[0]
    path = folder / "tracks" / "cam_1.csv"
    lines = _lines(path)
    rows = lines[1:]
    shuffled = [rows[i] for i in np.random.default_rng(0).permutation(len(rows))]
    assert shuffled != rows
    _write_lines(path, [lines[0], *shuffled])
    loaded = load_sequence(folder)
    trk = loaded.tracks[0]
    assert np.array_equal(np.lexsort((trk.track_ids, trk.frames)), np.arange(len(trk)))
    assert trk.equals(seq.tracks[0])
    assert loaded.equals(load_sequence(template[1]))


# ------------------------------------------------------------------------------ shipped sample
def test_shipped_sample_loads() -> None:
    seq = load_sequence(SAMPLE)
    assert seq.n_frames == 200
    assert seq.n_segments == 3
    assert seq.cameras == (0, 1, 2)
    assert seq.has_truth and seq.thetas is not None and seq.thetas.shape == (200, 3)
    assert seq.world_T_base is None and seq.psis is None
    np.testing.assert_allclose(seq.timestamps, np.arange(200) / 30.0, rtol=0, atol=1e-15)
    assert seq.robot == load_robot(ROBOT_FILE)
    for cam in (0, 1, 2):
        rows = len(_lines(SAMPLE / "tracks" / f"cam_{cam + 1}.csv")) - 1
        assert len(seq.tracks[cam]) == rows > 0
        uv = seq.tracks[cam].uv
        assert np.array_equal(np.round(uv, 3), uv)  # --decimals 3
    assert seq.images == {}


def test_shipped_sample_is_reproduced_by_its_command(tmp_path: Path,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "planar_three"
    code = main(["simulate", "--robot", str(ROBOT_FILE), "--frames", "200", "--out", str(out),
                 "--noise-px", "0.5", "--outliers", "0.05", "--seed", "1", "--decimals", "3"])
    assert code == 0, capsys.readouterr().err
    shipped, made = _files(SAMPLE), _files(out)
    assert made.keys() == shipped.keys()
    for name, data in shipped.items():
        assert made[name] == data, f"{name} differs from the shipped sample"


# ------------------------------------------------------------------------- validation errors
Edit = Callable[[Path], None]


def _frames(folder: Path) -> Path:
    return folder / "frames.csv"


def _cam(folder: Path, i: int = 2) -> Path:
    return folder / "tracks" / f"cam_{i}.csv"


def _drop_column(name: str) -> Edit:
    def edit(folder: Path) -> None:
        lines = _lines(_frames(folder))
        index = lines[0].split(",").index(name)
        _write_lines(_frames(folder), [",".join(f for j, f in enumerate(line.split(","))
                                                if j != index) for line in lines])
    return edit


def _add_column(name: str, value: str) -> Edit:
    def edit(folder: Path) -> None:
        lines = _lines(_frames(folder))
        _write_lines(_frames(folder), [lines[0] + "," + name] + [f"{ln},{value}"
                                                                 for ln in lines[1:]])
    return edit


def _swap_header(a: str, b: str) -> Edit:
    def edit(folder: Path) -> None:
        lines = _lines(_frames(folder))
        names = lines[0].split(",")
        i, j = names.index(a), names.index(b)
        names[i], names[j] = names[j], names[i]
        _write_lines(_frames(folder), [",".join(names), *lines[1:]])
    return edit


def _set(file: Callable[[Path], Path], line: int, column: str, value: str) -> Edit:
    def edit(folder: Path) -> None:
        _set_field(file(folder), line, column, value)
    return edit


def _lines_edit(file: Callable[[Path], Path], change: Callable[[list[str]], list[str]]) -> Edit:
    def edit(folder: Path) -> None:
        _write_lines(file(folder), change(_lines(file(folder))))
    return edit


def _swap(lines: list[str], a: int, b: int) -> list[str]:
    out = list(lines)
    out[a - 1], out[b - 1] = out[b - 1], out[a - 1]
    return out


def _copy_timestamp(source_line: int, target_line: int, delta: float = 0.0) -> Edit:
    def edit(folder: Path) -> None:
        value = float(_field(_frames(folder), source_line, "timestamp")) + delta
        _set_field(_frames(folder), target_line, "timestamp", repr(value))
    return edit


def _scale_qw(folder: Path) -> None:
    value = float(_field(_frames(folder), 4, "base_qw"))
    _set_field(_frames(folder), 4, "base_qw", repr(value * 1.01))


def _duplicate_track_row(folder: Path) -> None:
    lines = _lines(_cam(folder))
    _write_lines(_cam(folder), [*lines, lines[6]])  # line 7 again, as the last line


def _copy_file(src: str, dst: str) -> Edit:
    def edit(folder: Path) -> None:
        shutil.copy(folder / src, folder / dst)
    return edit


def _write_file(rel: str, data: bytes) -> Edit:
    def edit(folder: Path) -> None:
        (folder / rel).parent.mkdir(parents=True, exist_ok=True)
        (folder / rel).write_bytes(data)
    return edit


def _replace_in_robot(old: str, new: str) -> Edit:
    def edit(folder: Path) -> None:
        text = (folder / "robot.toml").read_text()
        assert old in text
        (folder / "robot.toml").write_text(text.replace(old, new, 1))
    return edit


# The template's frames.csv has 12 columns: frame, timestamp, 7 base pose columns, theta_1..3.
# Frame f is on line f + 2. Its tracks/cam_2.csv has rows from line 2.
BROKEN = {
    "frames-missing-timestamp": (
        _drop_column("timestamp"), "frames.csv",
        ["line 1:", "column 2 is 'base_x', expected 'timestamp'"]),
    "frames-extra-column": (
        _add_column("extra", "0"), "frames.csv",
        ["line 1:", "unexpected extra column 'extra'"]),
    "frames-wrong-order": (
        _swap_header("theta_1", "theta_2"), "frames.csv",
        ["line 1:", "column 10 is 'theta_2', expected 'theta_1'"]),
    "frames-theta_4-on-3-segments": (
        _add_column("theta_4", "0.1"), "frames.csv",
        ["line 1:", "unexpected extra column 'theta_4'"]),
    "frames-missing-theta_3": (
        _drop_column("theta_3"), "frames.csv",
        ["line 1:", "missing column 'theta_3'"]),
    "frames-not-a-number": (
        _set(_frames, 7, "timestamp", "abc"), "frames.csv",
        ["line 7, column 'timestamp'", "'abc' is not a number"]),
    "frames-nan": (
        _set(_frames, 9, "theta_2", "nan"), "frames.csv",
        ["line 9, column 'theta_2'", "finite"]),
    "frames-inf": (
        _set(_frames, 5, "base_x", "inf"), "frames.csv",
        ["line 5, column 'base_x'", "finite"]),
    "frames-minus-inf": (
        _set(_frames, 21, "theta_3", "-inf"), "frames.csv",
        ["line 21, column 'theta_3'", "finite"]),
    "frames-too-few-fields": (
        _lines_edit(_frames, lambda ls: [*ls[:5], ls[5].rsplit(",", 1)[0], *ls[6:]]),
        "frames.csv", ["line 6:", "expected 12 fields", "got 11"]),
    "frames-too-many-fields": (
        _lines_edit(_frames, lambda ls: [*ls[:7], ls[7] + ",1.0", *ls[8:]]),
        "frames.csv", ["line 8:", "expected 12 fields", "got 13"]),
    "frames-blank-line": (
        _lines_edit(_frames, lambda ls: [*ls[:11], "", *ls[11:]]),
        "frames.csv", ["line 12:", "blank line"]),
    "frames-swapped": (
        _lines_edit(_frames, lambda ls: _swap(ls, 5, 6)), "frames.csv",
        ["line 5, column 'frame'", "expected frame 3, got 4"]),
    "frames-skipped": (
        _lines_edit(_frames, lambda ls: ls[:6] + ls[7:]), "frames.csv",
        ["line 7, column 'frame'", "expected frame 5, got 6"]),
    "frames-start-at-1": (
        _lines_edit(_frames, lambda ls: ls[:1] + ls[2:]), "frames.csv",
        ["line 2, column 'frame'", "expected frame 0, got 1"]),
    "frames-fractional-frame": (
        _set(_frames, 4, "frame", "2.5"), "frames.csv",
        ["line 4, column 'frame'", "integer"]),
    "frames-duplicate-timestamp": (
        _copy_timestamp(9, 10), "frames.csv",
        ["line 10, column 'timestamp'", "strictly increasing"]),
    "frames-decreasing-timestamp": (
        _copy_timestamp(8, 10), "frames.csv",
        ["line 10, column 'timestamp'", "strictly increasing"]),
    "frames-non-unit-quaternion": (
        _scale_qw, "frames.csv",
        ["line 4, column 'base_qw'", "unit quaternion"]),
    "frames-header-only": (
        _lines_edit(_frames, lambda ls: ls[:1]), "frames.csv", ["no frames"]),
    "frames-missing": (
        lambda folder: _frames(folder).unlink(), "frames.csv", ["no such file"]),
    "tracks-wrong-header": (
        _lines_edit(_cam, lambda ls: ["frame,track,u,v", *ls[1:]]), "tracks/cam_2.csv",
        ["line 1:", "column 2 is 'track', expected 'track_id'"]),
    "tracks-not-a-number": (
        _set(_cam, 12, "u", "x1"), "tracks/cam_2.csv",
        ["line 12, column 'u'", "'x1' is not a number"]),
    "tracks-nan": (
        _set(_cam, 13, "v", "nan"), "tracks/cam_2.csv",
        ["line 13, column 'v'", "finite"]),
    "tracks-negative-id": (
        _set(_cam, 6, "track_id", "-1"), "tracks/cam_2.csv",
        ["line 6, column 'track_id'", "integer >= 0"]),
    "tracks-fractional-frame": (
        _set(_cam, 9, "frame", "1.5"), "tracks/cam_2.csv",
        ["line 9, column 'frame'", "integer"]),
    "tracks-frame-without-timestamp": (
        _set(_cam, 14, "frame", str(N_FRAMES)), "tracks/cam_2.csv",
        ["line 14, column 'frame'", f"frame {N_FRAMES} has no timestamp"]),
    "tracks-too-few-fields": (
        _lines_edit(_cam, lambda ls: [*ls[:3], ls[3].rsplit(",", 1)[0], *ls[4:]]),
        "tracks/cam_2.csv", ["line 4:", "expected 4 fields", "got 3"]),
    "tracks-camera-the-robot-lacks": (
        _copy_file("tracks/cam_1.csv", "tracks/cam_4.csv"), "tracks/cam_4.csv",
        ["no camera on segment 4"]),
    "tracks-other-file": (
        _write_file("tracks/notes.txt", b"hello\n"), "tracks/notes.txt",
        ["unexpected file", "cam_<i>.csv"]),
    "images-badly-named": (
        _write_file("images/cam_1/0.png", b"not checked"), "images/cam_1/0.png",
        ["<frame:06d>.png"]),
    "images-frame-without-timestamp": (
        _write_file(f"images/cam_1/{N_FRAMES:06d}.png", b"x"),
        f"images/cam_1/{N_FRAMES:06d}.png", [f"frame {N_FRAMES} has no timestamp"]),
    "images-camera-the-robot-lacks": (
        _write_file("images/cam_5/000000.png", b"x"), "images/cam_5",
        ["no camera on segment 5"]),
    "robot-unknown-key": (
        _replace_in_robot("length = 0.3\n", "length = 0.3\ncolour = \"red\"\n"), "robot.toml",
        ["segments[0].colour", "unknown key"]),
    "robot-invalid-value": (
        _replace_in_robot("k = 0.24\n", "k = 0.7\n"), "robot.toml",
        ["segments[1].k", "0.7"]),
    "robot-bad-format": (
        _replace_in_robot('"apcc-graph/robot@1"', '"apcc-graph/robot@9"'), "robot.toml",
        ["format"]),
}


@pytest.mark.parametrize("case", sorted(BROKEN))
def test_broken_folder_names_file_line_and_column(case: str, folder: Path) -> None:
    edit, target, fragments = BROKEN[case]
    load_sequence(folder)  # the copy is valid before the edit
    edit(folder)
    with pytest.raises(ValueError) as info:
        load_sequence(folder)
    message = str(info.value)
    assert message.startswith(str(folder / target)), message
    for fragment in fragments:
        assert fragment in message, f"{fragment!r} not in {message!r}"


def test_duplicate_track_id_names_both_lines(folder: Path) -> None:
    lines = _lines(_cam(folder))
    frame, track_id = lines[6].split(",")[:2]
    _duplicate_track_row(folder)
    last = len(lines) + 1
    with pytest.raises(ValueError) as info:
        load_sequence(folder)
    message = str(info.value)
    assert message.startswith(f"{_cam(folder)}: line {last}, column 'track_id'"), message
    assert f"track id {track_id} appears twice in frame {frame}" in message
    assert "also on line 7" in message


def test_two_files_for_one_camera_are_refused(folder: Path) -> None:
    _copy_file("tracks/cam_2.csv", "tracks/cam_01.csv")(folder)
    with pytest.raises(ValueError, match="cam_01"):
        load_sequence(folder)


# --------------------------------------------------------------------------- dropped pixels
def test_pixels_outside_image_are_dropped_with_one_warning_per_file(
        template: tuple[Sequence, Path], folder: Path) -> None:
    seq = template[0]
    cam_1, cam_3 = _cam(folder, 1), _cam(folder, 3)
    # cam_1: three rows outside (u = width is outside), one on the corner (0, 0), kept.
    for line in (5, 12, 52):
        _set_field(cam_1, line, "u", "640.0")
    _set_field(cam_1, 22, "u", "0.0")
    _set_field(cam_1, 22, "v", "0.0")
    # cam_3: two rows outside, above and below.
    _set_field(cam_3, 7, "v", "-0.001")
    _set_field(cam_3, 8, "v", "480.0")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        loaded = load_sequence(folder)
    found = [w for w in caught if issubclass(w.category, SequenceWarning)]
    assert len(found) == 2, [str(w.message) for w in caught]
    messages = sorted(str(w.message) for w in found)
    n1, n3 = len(seq.tracks[0]), len(seq.tracks[2])
    assert messages[0].startswith(str(cam_1)) and f"dropped 3 of {n1}" in messages[0]
    assert messages[1].startswith(str(cam_3)) and f"dropped 2 of {n3}" in messages[1]

    original = seq.tracks[0]
    uv = original.uv.copy()
    uv[20] = 0.0  # file line 22 is row 20
    drop = [3, 10, 50]
    expected = Tracks(np.delete(original.frames, drop), np.delete(original.track_ids, drop),
                      np.delete(uv, drop, axis=0))
    assert len(loaded.tracks[0]) == n1 - 3
    assert loaded.tracks[0].equals(expected)
    assert len(loaded.tracks[2]) == n3 - 2
    assert loaded.tracks[1].equals(seq.tracks[1])


def test_no_warning_for_a_clean_folder(template: tuple[Sequence, Path]) -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("error", SequenceWarning)
        load_sequence(template[1])


# ----------------------------------------------------------------------------------- saving
def test_save_into_new_nested_folder(robot: Robot, tmp_path: Path) -> None:
    seq = simulate_sequence(robot, N_FRAMES, seed=5)
    target = tmp_path / "a" / "b" / "c"
    save_sequence(seq, target)
    assert load_sequence(target).equals(seq)


def test_save_refuses_folder_with_stale_tracks(robot: Robot, tmp_path: Path) -> None:
    seq = simulate_sequence(robot, N_FRAMES, seed=5)
    target = tmp_path / "seq"
    (target / "tracks").mkdir(parents=True)
    (target / "tracks" / "cam_9.csv").write_text(TRACK_HEADER)
    with pytest.raises(ValueError, match="cam_9.csv") as info:
        save_sequence(seq, target)
    assert str(target / "tracks") in str(info.value)
    assert not (target / "robot.toml").exists()
    assert not (target / "frames.csv").exists()
    assert sorted(p.name for p in target.rglob("*")) == ["cam_9.csv", "tracks"]


def test_save_refuses_folder_with_stale_images(robot: Robot, tmp_path: Path) -> None:
    seq = simulate_sequence(robot, N_FRAMES, seed=5)
    target = tmp_path / "seq"
    (target / "images" / "cam_9").mkdir(parents=True)
    (target / "images" / "cam_9" / "000000.png").write_bytes(b"x")
    try:
        save_sequence(seq, target)
    except ValueError:
        assert not (target / "frames.csv").exists()
        return
    load_sequence(target)  # else the saved folder must at least be readable


def test_save_over_existing_sequence(robot: Robot, tmp_path: Path) -> None:
    target = tmp_path / "seq"
    save_sequence(simulate_sequence(robot, 30, seed=1), target)
    newer = simulate_sequence(robot, N_FRAMES, seed=2, moving_base=True)
    save_sequence(newer, target)
    loaded = load_sequence(target)
    assert loaded.n_frames == N_FRAMES
    assert loaded.world_T_base is not None
    assert all(loaded.tracks[c].equals(newer.tracks[c]) for c in newer.tracks)


def test_failed_write_leaves_file_untouched_and_no_temporary_files(
        robot: Robot, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    target = tmp_path / "seq"
    save_sequence(simulate_sequence(robot, N_FRAMES, seed=1), target)
    before = _files(target)
    real_replace = atomic_write.os.replace

    def failing_replace(src: str, dst: str | Path) -> None:
        if Path(dst).name == "frames.csv":
            raise OSError(28, "No space left on device")
        real_replace(src, dst)

    monkeypatch.setattr(atomic_write.os, "replace", failing_replace)
    other = simulate_sequence(robot, N_FRAMES + 5, seed=2)
    with pytest.raises(OSError) as info:
        save_sequence(other, target)
    assert info.value.filename == str(target / "frames.csv")
    after = _files(target)
    assert after["frames.csv"] == before["frames.csv"]
    assert after.keys() == before.keys()  # no temporary files left behind
    assert not [p for p in target.rglob("*") if p.name.startswith(".") or p.suffix == ".tmp"]


# ----------------------------------------------------------------------------------- images
def _write_pngs(folder: Path) -> dict[int, dict[int, Path]]:
    rng = np.random.default_rng(11)
    wanted = {0: [0, 3, N_FRAMES - 1], 2: [7]}
    out: dict[int, dict[int, Path]] = {}
    for cam, frames in wanted.items():
        cam_dir = folder / "images" / f"cam_{cam + 1}"
        cam_dir.mkdir(parents=True, exist_ok=True)
        for frame in frames:
            path = cam_dir / f"{frame:06d}.png"
            assert cv2.imwrite(str(path), rng.integers(0, 256, (6, 8, 3), dtype=np.uint8))
            out.setdefault(cam, {})[frame] = path
    return out


def test_images_are_found_and_copied(folder: Path, tmp_path: Path) -> None:
    expected = _write_pngs(folder)
    seq = load_sequence(folder)
    assert seq.images == expected
    copy = tmp_path / "copy"
    save_sequence(seq, copy)
    assert _files(copy / "images") == _files(folder / "images")
    reloaded = load_sequence(copy)
    assert reloaded.images == {cam: {f: copy / p.relative_to(folder) for f, p in files.items()}
                               for cam, files in expected.items()}
    assert reloaded.equals(seq)
    # Saving a sequence back into its own folder leaves its images as they are.
    images_before = _files(folder / "images")
    save_sequence(seq, folder)
    assert _files(folder / "images") == images_before


# ------------------------------------------------------------------------------- bad paths
def test_load_a_file_is_an_error(tmp_path: Path) -> None:
    path = tmp_path / "frames.csv"
    path.write_text("frame,timestamp\n0,0.0\n")
    with pytest.raises(ValueError, match="not a sequence folder") as info:
        load_sequence(path)
    assert str(path) in str(info.value)


def test_load_a_missing_folder_is_an_error(tmp_path: Path) -> None:
    path = tmp_path / "nowhere"
    with pytest.raises(ValueError) as info:
        load_sequence(path)
    assert str(info.value).startswith(str(path))


def test_load_a_folder_without_robot_toml_is_an_error(folder: Path) -> None:
    (folder / "robot.toml").unlink()
    with pytest.raises(ValueError, match="no such file") as info:
        load_sequence(folder)
    assert str(info.value).startswith(str(folder / "robot.toml"))
