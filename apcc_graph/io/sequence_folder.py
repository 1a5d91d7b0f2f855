"""Sequence folders on disk (docs/formats.md), read with validation and written atomically.

A sequence is a folder::

    robot.toml
    frames.csv         frame,timestamp[,base_x,base_y,base_z,base_qw,base_qx,base_qy,base_qz]
                       [,theta_1..theta_S][,psi_1..psi_S]
    tracks/cam_<i>.csv frame,track_id,u,v          (i = 1..S: the segment the camera rides on)
    images/cam_<i>/<frame:06d>.png                 (optional)

Frames are 0-based, consecutive and increasing; timestamps in seconds; base pose columns absent
means a fixed base; theta/psi columns are ground truth in radians. Track rows need not be sorted.
Every error names the file, and for CSV files the 1-based line (the header is line 1) and column.
Pixels outside the image are dropped with one :class:`SequenceWarning` per file that counts them.

Saving writes each file to a temporary file and renames it, so a reader never sees half a file;
numbers are written in their shortest exact form, so save -> load -> save is byte-for-byte stable.
"""

from __future__ import annotations

import re
import warnings
from pathlib import Path

import numpy as np
import tomli_w

from apcc_graph.io.atomic import atomic_write_bytes, atomic_write_text
from apcc_graph.io.csv_table import CsvTable, format_number, read_header, read_table
from apcc_graph.io.poses import (
    UNIT_TOLERANCE,
    quaternion_for_file,
    rotation_from_quaternion,
)
from apcc_graph.io.robot_file import load_robot, robot_to_toml
from apcc_graph.io.truth_tips import load_truth_tips, truth_tips_csv
from apcc_graph.model.robot import Robot
from apcc_graph.model.sequence import Sequence, Tracks

BASE_COLUMNS = ["base_x", "base_y", "base_z", "base_qw", "base_qx", "base_qy", "base_qz"]
TRACK_COLUMNS = ["frame", "track_id", "u", "v"]
_CAM_FILE = re.compile(r"cam_([1-9]\d*)\.csv")
_CAM_DIR = re.compile(r"cam_([1-9]\d*)")
_IMAGE_FILE = re.compile(r"(\d{6})\.png")


class SequenceWarning(UserWarning):
    """Something in a sequence was repaired (e.g. pixels outside the image were dropped)."""


def frame_columns(n_segments: int, base: bool, thetas: bool, psis: bool) -> list[str]:
    """The header of ``frames.csv`` for the given optional column groups."""
    names = ["frame", "timestamp"]
    if base:
        names += BASE_COLUMNS
    if thetas:
        names += [f"theta_{i}" for i in range(1, n_segments + 1)]
    if psis:
        names += [f"psi_{i}" for i in range(1, n_segments + 1)]
    return names


TRUTH_TIPS_FILE = "truth_tips.csv"
"""The measured segment-end poses of a real-motion replay (:mod:`apcc_graph.io.truth_tips`)."""


# ------------------------------------------------------------------------------------ loading
def load_sequence(path: str | Path) -> Sequence:
    """Read a sequence folder.

    Args:
        path: the folder.

    Returns:
        The sequence (cameras keyed by 0-based segment index).

    Raises:
        ValueError: a missing or malformed file; the message names the file, line and column.
    """
    folder = Path(path)
    if not folder.is_dir():
        raise ValueError(f"{folder}: not a sequence folder (expected a folder with robot.toml, "
                         "frames.csv and tracks/)")
    robot = load_robot(folder / "robot.toml")
    timestamps, base, thetas, psis = _load_frames(folder / "frames.csv", robot.n_segments)
    tracks = _load_all_tracks(folder / "tracks", robot, len(timestamps))
    images = _find_images(folder / "images", robot, len(timestamps))
    tips_file = folder / TRUTH_TIPS_FILE
    tips = (load_truth_tips(tips_file, len(timestamps), robot.n_segments)
            if tips_file.is_file() else None)
    return Sequence(robot, timestamps, tracks, world_T_base=base, thetas=thetas, psis=psis,
                    images=images, truth_tips=tips)


def _load_frames(
    path: Path, n_seg: int
) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None, np.ndarray | None]:
    names = read_header(path)
    expected = frame_columns(n_seg, "base_x" in names, "theta_1" in names, "psi_1" in names)
    table = read_table(path, expected)
    if len(table) == 0:
        raise ValueError(f"{path}: no frames; expected one row per frame")
    table.require_finite()
    frames = table.integers("frame")
    wrong = np.flatnonzero(frames != np.arange(len(frames)))
    if len(wrong):
        row = int(wrong[0])
        raise table.error(row, "frame", f"expected frame {row}, got {int(frames[row])} (frames are "
                          "0-based, consecutive and increasing)")
    ts = table.column("timestamp")
    back = np.flatnonzero(np.diff(ts) <= 0)
    if len(back):
        row = int(back[0]) + 1
        raise table.error(row, "timestamp", f"{float(ts[row])!r} s is not after the previous "
                          f"frame's {float(ts[row - 1])!r} s; expected strictly increasing "
                          "timestamps")
    base = _base_poses(table) if "base_x" in names else None
    thetas = psis = None
    if "theta_1" in names:
        thetas = np.column_stack([table.column(f"theta_{i}") for i in range(1, n_seg + 1)])
    if "psi_1" in names:
        psis = np.column_stack([table.column(f"psi_{i}") for i in range(1, n_seg + 1)])
    return ts, base, thetas, psis


def _base_poses(table: CsvTable) -> np.ndarray:
    quats = np.column_stack([table.column(n) for n in BASE_COLUMNS[3:]])
    norms = np.linalg.norm(quats, axis=1)
    bad = np.flatnonzero(np.abs(norms - 1.0) > UNIT_TOLERANCE)
    if len(bad):
        row = int(bad[0])
        raise table.error(row, "base_qw", f"(base_qw, base_qx, base_qy, base_qz) must be a unit "
                          f"quaternion, got norm {norms[row]:.9g}")
    poses = np.zeros((len(table), 4, 4))
    poses[:, 3, 3] = 1.0
    for f, quat in enumerate(quats.tolist()):
        poses[f, :3, :3] = rotation_from_quaternion(quat)
    poses[:, :3, 3] = np.column_stack([table.column(n) for n in BASE_COLUMNS[:3]])
    return poses


def _camera_index(folder: Path, entry: Path, pattern: re.Pattern[str], robot: Robot,
                  what: str) -> int:
    match = pattern.fullmatch(entry.name)
    if match is None:
        raise ValueError(f"{entry}: unexpected {what} in {folder}; expected cam_<i>"
                         f"{'.csv' if what == 'file' else ''} with i = 1..{robot.n_segments}")
    cam = int(match.group(1)) - 1
    if cam not in robot.camera_segments:
        have = ", ".join(f"cam_{c + 1}" for c in robot.camera_segments) or "none"
        raise ValueError(f"{entry}: the robot has no camera on segment {cam + 1} "
                         f"(cameras: {have})")
    return cam


def _load_all_tracks(folder: Path, robot: Robot, n_frames: int) -> dict[int, Tracks]:
    if not folder.exists():
        return {}
    if not folder.is_dir():
        raise ValueError(f"{folder}: expected a folder of cam_<i>.csv files")
    tracks = {}
    for entry in sorted(folder.iterdir()):
        if entry.name.startswith("."):
            continue
        cam = _camera_index(folder, entry, _CAM_FILE, robot, "file")
        tracks[cam] = load_tracks(entry, robot, cam, n_frames)
    return tracks


def load_tracks(path: str | Path, robot: Robot, cam: int, n_frames: int) -> Tracks:
    """Read one ``tracks/cam_<i>.csv`` for camera ``cam`` (0-based) of a sequence of n frames.

    Raises:
        ValueError: bad header, line, value, a frame without a timestamp or a duplicate track id in
            one frame; the message names the file and the line.
    """
    path = Path(path)
    table = read_table(path, TRACK_COLUMNS)
    table.require_finite()
    frames = table.integers("frame")
    ids = table.integers("track_id")
    late = np.flatnonzero(frames >= n_frames)
    if len(late):
        row = int(late[0])
        raise table.error(row, "frame", f"frame {frames[row]} has no timestamp in frames.csv "
                          f"(frames 0..{n_frames - 1})")
    order = np.lexsort((ids, frames))
    dup = np.flatnonzero((np.diff(frames[order]) == 0) & (np.diff(ids[order]) == 0))
    if len(dup):
        first, second = sorted((int(order[dup[0]]), int(order[dup[0] + 1])))
        raise table.error(second, "track_id", f"track id {ids[second]} appears twice in frame "
                          f"{frames[second]} (also on line {table.line(first)})")
    uv = table.values[:, 2:4]
    camera = robot.cameras[cam]
    assert camera is not None
    inside = camera.in_image(uv)
    if not inside.all():
        warnings.warn(
            f"{path}: dropped {int((~inside).sum())} of {len(uv)} track rows with pixels outside "
            f"the {camera.width}x{camera.height} image",
            SequenceWarning, stacklevel=3,
        )
    keep = order[inside[order]]  # sorted by (frame, track id): Tracks need not sort again
    return Tracks(frames[keep], ids[keep], uv[keep])


def _find_images(folder: Path, robot: Robot, n_frames: int) -> dict[int, dict[int, Path]]:
    if not folder.exists():
        return {}
    images: dict[int, dict[int, Path]] = {}
    for cam_dir in sorted(folder.iterdir()):
        if cam_dir.name.startswith("."):
            continue
        if not cam_dir.is_dir():
            raise ValueError(f"{cam_dir}: expected a folder images/cam_<i>/")
        cam = _camera_index(folder, cam_dir, _CAM_DIR, robot, "folder")
        files = {}
        for image in sorted(cam_dir.iterdir()):
            if image.name.startswith("."):
                continue
            match = _IMAGE_FILE.fullmatch(image.name)
            if match is None:
                raise ValueError(f"{image}: unexpected file; images are named <frame:06d>.png")
            frame = int(match.group(1))
            if frame >= n_frames:
                raise ValueError(f"{image}: frame {frame} has no timestamp in frames.csv "
                                 f"(frames 0..{n_frames - 1})")
            files[frame] = image
        images[cam] = files
    return images


# ------------------------------------------------------------------------------------- saving
def save_sequence(sequence: Sequence, path: str | Path) -> None:
    """Write a sequence folder; each file is written atomically (temporary file, then rename).

    Every camera of the robot gets a tracks file (header only if it saw nothing); images are
    copied into ``images/`` when they live elsewhere.

    Args:
        sequence: the sequence.
        path: the folder; created if needed. An existing sequence there is overwritten file by
            file.

    Raises:
        ValueError: the folder holds a tracks file for a camera this robot does not have, or
            images that are not this sequence's (either would make the saved folder unreadable or
            wrong); nothing is written then.
    """
    folder = Path(path)
    if folder.exists() and not folder.is_dir():
        raise ValueError(f"{folder}: exists and is not a folder")
    robot = sequence.robot
    wanted = {f"cam_{c + 1}.csv" for c in robot.camera_segments}
    tracks_dir = folder / "tracks"
    if tracks_dir.is_dir():
        stale = sorted(p.name for p in tracks_dir.iterdir()
                       if not p.name.startswith(".") and p.name not in wanted)
        if stale:
            raise ValueError(f"{tracks_dir}: holds {', '.join(stale)}, which this robot has no "
                             "camera for; save into an empty folder")
    targets = {
        (folder / "images" / f"cam_{cam + 1}" / f"{frame:06d}.png").resolve()
        for cam, files in sequence.images.items() for frame in files
    }
    images_dir = folder / "images"
    if images_dir.is_dir():
        stale_images = sorted(
            str(p.relative_to(folder)) for p in images_dir.rglob("*")
            if p.is_file() and not p.name.startswith(".") and p.resolve() not in targets
        )
        if stale_images:
            shown = ", ".join(stale_images[:3]) + (" ..." if len(stale_images) > 3 else "")
            raise ValueError(f"{images_dir}: holds {len(stale_images)} image(s) that are not part "
                             f"of this sequence ({shown}); save into an empty folder")
    atomic_write_bytes(folder / "robot.toml", tomli_w.dumps(robot_to_toml(robot)).encode())
    atomic_write_text(folder / "frames.csv", frames_csv(sequence))
    if sequence.truth_tips is not None:
        atomic_write_text(folder / TRUTH_TIPS_FILE, truth_tips_csv(sequence.truth_tips))
    else:
        (folder / TRUTH_TIPS_FILE).unlink(missing_ok=True)  # not this sequence's truth
    for cam in robot.camera_segments:
        trk = sequence.tracks.get(cam)
        atomic_write_text(tracks_dir / f"cam_{cam + 1}.csv", tracks_csv(trk))
    for cam, files in sequence.images.items():
        for frame, source in files.items():
            target = folder / "images" / f"cam_{cam + 1}" / f"{frame:06d}.png"
            if source.resolve() != target.resolve():
                atomic_write_bytes(target, source.read_bytes())


def frames_csv(sequence: Sequence) -> str:
    """The text of ``frames.csv``."""
    n_seg = sequence.n_segments
    names = frame_columns(n_seg, sequence.world_T_base is not None, sequence.thetas is not None,
                          sequence.psis is not None)
    columns: list[list[str]] = [
        [str(f) for f in range(sequence.n_frames)],
        [format_number(t) for t in sequence.timestamps.tolist()],
    ]
    if sequence.world_T_base is not None:
        poses = sequence.world_T_base
        columns += [[format_number(v) for v in poses[:, i, 3].tolist()] for i in range(3)]
        quats = [quaternion_for_file(pose[:3, :3]) for pose in poses]
        columns += [[format_number(q[j]) for q in quats] for j in range(4)]
    for angles in (sequence.thetas, sequence.psis):
        if angles is not None:
            columns += [[format_number(v) for v in angles[:, i].tolist()] for i in range(n_seg)]
    rows = [",".join(fields) for fields in zip(*columns, strict=True)]
    return ",".join(names) + "\n" + "".join(row + "\n" for row in rows)


def tracks_csv(tracks: Tracks | None) -> str:
    """The text of one ``tracks/cam_<i>.csv`` (rows sorted by frame, then track id)."""
    header = ",".join(TRACK_COLUMNS) + "\n"
    if tracks is None or len(tracks) == 0:
        return header
    rows = zip(tracks.frames.tolist(), tracks.track_ids.tolist(), tracks.uv[:, 0].tolist(),
               tracks.uv[:, 1].tolist(), strict=True)
    return header + "".join(f"{f},{i},{u!r},{v!r}\n" for f, i, u, v in rows)


__all__ = ["SequenceWarning", "load_sequence", "load_tracks", "save_sequence"]
