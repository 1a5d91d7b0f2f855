"""Camera recordings besides image folders: ROS bags and video files, tracked into a sequence.

A recording gives each camera a stream of timestamped images (:class:`CameraStream`):

- :func:`bag_streams`: ROS 1 bags and ROS 2 bags (sqlite3 or MCAP), read by the pure-Python
  ``rosbags`` package (no ROS installation; ``pip install "apcc-graph[ros]"``), one
  ``sensor_msgs/Image`` (``mono8``, ``mono16``, ``bgr8``, ``rgb8``, ``bgra8``, ``rgba8``) or
  ``sensor_msgs/CompressedImage`` topic per camera; a message's time is its header stamp;
- :func:`video_streams`: one video file per camera (OpenCV), a frame's time its position in
  the video.

Cameras that are not synchronised are matched to common frames by time (:func:`match_frames`):
the first camera's images set the frames, and every other camera contributes its image nearest
in time when it lies within the tolerance (default: half the first camera's median frame
interval). A frame some camera cannot match is dropped; what was dropped is counted
(:class:`Matched`). :func:`track_recording` then runs the KLT tracker of
:mod:`apcc_graph.frontend.tracking` over each camera's matched images, in order, and writes a
sequence folder.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from apcc_graph.frontend.tracking import KLTTracker, TrackerOptions, tracks_of
from apcc_graph.model.arrays import FloatArray, IntArray
from apcc_graph.model.robot import Robot
from apcc_graph.model.sequence import Sequence as RobotSequence


@dataclass(frozen=True)
class CameraStream:
    """One camera's images: their times and a way to read them again, in order.

    Attributes:
        name: where they come from (``bag:/topic`` or the video file), for messages.
        timestamps: ``(N,)`` seconds, non-decreasing.
        images: a fresh iterator over ``(index, image)`` in order (``index`` into
            ``timestamps``); it may skip nothing.
    """

    name: str
    timestamps: FloatArray
    images: Callable[[], Iterator[tuple[int, NDArray]]]


@dataclass(frozen=True)
class Matched:
    """Common frames of several cameras.

    Attributes:
        timestamps: ``(F,)`` the frames' times (the first camera's), seconds.
        indices: ``(C, F)`` per camera, the image of each frame.
        dropped: per camera, its images no frame took.
        unmatched: frames of the first camera dropped because another had no image near enough.
        tolerance: the largest time difference allowed (seconds).
    """

    timestamps: FloatArray
    indices: IntArray
    dropped: tuple[int, ...]
    unmatched: int
    tolerance: float


def match_frames(stamps: Sequence[FloatArray], tolerance: float | None = None) -> Matched:
    """Common frames of cameras with the image times ``stamps`` (module docstring).

    Raises:
        ValueError: a camera without images, times that decrease, or no common frame.
    """
    stamps = [np.asarray(s, dtype=float) for s in stamps]
    for c, s in enumerate(stamps):
        if len(s) == 0:
            raise ValueError(f"camera {c + 1}: no images")
        if np.any(np.diff(s) < 0):
            raise ValueError(f"camera {c + 1}: image times go back")
    ref = stamps[0]
    if tolerance is None:
        tolerance = 0.5 * float(np.median(np.diff(ref))) if len(ref) > 1 else 0.0
    columns, keep = [np.arange(len(ref))], np.ones(len(ref), dtype=bool)
    for s in stamps[1:]:
        right = np.searchsorted(s, ref).clip(0, len(s) - 1)
        left = (right - 1).clip(0, len(s) - 1)
        nearest = np.where(np.abs(s[left] - ref) <= np.abs(s[right] - ref), left, right)
        keep &= np.abs(s[nearest] - ref) <= tolerance + 1e-12
        columns.append(nearest)
    indices = np.array(columns)[:, keep]
    if indices.shape[1] > 1:  # one image per frame: a repeated image keeps its first frame
        repeated = np.any(np.diff(indices, axis=1) == 0, axis=0)
        indices = indices[:, np.concatenate([[True], ~repeated])]
    if indices.shape[1] == 0:
        raise ValueError(f"no frame: the cameras' images are never within {tolerance:.4g} s "
                         "of each other")
    dropped = tuple(int(len(s) - len(np.unique(row))) for s, row in zip(stamps, indices,
                                                                           strict=True))
    return Matched(ref[indices[0]], indices, dropped, int(len(ref) - indices.shape[1]),
                   float(tolerance))


def track_recording(streams: Sequence[CameraStream], robot: Robot,
                    tolerance: float | None = None, options: TrackerOptions | None = None,
                    progress: bool = False) -> tuple[RobotSequence, Matched]:
    """Track a recording: its cameras' streams (one per camera of ``robot``, in the order of
    ``robot.camera_segments``) matched to common frames and tracked; returns the sequence
    (times from 0 at its first frame) and how the frames were matched.

    Raises:
        ValueError: a stream per camera missing, no common frame, or an image of the wrong
            size (the message names the stream and the image).
    """
    from apcc_graph.io.console import progress_bar

    cams = robot.camera_segments
    if len(streams) != len(cams):
        raise ValueError(f"{len(streams)} camera streams for a robot with {len(cams)} cameras "
                         f"(on segments {', '.join(str(c + 1) for c in cams)})")
    matched = match_frames([s.timestamps for s in streams], tolerance)
    tracks = {}
    bar = progress_bar(total=matched.indices.size, desc="track", unit="image", progress=progress)
    for cam, stream, wanted in zip(cams, streams, matched.indices, strict=True):
        camera = robot.cameras[cam]
        assert camera is not None
        frame_of = {int(i): f for f, i in enumerate(wanted)}
        tracker = KLTTracker((camera.width, camera.height), options)
        chosen = ((frame_of[i], image, f"{stream.name}, image {i}")
                  for i, image in stream.images() if i in frame_of)
        read = [0]
        tracks[cam] = tracks_of(tracker, chosen, partial(_tick, read, bar))
        if read[0] != len(wanted):
            raise ValueError(f"{stream.name}: {read[0]} of its {len(wanted)} matched images "
                             "could be read (the recording ends early or is damaged)")
    bar.close()
    times = matched.timestamps - matched.timestamps[0]
    return RobotSequence(robot, times, tracks), matched


def _tick(read: list[int], bar: Any) -> None:
    """One more image tracked: counted, and shown."""
    read[0] += 1
    bar.update()


# ------------------------------------------------------------------------------ videos
def video_streams(paths: Sequence[str | Path]) -> list[CameraStream]:
    """One stream per video file (OpenCV), a frame's time its position in the video.

    Raises:
        ValueError: a file OpenCV cannot open, or without frames.
    """
    out = []
    for path in map(Path, paths):
        capture = cv2.VideoCapture(str(path))
        if not capture.isOpened():
            raise ValueError(f"{path}: OpenCV cannot open it as a video")
        stamps = []
        fps = capture.get(cv2.CAP_PROP_FPS) or 0.0
        while capture.grab():
            msec = capture.get(cv2.CAP_PROP_POS_MSEC)
            stamps.append(msec / 1e3 if msec > 0 or not stamps or fps <= 0
                          else len(stamps) / fps)
        capture.release()
        if not stamps:
            raise ValueError(f"{path}: no frames")
        out.append(CameraStream(str(path), _increasing(stamps, fps), _video_images(path)))
    return out


def _increasing(stamps: list[float], fps: float) -> FloatArray:
    """Frame times that never go back (some containers report 0 for the first frames)."""
    t = np.asarray(stamps, dtype=float)
    if fps > 0 and (np.any(np.diff(t) <= 0)):
        return np.arange(len(t)) / fps
    return t


def _video_images(path: Path) -> Callable[[], Iterator[tuple[int, NDArray]]]:
    def images() -> Iterator[tuple[int, NDArray]]:
        capture = cv2.VideoCapture(str(path))
        index = 0
        try:
            while True:
                ok, image = capture.read()
                if not ok:
                    return
                yield index, image
                index += 1
        finally:
            capture.release()
    return images


# -------------------------------------------------------------------------------- bags
def bag_streams(path: str | Path, topics: Sequence[str] | None, n_cameras: int
                ) -> list[CameraStream]:
    """One stream per image topic of a ROS 1 or ROS 2 bag (``topics`` in camera order; by
    default the bag's image topics, sorted, when there are exactly ``n_cameras``).

    Raises:
        ValueError: ``rosbags`` missing, a bag it cannot read (the message says why), a topic
            missing or not of an image type (the bag's image topics are listed).
    """
    from apcc_graph.frontend.bag_images import image_topics, open_bag, read_stamps

    path = Path(path)
    with open_bag(path) as reader:
        found = image_topics(reader)
        if topics is None:
            if len(found) != n_cameras:
                raise ValueError(f"{path}: {len(found)} image topics ({', '.join(found) or 'none'})"
                                 f" for {n_cameras} cameras: name them with --topics")
            topics = sorted(found)
        for topic in topics:
            if topic not in found:
                raise ValueError(f"{path}: no image topic {topic!r} (its image topics: "
                                 f"{', '.join(sorted(found)) or 'none'})")
        stamps = read_stamps(reader, path, list(topics))
    return [CameraStream(f"{path}:{topic}", stamps[topic], _bag_images(path, topic))
            for topic in topics]


def _bag_images(path: Path, topic: str) -> Callable[[], Iterator[tuple[int, NDArray]]]:
    def images() -> Iterator[tuple[int, NDArray]]:
        from apcc_graph.frontend.bag_images import read_images

        yield from read_images(path, topic)
    return images
