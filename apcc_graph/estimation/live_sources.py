"""Frame sources of the live loop (:mod:`~apcc_graph.estimation.live`): a recording's
streams matched by time (:func:`recording_frames`) and cameras plugged in
(:func:`device_frames`). Each yields ``(index, timestamp, camera -> image)`` in time order."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator, Sequence

from numpy.typing import NDArray

from apcc_graph.frontend.recordings import CameraStream, match_frames

Frame = tuple[int, float, dict[int, NDArray]]
"""``(index in the source, timestamp in seconds, camera -> image)``."""

__all__ = ["Frame", "device_frames", "recording_frames"]


def recording_frames(streams: Sequence[CameraStream], cameras: Sequence[int],
                     tolerance: float | None = None) -> Iterator[Frame]:
    """The frames of a recording's streams (one per camera, in the order of ``cameras``),
    matched by time (:func:`~apcc_graph.frontend.recordings.match_frames`), read in order."""
    matched = match_frames([s.timestamps for s in streams], tolerance)
    readers = [s.images() for s in streams]
    for f, t in enumerate(matched.timestamps.tolist()):
        images = {}
        for cam, reader, wanted in zip(cameras, readers, matched.indices[:, f], strict=True):
            for index, image in reader:
                if index == wanted:
                    images[cam] = image
                    break
        if len(images) < len(cameras):
            return  # a stream ended early
        yield f, t, images


def device_frames(devices: Sequence[int], cameras: Sequence[int],
                  clock: Callable[[], float] = time.monotonic) -> Iterator[Frame]:
    """Frames of cameras plugged in (OpenCV device indices, one per camera in the order of
    ``cameras``): each camera's newest image, grabbed together, timed by ``clock``.

    Raises:
        ValueError: a device OpenCV cannot open.
    """
    import cv2

    captures = []
    for device in devices:
        capture = cv2.VideoCapture(int(device))
        if not capture.isOpened():
            raise ValueError(f"camera device {device}: OpenCV cannot open it")
        capture.set(cv2.CAP_PROP_BUFFERSIZE, 1)
        captures.append(capture)
    try:
        index = 0
        while True:
            if not all(c.grab() for c in captures):
                return
            t = clock()
            images = {}
            for cam, capture in zip(cameras, captures, strict=True):
                ok, image = capture.retrieve()
                if not ok:
                    return
                images[cam] = image
            yield index, t, images
            index += 1
    finally:
        for capture in captures:
            capture.release()
