"""The ``robot.toml`` file (formats ``apcc-graph/robot@1`` and ``@2``, docs/formats.md), and the
camera table it shares with the setup file of calibration photos (:func:`camera_from_table`).

Version 2 adds each segment's measured departure from its model, ``[segments.model_error]``
(:class:`~apcc_graph.model.model_error.ModelError`: ``position_mm``, ``rotation_deg``, the
optional ``correlation_s``, ``correlation_deg`` and ``measured``, how it was measured). A robot
with a model error is written as version 2, any other as version 1, which version-1 readers keep
reading; both are read.

Angles are degrees in the file (keys ending in ``_deg``) and radians in memory. The camera mounting
``tip_T_cam`` is a translation in metres and a unit quaternion ``(w, x, y, z)``. Every error names
the file and the key (``segments[i].camera.fx``; indices are 0-based as in the TOML array).
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import tomli_w

from apcc_graph.io.atomic import atomic_write_bytes
from apcc_graph.io.poses import (
    quaternion_for_file,
    rotation_from_quaternion,
)
from apcc_graph.io.toml_fields import TomlTable, read_toml
from apcc_graph.io.units import PLAUSIBLE_LENGTH_M, UnitsWarning
from apcc_graph.model.camera import TipCamera
from apcc_graph.model.model_error import ModelError
from apcc_graph.model.robot import Robot
from apcc_graph.model.segment import Segment

ROBOT_FORMAT = "apcc-graph/robot@1"
ROBOT_FORMAT_MODEL_ERROR = "apcc-graph/robot@2"
"""The version that carries the segments' model errors."""

_SEGMENT_KEYS = {
    "length": "length",
    "k": "k",
    "delta_max": "delta_max_deg",
    "theta_max": "theta_max_deg",
}
_CAMERA_KEYS = ("fx", "fy", "cx", "cy", "width", "height", "distortion", "model", "topic",
                "tip_T_cam")


def _model_error_from(table: TomlTable) -> ModelError:
    table.check_keys(("position_mm", "rotation_deg", "correlation_s", "correlation_deg",
                      "measured"),
                     required=("position_mm", "rotation_deg"))
    values: dict[str, Any] = {"position": table.number("position_mm") / 1000.0,
                              "rotation": math.radians(table.number("rotation_deg"))}
    if table.has("correlation_s"):
        values["correlation_time"] = table.number("correlation_s")
    if table.has("correlation_deg"):
        values["correlation_bend"] = math.radians(table.number("correlation_deg"))
    if table.has("measured"):
        values["measured"] = table.string("measured")
    try:
        return ModelError(**values)
    except ValueError as exc:
        raise table.error("", str(exc)) from None


def _segment_from(table: TomlTable, version: int) -> Segment:
    allowed = [*_SEGMENT_KEYS.values(), "camera"] + (["model_error"] if version >= 2 else [])
    if version < 2 and table.has("model_error"):
        raise table.error("model_error", f"a segment's model error needs format = "
                          f"{ROBOT_FORMAT_MODEL_ERROR!r}")
    table.check_keys(allowed, required=_SEGMENT_KEYS.values())
    values: dict[str, Any] = {
        "length": table.metres("length"),
        "k": table.number("k"),
        "delta_max": math.radians(table.number("delta_max_deg")),
        "theta_max": math.radians(table.number("theta_max_deg")),
    }
    if table.has("model_error"):
        values["model_error"] = _model_error_from(table.table("model_error"))
    try:
        return Segment(**values)
    except ValueError as exc:
        for field, key in _SEGMENT_KEYS.items():
            if str(exc).startswith(f"Segment.{field} "):
                shown = table.data[key]
                raise table.error(key, f"{exc} (the file gives {key} = {shown!r})") from None
        raise table.error("", str(exc)) from None


def _pose_from(table: TomlTable) -> np.ndarray:
    table.check_keys(("translation", "quaternion_wxyz"))
    translation = table.numbers("translation", 3, default=[0.0, 0.0, 0.0])
    far = [i for i, t in enumerate(translation) if abs(t) > PLAUSIBLE_LENGTH_M]
    if far:
        warnings.warn(f"{table.path}: {table.key('translation')}[{far[0]}] = "
                      f"{translation[far[0]]!r} m: an offset of more than "
                      f"{PLAUSIBLE_LENGTH_M:g} m on a continuum robot is implausible; lengths "
                      f"are in metres (if this is millimetres, write "
                      f"{translation[far[0]] / 1000.0:g})", UnitsWarning, stacklevel=4)
    quat = table.numbers("quaternion_wxyz", 4, default=[1.0, 0.0, 0.0, 0.0])
    norm = math.sqrt(sum(q * q for q in quat))
    if abs(norm - 1.0) > 1e-6:
        raise table.error(
            "quaternion_wxyz", f"expected a unit quaternion (w, x, y, z), got norm {norm:.9g}"
        )
    pose = np.eye(4)
    pose[:3, :3] = rotation_from_quaternion(quat)
    pose[:3, 3] = translation
    return pose


def camera_from_table(table: TomlTable, mounting: bool = True) -> TipCamera:
    """A :class:`TipCamera` from its TOML table: ``fx``, ``fy``, ``cx``, ``cy``, ``width``,
    ``height``, the optional ``distortion`` (OpenCV order) and its ``model`` (``"pinhole"``, the
    default, or ``"fisheye"``) and, with ``mounting``, the optional ``tip_T_cam`` table (default
    identity). Without ``mounting`` a ``tip_T_cam`` key is unknown.

    The camera table of ``robot.toml`` and of a calibration-images folder's ``calibration.toml``
    (docs/formats.md).

    Raises:
        ValueError: a missing, unknown or bad key; the message names the file and the key.
    """
    keys = _CAMERA_KEYS if mounting else _CAMERA_KEYS[:-1]
    table.check_keys(keys, required=("fx", "fy", "cx", "cy", "width", "height"))
    tip_T_cam = _pose_from(table.table("tip_T_cam")) if table.has("tip_T_cam") else np.eye(4)
    values: dict[str, Any] = {name: table.number(name) for name in ("fx", "fy", "cx", "cy")}
    values.update(width=table.integer("width"), height=table.integer("height"))
    values["distortion"] = tuple(table.numbers("distortion", default=[]))
    if table.has("model"):
        values["model"] = table.string("model")
    if table.has("topic"):
        table.string("topic")  # a ROS image topic: checked here, read by camera_topics
    try:
        return TipCamera(**values, tip_T_cam=tip_T_cam)
    except ValueError as exc:
        message = str(exc)
        for name in keys:
            if message.startswith(f"TipCamera.{name}"):
                raise table.error(name, message) from None
        raise table.error("", message) from None


def robot_from_toml(data: dict[str, Any], path: str | Path = "<robot.toml>") -> Robot:
    """Build a :class:`Robot` from parsed ``robot.toml`` data (``path`` is used in messages).
    The optional ``[[markers]]`` tables are checked too (:func:`markers_from_toml`)."""
    top = TomlTable(path, "", data)
    top.check_keys(("format", "segments", "markers"), required=("format", "segments"))
    found = top.string("format")
    if found not in (ROBOT_FORMAT, ROBOT_FORMAT_MODEL_ERROR):
        raise top.error("format", f"expected {ROBOT_FORMAT!r} or {ROBOT_FORMAT_MODEL_ERROR!r} "
                        f"(with the segments' model errors), got {found!r}")
    version = 2 if found == ROBOT_FORMAT_MODEL_ERROR else 1
    segments, cameras = [], []
    for table in top.tables("segments"):
        segments.append(_segment_from(table, version))
        cameras.append(camera_from_table(table.table("camera")) if table.has("camera") else None)
    markers_from_toml(data, path)
    return Robot(segments, cameras)


def camera_topics(path: str | Path) -> dict[int, str]:
    """Segment (0-based) -> the ROS image topic its camera's table names (``topic``), for
    cameras that name one (``apcc-graph track`` and ``live`` read a bag's topics from it)."""
    data = read_toml(path)
    out = {}
    for i, table in enumerate(TomlTable(path, "", data).tables("segments")):
        if table.has("camera") and table.table("camera").has("topic"):
            out[i] = table.table("camera").string("topic")
    return out


def markers_from_toml(data: dict[str, Any], path: str | Path = "<robot.toml>"
                      ) -> dict[float, np.ndarray]:
    """The motion-capture marker offsets of parsed ``robot.toml`` data: arc length (metres) ->
    ``backbone_T_marker`` (4x4), from the optional ``[[markers]]`` tables; empty without them.

    Raises:
        ValueError: a bad or repeated arc length, or a bad pose; the message names the key.
    """
    top = TomlTable(path, "", data)
    if not top.has("markers"):
        return {}
    out: dict[float, np.ndarray] = {}
    for table in top.tables("markers"):
        table.check_keys(("arclength", "backbone_T_marker"),
                         required=("arclength", "backbone_T_marker"))
        arc = table.metres("arclength", "a marker's place along a continuum robot")
        if arc < 0.0:
            raise table.error("arclength", f"expected an arc length >= 0 (metres), got {arc!r}")
        if any(abs(arc - seen) < 1e-9 for seen in out):
            raise table.error("arclength", f"a marker at {arc!r} m is already listed")
        out[arc] = _pose_from(table.table("backbone_T_marker"))
    return out


def load_markers(path: str | Path) -> dict[float, np.ndarray]:
    """The marker offsets of ``robot.toml`` (see :func:`markers_from_toml`)."""
    return markers_from_toml(read_toml(path), path)


def load_robot(path: str | Path) -> Robot:
    """Read ``robot.toml``.

    Args:
        path: the file.

    Returns:
        The robot, angles in radians.

    Raises:
        ValueError: missing file, bad TOML, wrong format version, unknown or missing keys, bad
            values; the message names the file and the key.
    """
    return robot_from_toml(read_toml(path), path)


def _degrees(radians: float) -> float:
    """Degrees for the file, rounded to 15 significant digits so that ``60.0`` stays ``60.0``.

    15 digits survive decimal -> double -> decimal, so a file that is loaded and saved again is
    unchanged, and the radians read back differ from the original by at most ~1e-15 relative.
    """
    return float(f"{math.degrees(radians):.15g}")


def _segment_degrees(segment: Segment) -> tuple[float, float]:
    """``(delta_max_deg, theta_max_deg)`` for the file, still valid after rounding.

    Rounding each to 15 digits could make ``|delta_max_deg| == theta_max_deg`` when the two
    differ by less than 1e-15 relative; such a delta_max is moved 1e-12 (relative) inward.
    """
    delta, theta = _degrees(segment.delta_max), _degrees(segment.theta_max)
    limit = float(f"{theta * (1.0 - 1e-12):.15g}")
    if abs(delta) > limit:
        delta = math.copysign(limit, delta)
    return delta, theta


def _pose_to(pose: np.ndarray) -> dict[str, list[float]]:
    return {"translation": [float(v) for v in pose[:3, 3]],
            "quaternion_wxyz": quaternion_for_file(pose[:3, :3])}


def robot_to_toml(robot: Robot, markers: Mapping[float, np.ndarray] | None = None
                  ) -> dict[str, Any]:
    """The ``robot.toml`` document of ``robot`` as a dict (degrees for angles), with the
    marker offsets (arc length -> ``backbone_T_marker``) when given."""
    segments = []
    for seg, cam in zip(robot.segments, robot.cameras, strict=True):
        entry: dict[str, Any] = {
            "length": seg.length,
            "k": seg.k,
            "delta_max_deg": _segment_degrees(seg)[0],
            "theta_max_deg": _segment_degrees(seg)[1],
        }
        if seg.model_error is not None:
            error = seg.model_error
            entry["model_error"] = {"position_mm": float(f"{error.position * 1e3:.15g}"),
                                    "rotation_deg": _degrees(error.rotation)}
            if error.correlation_time is not None:
                entry["model_error"]["correlation_s"] = float(f"{error.correlation_time:.6g}")
            if error.correlation_bend is not None:
                entry["model_error"]["correlation_deg"] = _degrees(error.correlation_bend)
            if error.measured:
                entry["model_error"]["measured"] = error.measured
        if cam is not None:
            entry["camera"] = {
                "fx": cam.fx,
                "fy": cam.fy,
                "cx": cam.cx,
                "cy": cam.cy,
                "width": cam.width,
                "height": cam.height,
                "distortion": list(cam.distortion),
                **({} if cam.model == "pinhole" else {"model": cam.model}),
                "tip_T_cam": _pose_to(cam.tip_T_cam),
            }
        segments.append(entry)
    carries = any(seg.model_error is not None for seg in robot.segments)
    document: dict[str, Any] = {"format": ROBOT_FORMAT_MODEL_ERROR if carries else ROBOT_FORMAT,
                                "segments": segments}
    if markers:
        document["markers"] = [{"arclength": float(arc), "backbone_T_marker": _pose_to(pose)}
                               for arc, pose in sorted(markers.items())]
    return document


def save_robot(robot: Robot, path: str | Path,
               markers: Mapping[float, np.ndarray] | None = None) -> None:
    """Write ``robot`` as ``robot.toml`` atomically (temporary file, then rename).

    Args:
        robot: the robot.
        path: destination file; its folder is created if needed.
        markers: optional motion-capture marker offsets, arc length (metres) ->
            ``backbone_T_marker`` (4x4), written as ``[[markers]]`` tables.
    """
    atomic_write_bytes(path, tomli_w.dumps(robot_to_toml(robot, markers)).encode("utf-8"))
