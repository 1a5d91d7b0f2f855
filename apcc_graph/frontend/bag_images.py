"""Images out of ROS 1 and ROS 2 bags, read by the pure-Python ``rosbags`` package.

``sensor_msgs/Image`` (``mono8``, ``mono16``, ``8UC1``, ``bgr8``, ``rgb8``, ``bgra8``,
``rgba8``) and ``sensor_msgs/CompressedImage`` (any format OpenCV decodes) become 8-bit grey
images; a message's time is its header stamp (seconds). Used by
:mod:`apcc_graph.frontend.recordings`.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from apcc_graph.model.arrays import FloatArray

IMAGE = "sensor_msgs/msg/Image"
COMPRESSED = "sensor_msgs/msg/CompressedImage"


@contextmanager
def open_bag(path: Path) -> Iterator[Any]:
    """An open ``rosbags`` ``AnyReader`` of a ROS 1 bag file or a ROS 2 bag folder.

    Raises:
        ValueError: ``rosbags`` is not installed, or it cannot read the bag (why).
    """
    try:
        from rosbags.highlevel import AnyReader
    except ImportError:
        raise ValueError('reading ROS bags needs rosbags: pip install "apcc-graph[ros]"'
                         ) from None
    if not path.exists():
        raise ValueError(f"{path}: no such bag")
    try:
        reader = AnyReader([path])
        reader.open()
    except Exception as exc:  # rosbags' reader errors have no common public base
        raise ValueError(f"{path}: not a readable ROS bag ({exc})") from None
    try:
        yield reader
    finally:
        reader.close()


def image_topics(reader: Any) -> dict[str, str]:
    """The bag's topics that carry images, with their message types."""
    return {c.topic: c.msgtype for c in reader.connections if c.msgtype in (IMAGE, COMPRESSED)}


def read_stamps(reader: Any, path: Path, topics: list[str]) -> dict[str, FloatArray]:
    """Each topic's header stamps (seconds), in the order of its messages.

    Raises:
        ValueError: a message that cannot be read (a truncated or damaged bag).
    """
    stamps: dict[str, list[float]] = {t: [] for t in topics}
    connections = [c for c in reader.connections if c.topic in stamps]
    try:
        for connection, _, raw in reader.messages(connections=connections):
            msg = reader.deserialize(raw, connection.msgtype)
            stamp = msg.header.stamp
            stamps[connection.topic].append(stamp.sec + stamp.nanosec * 1e-9)
    except Exception as exc:  # rosbags raises its own errors on a damaged bag
        raise ValueError(f"{path}: cannot read its messages ({exc}); is it truncated?") from None
    return {t: np.asarray(s, dtype=float) for t, s in stamps.items()}


def read_images(path: Path, topic: str) -> Iterator[tuple[int, NDArray[np.uint8]]]:
    """``(index, grey image)`` of every message of ``topic``, in order.

    Raises:
        ValueError: an encoding it cannot turn into grey, or an image that cannot be decoded.
    """
    with open_bag(path) as reader:
        connections = [c for c in reader.connections if c.topic == topic]
        for index, (connection, _, raw) in enumerate(reader.messages(connections=connections)):
            msg = reader.deserialize(raw, connection.msgtype)
            where = f"{path}:{topic}, message {index}"
            yield index, (_decoded(msg, where) if connection.msgtype == COMPRESSED
                          else _raw_image(msg, where))


def _decoded(msg: Any, where: str) -> NDArray[np.uint8]:
    image = cv2.imdecode(np.asarray(msg.data, dtype=np.uint8), cv2.IMREAD_GRAYSCALE)
    if image is None:
        raise ValueError(f"{where}: OpenCV cannot decode its {msg.format!r} image")
    return image


def _raw_image(msg: Any, where: str) -> NDArray[np.uint8]:
    """A ``sensor_msgs/Image`` as 8-bit grey."""
    height, width, step, encoding = int(msg.height), int(msg.width), int(msg.step), msg.encoding
    data = np.asarray(msg.data, dtype=np.uint8)
    channels = {"mono8": 1, "8UC1": 1, "bgr8": 3, "rgb8": 3, "bgra8": 4, "rgba8": 4,
                "mono16": 2, "16UC1": 2}.get(encoding)
    if channels is None:
        raise ValueError(f"{where}: encoding {encoding!r}: expected mono8, mono16, bgr8, rgb8, "
                         "bgra8 or rgba8")
    if len(data) < height * step or step < width * channels:
        raise ValueError(f"{where}: {len(data)} bytes for {height} rows of {step}")
    rows = data[:height * step].reshape(height, step)[:, :width * channels]
    if channels == 2:  # 16-bit grey, to 8 bits
        big = ">" if msg.is_bigendian else "<"
        image16 = rows.copy().view(f"{big}u2").reshape(height, width)
        return (image16 >> 8).astype(np.uint8)
    if channels == 1:
        return np.ascontiguousarray(rows)
    image = rows.reshape(height, width, channels)
    code = {"bgr8": cv2.COLOR_BGR2GRAY, "rgb8": cv2.COLOR_RGB2GRAY, "bgra8": cv2.COLOR_BGRA2GRAY,
            "rgba8": cv2.COLOR_RGBA2GRAY}[encoding]
    return cv2.cvtColor(np.ascontiguousarray(image), code)
