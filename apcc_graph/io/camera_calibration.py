"""Camera calibration files of other tools, read into the intrinsics of a tip camera.

Two kinds (docs/formats.md, "Camera calibration files"):

- **OpenCV** (``cv::FileStorage``: YAML with its ``%YAML`` header, XML or JSON), as the
  ``calibrateCamera`` samples write them: ``camera_matrix`` (3x3), ``distortion_coefficients``
  (OpenCV order) and ``image_width`` / ``image_height``. Other spellings that tools use are
  accepted (``cameraMatrix``, ``K``; ``dist_coeffs``, ``distCoeffs``, ``D``; ``image_size``
  as ``[width, height]``), and an optional ``distortion_model`` names the model. Read by
  OpenCV itself.
- **Kalibr** camchain YAML: one table per camera (``cam0``, ``cam1``, ...) with
  ``camera_model`` (only ``pinhole`` maps to OpenCV), ``intrinsics`` ``[fu, fv, pu, pv]``,
  ``resolution`` ``[width, height]``, ``distortion_model`` and ``distortion_coeffs``. Read by
  PyYAML (OpenCV's YAML reader refuses Kalibr's block lists).

Distortion models map by name: Kalibr's ``radtan`` is OpenCV's ``k1, k2, p1, p2`` (the
``pinhole`` model of :class:`~apcc_graph.model.camera.TipCamera`), ``equidistant`` is OpenCV's
fisheye model (``k1..k4``, the ``fisheye`` model), ``none`` has no coefficients; any other
(Kalibr's ``fov``, the ``omni``, ``eucm`` and ``ds`` camera models) is refused by name.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from apcc_graph.io.text_files import MAX_TOML_BYTES, bom_length
from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.camera import TipCamera

MODELS = {"radtan": "pinhole", "plumb_bob": "pinhole", "pinhole": "pinhole", "opencv": "pinhole",
          "equidistant": "fisheye", "fisheye": "fisheye", "none": "pinhole"}
"""Distortion model names of Kalibr, ROS and OpenCV -> the :class:`TipCamera` model."""
_MATRIX_KEYS = ("camera_matrix", "cameraMatrix", "K", "camera_matrix_K")
_DISTORTION_KEYS = ("distortion_coefficients", "dist_coeffs", "distCoeffs", "D",
                    "distortion_coeffs")


@dataclass(frozen=True)
class CameraIntrinsics:
    """What a calibration file says of one camera (pixels; distortion in OpenCV order)."""

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    distortion: tuple[float, ...]
    model: str  # "pinhole" or "fisheye" (TipCamera.model)
    source: str  # the file, and the camera's name in it

    def camera(self, tip_T_cam: FloatArray | None = None) -> TipCamera:
        """A :class:`TipCamera` with these intrinsics, mounted by ``tip_T_cam`` (default
        identity)."""
        mount = np.eye(4) if tip_T_cam is None else tip_T_cam
        return TipCamera(self.fx, self.fy, self.cx, self.cy, self.width, self.height,
                         self.distortion, mount, self.model)


def read_camera_file(path: str | Path, camera: str | None = None) -> CameraIntrinsics:
    """The intrinsics of one camera of an OpenCV or Kalibr calibration file.

    Args:
        path: the file.
        camera: in a Kalibr camchain, which camera (``cam0``, ...); required when it holds
            more than one.

    Raises:
        ValueError: an unreadable file, a missing or bad field, an unknown camera, or a
            distortion or camera model that does not map to OpenCV's; the message names the
            file and the field.
    """
    path = Path(path)
    try:
        with path.open("rb") as fh:
            raw = fh.read(MAX_TOML_BYTES + 1)
    except OSError as exc:
        raise ValueError(f"{path}: cannot read it ({exc.strerror or exc})") from None
    if len(raw) > MAX_TOML_BYTES:
        raise ValueError(f"{path}: larger than {MAX_TOML_BYTES >> 20} MB; expected a camera "
                         "calibration file (a few KB)")
    text = raw[bom_length(raw[:4], path):].decode("utf-8", errors="replace")
    if text.lstrip().startswith(("%YAML", "<?xml", "<opencv_storage", "{")) or \
            "!!opencv-matrix" in text or path.suffix.lower() in (".xml", ".json"):
        return _opencv(path, camera)
    data = _yaml(path, text)
    cams = sorted(k for k in data if re.fullmatch(r"cam\d+", str(k)))
    if cams:
        return _kalibr(path, data, cams, camera)
    return _opencv_fields(path, data, camera)


def _yaml(path: Path, text: str) -> dict[str, Any]:
    import yaml  # PyYAML

    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ValueError(f"{path}: not a YAML file ({exc})") from None
    if not isinstance(data, dict):
        raise ValueError(f"{path}: expected a YAML mapping (an OpenCV or Kalibr calibration)")
    return data


def _kalibr(path: Path, data: dict[str, Any], cams: list[str], camera: str | None
            ) -> CameraIntrinsics:
    """One camera of a Kalibr camchain."""
    if camera is None:
        if len(cams) > 1:
            raise ValueError(f"{path}: holds cameras {', '.join(cams)}: say which (--camera)")
        camera = cams[0]
    if camera not in data:
        raise ValueError(f"{path}: no camera {camera!r} (it holds {', '.join(cams)})")
    table = data[camera]
    if not isinstance(table, dict):
        raise ValueError(f"{path}: {camera}: expected a table of the camera's fields")
    where = f"{path}: {camera}"
    kind = table.get("camera_model", "pinhole")
    if kind != "pinhole":
        raise ValueError(f"{where}.camera_model = {kind!r}: only Kalibr's pinhole camera maps "
                         "to OpenCV's models (omni, eucm and ds do not)")
    fu, fv, pu, pv = _numbers(table, "intrinsics", where, 4)
    width, height = (int(v) for v in _numbers(table, "resolution", where, 2))
    name = str(table.get("distortion_model", "none"))
    model = _model(name, f"{where}.distortion_model")
    coeffs = () if name == "none" else _numbers(table, "distortion_coeffs", where, 4)
    return _checked(where, fu, fv, pu, pv, width, height, coeffs, model)


def _opencv(path: Path, camera: str | None) -> CameraIntrinsics:
    """An OpenCV ``FileStorage`` file, read by OpenCV."""
    try:
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except cv2.error as exc:
        raise ValueError(f"{path}: OpenCV cannot read it ({exc.err})") from None
    if not fs.isOpened():
        raise ValueError(f"{path}: OpenCV cannot read it")
    root = fs.root()
    data = {key: _node_value(root.getNode(key)) for key in root.keys()}
    fs.release()
    return _opencv_fields(path, data, camera)


def _node_value(node: cv2.FileNode) -> Any:
    """A ``FileNode`` as Python: a matrix as an array, a sequence as a list, a map as a dict."""
    if node.isMap():
        if {"rows", "cols", "data"} <= set(node.keys()):
            return node.mat()
        return {key: _node_value(node.getNode(key)) for key in node.keys()}
    if node.isSeq():
        return [_node_value(node.at(i)) for i in range(node.size())]
    if node.isString():
        return node.string()
    if node.isInt():
        return int(node.real())
    return node.real()


def _opencv_fields(path: Path, data: dict[str, Any], camera: str | None) -> CameraIntrinsics:
    """The intrinsics from OpenCV's field names (``data`` read by OpenCV or PyYAML)."""
    if camera is not None:
        raise ValueError(f"{path}: an OpenCV calibration holds one camera: leave out --camera")
    where = str(path)
    matrix_key = next((k for k in _MATRIX_KEYS if k in data), None)
    if matrix_key is None:
        raise ValueError(f"{where}: no camera matrix: expected one of {', '.join(_MATRIX_KEYS)} "
                         "(an OpenCV calibration) or cam0, cam1, ... (a Kalibr camchain)")
    K = _matrix(data[matrix_key], f"{where}: {matrix_key}")
    if K.shape != (3, 3):
        raise ValueError(f"{where}: {matrix_key}: expected a 3x3 camera matrix, got shape "
                         f"{K.shape}")
    dist_key = next((k for k in _DISTORTION_KEYS if k in data), None)
    coeffs = () if dist_key is None else tuple(
        float(v) for v in np.asarray(_matrix(data[dist_key], f"{where}: {dist_key}")).ravel())
    if "image_width" in data and "image_height" in data:
        width, height = int(data["image_width"]), int(data["image_height"])
    elif "image_size" in data or "imageSize" in data:
        key = "image_size" if "image_size" in data else "imageSize"
        size = np.asarray(_matrix(data[key], f"{where}: {key}")).ravel()
        if len(size) != 2:
            raise ValueError(f"{where}: {key}: expected [width, height]")
        width, height = int(size[0]), int(size[1])
    else:
        raise ValueError(f"{where}: no image size: expected image_width and image_height "
                         "(or image_size = [width, height])")
    model = _model(str(data.get("distortion_model", "opencv")), f"{where}: distortion_model")
    return _checked(where, K[0, 0], K[1, 1], K[0, 2], K[1, 2], width, height, coeffs, model)


def _matrix(value: Any, where: str) -> FloatArray:
    """A matrix given as an array, a nested list or OpenCV's ``{rows, cols, data}``."""
    if isinstance(value, dict) and {"rows", "cols", "data"} <= set(value):
        value = np.reshape(np.asarray(value["data"], dtype=float),
                           (int(value["rows"]), int(value["cols"])))
    try:
        out = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{where}: expected numbers, got {value!r}") from None
    return out


def _numbers(table: dict[str, Any], key: str, where: str, length: int) -> tuple[float, ...]:
    """``length`` numbers of ``table[key]``."""
    if key not in table:
        raise ValueError(f"{where}.{key}: missing")
    value = table[key]
    if not isinstance(value, list) or len(value) != length or not all(
            isinstance(v, (int, float)) and not isinstance(v, bool) for v in value):
        raise ValueError(f"{where}.{key} = {value!r}: expected {length} numbers")
    return tuple(float(v) for v in value)


def _model(name: str, where: str) -> str:
    """The :class:`TipCamera` model of a distortion model's name."""
    if name not in MODELS:
        raise ValueError(f"{where} = {name!r}: expected radtan (OpenCV k1, k2, p1, p2), "
                         "equidistant (OpenCV's fisheye k1..k4) or none; other models do not "
                         "map to OpenCV's")
    return MODELS[name]


def _checked(where: str, fx: float, fy: float, cx: float, cy: float, width: int, height: int,
             coeffs: tuple[float, ...], model: str) -> CameraIntrinsics:
    """The intrinsics, checked as a :class:`TipCamera` checks them (the message names the
    file)."""
    found = CameraIntrinsics(float(fx), float(fy), float(cx), float(cy), width, height,
                             tuple(coeffs), model, where)
    try:
        found.camera()
    except ValueError as exc:
        raise ValueError(f"{where}: {exc}") from None
    return found
