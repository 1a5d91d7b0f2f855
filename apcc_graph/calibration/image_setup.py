"""The setup of a calibration-images folder (format ``apcc-graph/calibration-images@1``,
docs/formats.md): the marker layout, the side camera, ``calibration.toml`` and the images.

A folder holds ``calibration.toml`` and the images, every ``*.png`` in the folder, taken in name
order (8-bit grey or colour, read as grey; each ``width`` x ``height`` of the camera)::

    format = "apcc-graph/calibration-images@1"
    length = 0.4                 # segment length, metres
    theta_max_deg = 80.0         # optional: the segment's bending limit

    [markers]
    dictionary = "DICT_4X4_50"   # an OpenCV predefined ArUco dictionary (cv2.aruco.DICT_*)
    side = 0.05                  # side of the black square, metres
    [markers.base]
    id = 0
    offset = 0.04                # centre below the base, on the base axis, metres
    [markers.tip]
    id = 1
    offset = 0.04                # centre beyond the tip, on the tip tangent, metres

    [camera]                     # the side camera's intrinsics (pixels)
    fx = 600.0
    fy = 600.0
    cx = 319.5
    cy = 239.5
    width = 640
    height = 480
    distortion = []              # OpenCV order: k1, k2, p1, p2[, k3, ...]

The marker frames and the mounting the offsets refer to are described in
:mod:`~apcc_graph.calibration.marker_geometry`. The ``[camera]`` table is read by
:func:`~apcc_graph.io.robot_file.camera_from_table` (as in ``robot.toml``, without a mounting).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from apcc_graph.calibration.files import segment_fields
from apcc_graph.io.robot_file import camera_from_table
from apcc_graph.io.toml_fields import TomlTable, read_toml
from apcc_graph.model.camera import TipCamera

CALIBRATION_IMAGES_FORMAT = "apcc-graph/calibration-images@1"
SETUP_FILE = "calibration.toml"
"""The name of the setup file inside a calibration-images folder."""

IMAGE_PATTERN = "*.png"


@dataclass(frozen=True)
class MarkerLayout:
    """The ArUco markers on the base and the tip (metres; the mounting is described in
    :mod:`~apcc_graph.calibration.marker_geometry`).

    Args:
        side: side length of each marker's black square, metres, > 0.
        base_offset: distance from the base down to the base marker's centre, metres, >= 0.
        tip_offset: distance from the tip out to the tip marker's centre, metres, >= 0.
        dictionary: name of an OpenCV predefined dictionary, e.g. ``"DICT_4X4_50"``.
        base_id: the base marker's id in the dictionary.
        tip_id: the tip marker's id, different from ``base_id``.

    Raises:
        ValueError: an unknown dictionary, an id outside it, equal ids, or a length out of range;
            the message names the field.
    """

    side: float
    base_offset: float
    tip_offset: float
    dictionary: str = "DICT_4X4_50"
    base_id: int = 0
    tip_id: int = 1

    def __post_init__(self) -> None:
        for name in ("side", "base_offset", "tip_offset"):
            value = float(getattr(self, name))
            if not math.isfinite(value) or value < 0.0 or (name == "side" and value == 0.0):
                want = "> 0" if name == "side" else ">= 0"
                raise ValueError(f"MarkerLayout.{name} = {value!r}: expected a length {want} "
                                 "(metres)")
            object.__setattr__(self, name, value)
        size = dictionary_size(self.dictionary)
        for name in ("base_id", "tip_id"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not (
                0 <= value < size
            ):
                raise ValueError(f"MarkerLayout.{name} = {value!r}: expected an id 0..{size - 1} "
                                 f"of {self.dictionary}")
            object.__setattr__(self, name, int(value))
        if self.base_id == self.tip_id:
            raise ValueError(f"MarkerLayout: base_id and tip_id are both {self.base_id}: "
                             "expected two different marker ids")

    @property
    def aruco_dictionary(self) -> cv2.aruco.Dictionary:
        """The OpenCV dictionary object."""
        return cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))

    @classmethod
    def for_length(cls, length: float) -> MarkerLayout:
        """Markers scaled to a segment of ``length`` metres: side ``L/8``, offsets ``L/10``."""
        return cls(side=length / 8.0, base_offset=length / 10.0, tip_offset=length / 10.0)


def dictionary_size(name: str) -> int:
    """Number of markers in the OpenCV predefined ArUco dictionary ``name``.

    Raises:
        ValueError: ``name`` is not one of OpenCV's ``cv2.aruco.DICT_*`` names.
    """
    if not isinstance(name, str) or not name.startswith("DICT_") or not hasattr(cv2.aruco, name):
        known = sorted(n for n in dir(cv2.aruco) if n.startswith("DICT_"))
        raise ValueError(f"MarkerLayout.dictionary = {name!r}: expected an OpenCV ArUco "
                         f"dictionary name, one of {', '.join(known)}")
    dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, name))
    return int(dictionary.bytesList.shape[0])


@dataclass(frozen=True)
class CalibrationImagesSetup:
    """The contents of ``calibration.toml``: segment, markers and side camera.

    Attributes:
        length: segment length L, metres.
        theta_max: the segment's bending limit (radians) or ``None`` (see
            :func:`~apcc_graph.calibration.files.calibrate_measurements`).
        markers: the marker layout.
        camera: the side camera's intrinsics (its ``tip_T_cam`` is unused).
    """

    length: float
    theta_max: float | None
    markers: MarkerLayout
    camera: TipCamera


def _wrapped(table: TomlTable, owner: str, keys: dict[str, str], exc: ValueError) -> ValueError:
    """A model validation error re-raised naming the file and the key it is about."""
    message = str(exc)
    for field, key in keys.items():
        if message.startswith(f"{owner}.{field} "):
            return table.error(key, message)
    return table.error("", message)


def _markers_from(table: TomlTable) -> MarkerLayout:
    table.check_keys(("dictionary", "side", "base", "tip"),
                     required=("dictionary", "side", "base", "tip"))
    values: dict[str, object] = {"dictionary": table.string("dictionary"),
                                 "side": table.number("side")}
    keys = {"dictionary": "dictionary", "side": "side"}
    for which in ("base", "tip"):
        sub = table.table(which)
        sub.check_keys(("id", "offset"), required=("id", "offset"))
        values[f"{which}_id"] = sub.integer("id")
        values[f"{which}_offset"] = sub.number("offset")
        keys[f"{which}_id"] = f"{which}.id"
        keys[f"{which}_offset"] = f"{which}.offset"
    if values["base_id"] == values["tip_id"]:
        raise table.error("tip.id", f"duplicate marker id {values['tip_id']}: the base and the "
                          "tip marker need different ids")
    try:
        return MarkerLayout(**values)  # type: ignore[arg-type]
    except ValueError as exc:
        raise _wrapped(table, "MarkerLayout", keys, exc) from None


def load_setup(folder: str | Path) -> CalibrationImagesSetup:
    """Read ``calibration.toml`` of a calibration-images folder.

    Args:
        folder: the folder.

    Returns:
        The setup (radians in memory).

    Raises:
        ValueError: the folder or its ``calibration.toml`` is missing, not valid TOML, of another
            format, or has a missing, unknown or bad key; the message names the file and the key.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise ValueError(f"{folder}: no such folder (expected a folder of calibration images "
                         f"with {SETUP_FILE})")
    path = folder / SETUP_FILE
    if not path.is_file():
        raise ValueError(f"{path}: missing; a calibration-images folder needs {SETUP_FILE} "
                         f"(format = {CALIBRATION_IMAGES_FORMAT!r}) beside its images")
    top = TomlTable(path, "", read_toml(path))
    top.check_keys(("format", "length", "theta_max_deg", "markers", "camera"),
                   required=("format", "length", "markers", "camera"))
    top.check_format(CALIBRATION_IMAGES_FORMAT)
    length, theta_max = segment_fields(top)
    return CalibrationImagesSetup(length=length, theta_max=theta_max,
                                  markers=_markers_from(top.table("markers")),
                                  camera=camera_from_table(top.table("camera"), mounting=False))


def setup_to_toml(setup: CalibrationImagesSetup, comment: str = "") -> str:
    """The text of ``calibration.toml`` for ``setup``, with ``comment`` lines on top.

    Floats are written with ``repr`` so that :func:`load_setup` reads back the same values.
    """
    m, c = setup.markers, setup.camera
    lines = [f"# {line}" if line else "#" for line in comment.splitlines()]
    lines += [f'format = "{CALIBRATION_IMAGES_FORMAT}"',
              f"length = {setup.length!r}  # segment length, metres"]
    if setup.theta_max is not None:
        lines.append(f"theta_max_deg = {math.degrees(setup.theta_max)!r}")
    lines += ["", "[markers]",
              f'dictionary = "{m.dictionary}"',
              f"side = {m.side!r}  # black square, metres",
              "[markers.base]", f"id = {m.base_id}",
              f"offset = {m.base_offset!r}  # centre below the base on the base axis, metres",
              "[markers.tip]", f"id = {m.tip_id}",
              f"offset = {m.tip_offset!r}  # centre beyond the tip on the tip tangent, metres",
              "", "[camera]  # side camera, pixels"]
    lines += [f"{name} = {float(getattr(c, name))!r}" for name in ("fx", "fy", "cx", "cy")]
    lines += [f"width = {c.width}", f"height = {c.height}",
              "distortion = [" + ", ".join(repr(float(d)) for d in c.distortion) + "]"]
    return "\n".join(lines) + "\n"


def image_files(folder: str | Path) -> list[Path]:
    """The calibration images of a folder: its ``*.png`` files in name order."""
    return sorted(p for p in Path(folder).glob(IMAGE_PATTERN) if p.is_file())
