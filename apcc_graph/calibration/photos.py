"""Calibration of one segment from photos with ArUco markers (paper III.C "visual sampling").

The paper photographs the segment with a camera parallel to its bending plane and reads the chord
angle, the tip tangent angle and the point P off the photo. Here two ArUco markers make the same
measurement automatic: one on the base, one on the tip. Each image gives one tip pose ``(x, z)``
and tip angle ``theta_hat``, exactly the inputs of
:func:`~apcc_graph.calibration.fit.calibrate_from_tip` (one image) and
:func:`~apcc_graph.calibration.fit.fit_segment` (a sweep); :func:`calibrate_images` runs both through
:func:`~apcc_graph.calibration.files.calibrate_measurements`.

Conventions
-----------
- Units: metres, radians in code (``_deg`` keys in files), pixels for images; OpenCV pixel
  coordinates (pixel centres at integers), OpenCV distortion order ``k1, k2, p1, p2[, k3, ...]``.
- Base frame (docs/estimation.md, "Conventions"): origin at the base, +z the base axis, the
  bending plane is its x-z plane and a bend ``theta > 0`` moves the tip toward +x. A tip pose is
  ``(x, z)`` and the tip tangent angle from +z toward +x.
- Marker frame (OpenCV ArUco): origin at the centre of the black square, +x to the marker's right,
  +y up, +z out of the printed face; corners in detection order top-left, top-right,
  bottom-right, bottom-left, i.e. ``(-s/2, s/2), (s/2, s/2), (s/2, -s/2), (-s/2, -s/2)`` for the
  side length ``s`` of the black square (the white quiet zone around it is not counted).
- Mounting (both markers flat in the bending plane, printed face toward the side camera):
  the base marker's centre lies on the base axis ``base_offset`` below the base, at
  ``(0, -base_offset)``, with its +y along +z; the tip marker's centre lies on the tip tangent
  ``tip_offset`` beyond the tip, at ``tip + tip_offset (sin theta_hat, cos theta_hat)``, with its
  +y along the tip tangent. The markers therefore fix the base frame: base +x is the base
  marker's +x (to the right in the image when the base marker stands upright), so a bend toward
  the right of the upright base marker is positive whichever side the camera is on.
- Camera frame (OpenCV): +z along the optical axis, +x right in the image, +y down. The camera's
  pose is written ``base_T_cam`` / ``cam_T_base``.

Folder format (``format = "apcc-graph/calibration-images@1"``)
-------------------------------------------------------------
A folder holds ``calibration.toml`` and the images, every ``*.png`` in the folder, taken in name
order (8-bit grey or colour, read as grey; each ``width`` x ``height`` of the camera)::

    format = "apcc-graph/calibration-images@1"
    length = 0.4                 # segment length, metres
    theta_max_deg = 80.0         # optional: the segment's bending limit (see calibration_file)

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

Measurement (and why this one)
------------------------------
1. Detection: :class:`cv2.aruco.ArucoDetector` with sub-pixel corner refinement
   (``CORNER_REFINE_SUBPIX``, iterated to 0.01 px).
2. Corner alignment (:func:`refine_corners`): each marker's known pattern is aligned to the image
   by ``cv2.findTransformECC`` (a homography, started from the detector's corners), so that every
   edge of every bit takes part. ``cornerSubPix`` on the L-shaped corner of a 40 px marker puts
   the corners 0.15-0.2 px inside the square; every distance in the plane then comes out about
   1 % too long (3.5 mm at the tip), and k, which moves by about -2.6 times the relative scale
   error at 80 deg, comes out 0.03 low (0.179 instead of 0.21 on the shipped sweep; 0.208 with
   the alignment). Aligned corners are within ~0.01-0.03 px.
3. Tip pose (:func:`fit_marker_corners`): one plane pose ``cam_T_base`` (6 unknowns) and the tip
   pose ``(x, z, theta_hat)`` in that plane (3 unknowns) minimise the reprojection error of all
   8 corners (``scipy.optimize.least_squares``, started from
   ``cv2.solvePnPGeneric(SOLVEPNP_IPPE_SQUARE)`` on the base marker, both of its solutions tried,
   and the tip marker's corner rays intersected with that plane). It is the maximum-likelihood
   estimate under corner noise with the coplanarity that the mounting guarantees, and it takes
   the scale from both squares. Intersecting the tip marker's rays with the base marker's plane
   takes the scale from the base marker alone; two independent ``solvePnP`` poses are not
   coplanar and each carries its own depth error.
4. Images from a camera with distortion are first remapped to the pinhole camera with the same
   intrinsics (a marker is a homography of its pattern only there).

Measured on images rendered by :mod:`apcc_graph.simulation.calibration_photos` with the shipped setup
(640 x 480, f = 600 px, 40 px markers, 1 grey level of noise; 42 images, bends -80..80 deg), RMS
tip position / tip angle error:

=====================  =====================  =====================
tip from               ArUco corners alone    aligned corners
=====================  =====================  =====================
joint fit (used)       3.5 mm / 0.25 deg      0.18 mm / 0.019 deg
rays on base plane     12.2 mm / 0.28 deg     0.52 mm / 0.020 deg
two IPPE poses         3.9 mm / 0.28 deg      0.21 mm / 0.019 deg
=====================  =====================  =====================

With the camera tilted 2 deg the aligned rows read 0.16, 0.29 and 0.14 mm: the alignment is what
matters; the joint fit is never far from the best and keeps the model's coplanarity. What remains
is mostly a common scale bias of about +0.05 % (0.15 mm at the tip): k comes out about 0.0015 low
(see data/calibration/README.md for the recovery figures).

Synthetic images of this format, rendered from the APCC model, come from
:mod:`apcc_graph.simulation.calibration_photos`.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import scipy.optimize
from numpy.typing import ArrayLike, NDArray

from apcc_graph.calibration.files import (
    CalibrationReport,
    TipMeasurements,
    calibrate_measurements,
    segment_fields,
)
from apcc_graph.calibration.fit import REACH_SLACK
from apcc_graph.io.toml_fields import TomlTable, read_toml
from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.camera import TipCamera

CALIBRATION_IMAGES_FORMAT = "apcc-graph/calibration-images@1"
SETUP_FILE = "calibration.toml"
"""The name of the setup file inside a calibration-images folder."""

IMAGE_PATTERN = "*.png"

MARKER_FACING_BASE = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
"""Rotation ``base_R_marker`` of the base marker: marker +x = base +x, marker +y = base +z and
marker +z (its printed face) = base -y, toward a camera on the -y side."""


# ------------------------------------------------------------------------------------- setup
@dataclass(frozen=True)
class MarkerLayout:
    """The ArUco markers on the base and the tip (metres; see the module docstring).

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


_CAMERA_KEYS = ("fx", "fy", "cx", "cy", "width", "height", "distortion")


def _camera_from(table: TomlTable) -> TipCamera:
    table.check_keys(_CAMERA_KEYS, required=_CAMERA_KEYS[:6])
    values: dict[str, object] = {name: table.number(name) for name in ("fx", "fy", "cx", "cy")}
    values.update(width=table.integer("width"), height=table.integer("height"),
                  distortion=tuple(table.numbers("distortion", default=[])))
    try:
        return TipCamera(**values)  # type: ignore[arg-type]
    except ValueError as exc:
        raise _wrapped(table, "TipCamera", {k: k for k in _CAMERA_KEYS}, exc) from None


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
                                  camera=_camera_from(top.table("camera")))


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


# ---------------------------------------------------------------------------------- geometry
@dataclass(frozen=True)
class TipPose:
    """A tip pose in the bending plane, base at the origin (metres, radians).

    Attributes:
        x: across the base axis.
        z: along the base axis.
        angle: tip tangent angle ``theta_hat`` from the base axis (toward +x positive).
    """

    x: float
    z: float
    angle: float

    @property
    def chord_angle(self) -> float:
        """Angle of the chord base -> tip from the base axis (the paper's x), ``theta / 2``."""
        return math.atan2(self.x, self.z)

    def op_distance(self, length: float) -> float:
        """``|OP|``: where the ellipse with foci base and tip and major axis L meets the axis.

        ``|OP| = (L^2 - x^2 - z^2) / (2 (L - z))`` (docs/estimation.md, "Calibrating a segment");
        ``k = |OP| / L`` for a single pose. ``nan`` when the tip is on the axis at ``z >= L``.
        """
        if self.z >= length:
            return math.nan
        return (length**2 - self.x**2 - self.z**2) / (2.0 * (length - self.z))


def rotation_y(angle: float) -> FloatArray:
    """``Ry(angle)``: turns +z toward +x (a positive bend, docs/estimation.md, "Conventions")."""
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def pose_matrix(rotation: FloatArray, translation: ArrayLike) -> FloatArray:
    """The 4x4 homogeneous transform with ``rotation`` (3x3) and ``translation`` (3,)."""
    out = np.eye(4)
    out[:3, :3] = rotation
    out[:3, 3] = translation
    return out


def base_T_base_marker(offset: float) -> FloatArray:
    """Pose of the base marker in the base frame: centre ``(0, 0, -offset)``, +y along +z."""
    return pose_matrix(MARKER_FACING_BASE, [0.0, 0.0, -offset])


def base_T_tip_marker(tip: TipPose, offset: float) -> FloatArray:
    """Pose of the tip marker in the base frame: ``offset`` beyond the tip on its tangent."""
    s, c = math.sin(tip.angle), math.cos(tip.angle)
    return pose_matrix(rotation_y(tip.angle) @ MARKER_FACING_BASE,
                       [tip.x + offset * s, 0.0, tip.z + offset * c])


def marker_corners(side: float) -> FloatArray:
    """``(4, 3)`` corners of a marker in its own frame, in ArUco order (TL, TR, BR, BL)."""
    h = 0.5 * side
    return np.array([[-h, h, 0.0], [h, h, 0.0], [h, -h, 0.0], [-h, -h, 0.0]])


def tip_from_marker_poses(
    cam_T_base_marker: ArrayLike,
    cam_T_tip_marker: ArrayLike,
    base_offset: float,
    tip_offset: float,
) -> TipPose:
    """The tip pose in the bending plane from the two marker poses (any common frame).

    The base frame follows from the base marker (:func:`base_T_base_marker`); the tip marker's
    +y in that frame gives the tip angle, and its centre minus ``tip_offset`` along that
    direction the tip. Components out of the bending plane (which a perfect mounting does not
    have) are dropped.

    Args:
        cam_T_base_marker: 4x4 pose of the base marker.
        cam_T_tip_marker: 4x4 pose of the tip marker, in the same frame.
        base_offset: base marker centre below the base, metres.
        tip_offset: tip marker centre beyond the tip, metres.

    Returns:
        The tip ``(x, z, angle)``.
    """
    cam_T_bm = np.asarray(cam_T_base_marker, dtype=float)
    cam_T_tm = np.asarray(cam_T_tip_marker, dtype=float)
    base_T_tm = base_T_base_marker(base_offset) @ np.linalg.solve(cam_T_bm, cam_T_tm)
    up = base_T_tm[:3, 1]
    angle = math.atan2(up[0], up[2])
    centre = base_T_tm[:3, 3]
    return TipPose(x=float(centre[0] - tip_offset * math.sin(angle)),
                   z=float(centre[2] - tip_offset * math.cos(angle)), angle=angle)


@dataclass(frozen=True)
class CornerFit:
    """Result of :func:`fit_marker_corners`.

    Attributes:
        tip: the tip pose in the bending plane.
        cam_T_base: 4x4 pose of the base frame in the camera frame.
        rms_px: RMS distance between the 8 detected and the fitted corners, pixels.
    """

    tip: TipPose
    cam_T_base: FloatArray
    rms_px: float


def _corner_points(params: FloatArray, markers: MarkerLayout) -> FloatArray:
    """The 8 marker corners in the camera frame for ``(rvec, tvec, x, z, angle)``."""
    rotation = cv2.Rodrigues(params[:3])[0]
    cam_T_base = pose_matrix(rotation, params[3:6])
    tip = TipPose(float(params[6]), float(params[7]), float(params[8]))
    corners = marker_corners(markers.side)
    out = []
    for base_T_m in (base_T_base_marker(markers.base_offset),
                     base_T_tip_marker(tip, markers.tip_offset)):
        cam_T_m = cam_T_base @ base_T_m
        out.append(corners @ cam_T_m[:3, :3].T + cam_T_m[:3, 3])
    return np.concatenate(out)


def _tip_on_plane(cam_T_base: FloatArray, tip_px: FloatArray, camera: TipCamera,
                  markers: MarkerLayout) -> TipPose:
    """The tip from the tip marker's corner rays intersected with the base frame's x-z plane."""
    rays = camera.bearings(tip_px)
    normal, origin = cam_T_base[:3, 1], cam_T_base[:3, 3]
    depth = (normal @ origin) / (rays @ normal)
    in_base = (rays * depth[:, None] - origin) @ cam_T_base[:3, :3]
    seen = in_base[:, 0] + 1j * in_base[:, 2]
    template = marker_corners(markers.side)
    model = template[:, 0] + 1j * template[:, 1]
    # Marker point (u, v) lands at centre + (u + i v) exp(-i angle) in the (x + i z) plane.
    turn = np.vdot(model, seen - seen.mean())
    angle = -float(np.angle(turn))
    centre = seen.mean()
    return TipPose(x=float(centre.real - markers.tip_offset * math.sin(angle)),
                   z=float(centre.imag - markers.tip_offset * math.cos(angle)), angle=angle)


def fit_marker_corners(
    base_corners: ArrayLike,
    tip_corners: ArrayLike,
    camera: TipCamera,
    markers: MarkerLayout,
) -> CornerFit:
    """Tip pose from the detected corners of both markers (joint fit, see module docstring).

    Args:
        base_corners: ``(4, 2)`` pixels of the base marker's corners in ArUco order.
        tip_corners: ``(4, 2)`` pixels of the tip marker's corners in ArUco order.
        camera: the side camera (intrinsics and distortion).
        markers: the marker layout.

    Returns:
        The tip, the base frame's pose in the camera and the corner RMS in pixels.

    Raises:
        ValueError: OpenCV finds no pose for the base marker (degenerate corners).
    """
    base_px = np.asarray(base_corners, dtype=float).reshape(4, 2)
    tip_px = np.asarray(tip_corners, dtype=float).reshape(4, 2)
    observed = np.concatenate([base_px, tip_px])
    count, rvecs, tvecs, _ = cv2.solvePnPGeneric(
        marker_corners(markers.side), base_px.reshape(4, 1, 2), camera.intrinsic_matrix,
        camera.distortion_coefficients, flags=cv2.SOLVEPNP_IPPE_SQUARE)
    if not count:
        raise ValueError("no pose of the base marker fits its corners")

    def residuals(params: FloatArray) -> FloatArray:
        return (camera.project(_corner_points(params, markers)) - observed).ravel()

    best = None
    marker_T_base = np.linalg.inv(base_T_base_marker(markers.base_offset))
    for rvec, tvec in zip(rvecs, tvecs, strict=True):
        cam_T_base = pose_matrix(cv2.Rodrigues(rvec)[0], tvec.ravel()) @ marker_T_base
        tip = _tip_on_plane(cam_T_base, tip_px, camera, markers)
        x0 = np.concatenate([cv2.Rodrigues(cam_T_base[:3, :3])[0].ravel(), cam_T_base[:3, 3],
                             [tip.x, tip.z, tip.angle]])
        if not np.all(np.isfinite(x0)):
            continue  # IPPE's second solution is NaN when the marker is seen exactly square-on
        res = scipy.optimize.least_squares(residuals, x0, method="lm", x_scale="jac",
                                           xtol=1e-12, ftol=1e-12, gtol=1e-12)
        if best is None or res.cost < best.cost:
            best = res
    if best is None:
        raise ValueError("no pose of the base marker fits its corners")
    p = best.x
    angle = math.remainder(float(p[8]), 2.0 * math.pi)
    return CornerFit(tip=TipPose(float(p[6]), float(p[7]), angle),
                     cam_T_base=pose_matrix(cv2.Rodrigues(p[:3])[0], p[3:6]),
                     rms_px=float(np.sqrt(2.0 * best.cost / len(observed))))


# --------------------------------------------------------------------------------- detection
def marker_detector(markers: MarkerLayout) -> cv2.aruco.ArucoDetector:
    """An ArUco detector for the layout's dictionary with sub-pixel corner refinement.

    OpenCV's default window (at most 5 px, at most 0.3 of a marker cell), iterated to 0.01 px
    instead of 0.1 px. Its corners are the start of :func:`refine_corners`.
    """
    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    params.cornerRefinementMaxIterations = 100
    params.cornerRefinementMinAccuracy = 0.01
    return cv2.aruco.ArucoDetector(markers.aruco_dictionary, params)


def _marker_template(markers: MarkerLayout, marker_id: int, cell: int = 12
                     ) -> tuple[NDArray[np.float32], FloatArray]:
    """The marker image with half a cell of its white quiet zone, and its 4 corners (pixels).

    Only half the quiet zone: its outer edge meets an unknown background, which would pull the
    alignment (measured: corners 0.12 px inward with the whole quiet zone, 0.01 px with half).
    """
    cells = markers.aruco_dictionary.markerSize + 2
    image = cv2.aruco.generateImageMarker(markers.aruco_dictionary, marker_id, cells * cell,
                                          borderBits=1)
    pad = cell // 2
    image = cv2.copyMakeBorder(image, pad, pad, pad, pad, cv2.BORDER_CONSTANT, value=255)
    low, high = pad - 0.5, pad + cells * cell - 0.5  # pixel centres at integers
    corners = np.array([[low, low], [high, low], [high, high], [low, high]])
    return image.astype(np.float32), corners


ECC_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-8)


def refine_corners(gray: NDArray[np.uint8], corners: ArrayLike, markers: MarkerLayout,
                   marker_id: int) -> FloatArray | None:
    """Corners of one marker aligned to the image by ``cv2.findTransformECC`` (homography).

    The marker's known pattern is aligned to the image, starting from the detector's corners:
    every edge of every bit takes part, not only the corner's neighbourhood, and there is no
    smoothing (``gaussFiltSize = 1``) that would move the outer edges.

    Args:
        gray: the 8-bit grey image.
        corners: ``(4, 2)`` corners from the detector, ArUco order.
        markers: the layout (dictionary).
        marker_id: the marker's id.

    Returns:
        ``(4, 2)`` refined corners, or ``None`` if the alignment does not converge.
    """
    template, model = _marker_template(markers, marker_id)
    start = cv2.getPerspectiveTransform(model.astype(np.float32),
                                        np.asarray(corners, np.float32).reshape(4, 2))
    try:
        _, warp = cv2.findTransformECC(template, gray.astype(np.float32),
                                       start.astype(np.float32), cv2.MOTION_HOMOGRAPHY,
                                       ECC_CRITERIA, None, 1)
    except cv2.error:
        return None
    out = cv2.perspectiveTransform(model.reshape(-1, 1, 2), warp.astype(np.float64))
    out = out.reshape(4, 2)
    if not np.all(np.isfinite(out)) or np.max(np.abs(out - np.asarray(corners))) > 2.0:
        return None
    return out


def detect_markers(gray: NDArray[np.uint8], detector: cv2.aruco.ArucoDetector
                   ) -> dict[int, list[FloatArray]]:
    """All markers found in an 8-bit grey image: id -> list of ``(4, 2)`` corner arrays."""
    corners, ids, _ = detector.detectMarkers(gray)
    found: dict[int, list[FloatArray]] = {}
    if ids is not None:
        for marker_id, quad in zip(ids.ravel(), corners, strict=True):
            found.setdefault(int(marker_id), []).append(np.asarray(quad, float).reshape(4, 2))
    return found


@dataclass(frozen=True)
class ImageMeasurement:
    """The tip pose measured in one image.

    Attributes:
        name: the image (file name or a label), for messages and reports.
        tip: tip ``(x, z, angle)`` in the bending plane.
        rms_px: RMS corner reprojection error of the joint fit, pixels.
        cam_T_base: 4x4 pose of the base frame in the camera frame.
        aligned: how many of the two markers' corners :func:`refine_corners` refined (the
            others keep the detector's sub-pixel corners).
    """

    name: str
    tip: TipPose
    rms_px: float
    cam_T_base: FloatArray
    aligned: int = 2


def _read_gray(path: Path) -> NDArray[np.uint8]:
    try:
        data = np.fromfile(path, dtype=np.uint8)
    except OSError as exc:
        raise ValueError(f"{path}: cannot read: {exc.strerror or exc}") from None
    image = cv2.imdecode(data, cv2.IMREAD_GRAYSCALE) if data.size else None
    if image is None:
        raise ValueError(f"{path}: not a readable image (expected an 8-bit PNG)")
    return image


@functools.lru_cache(maxsize=4)
def _undistortion_maps(camera: TipCamera) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    return cv2.initUndistortRectifyMap(camera.intrinsic_matrix, camera.distortion_coefficients,
                                       None, camera.intrinsic_matrix,
                                       (camera.width, camera.height), cv2.CV_32FC1)


def _undistorted(image: NDArray[np.uint8], camera: TipCamera
                 ) -> tuple[NDArray[np.uint8], TipCamera]:
    """The image as a pinhole camera with the same intrinsics and no distortion sees it.

    A marker is a homography of its pattern only in a pinhole image; aligning it in the
    distorted image bends its corners (measured: 0.15 deg of tip angle near the border with
    k1 = -0.08).
    """
    map_x, map_y = _undistortion_maps(camera)
    pinhole = TipCamera(camera.fx, camera.fy, camera.cx, camera.cy, camera.width, camera.height)
    return cv2.remap(image, map_x, map_y, cv2.INTER_LINEAR), pinhole


def measure_image(
    image: NDArray[np.uint8],
    setup: CalibrationImagesSetup,
    name: str = "image",
    detector: cv2.aruco.ArucoDetector | None = None,
    refine: bool = True,
) -> ImageMeasurement:
    """Detect the two markers in one 8-bit grey image and measure the tip.

    Args:
        image: ``(height, width)`` uint8 image of the side camera.
        setup: the folder's setup.
        name: the image's name for messages.
        detector: a detector from :func:`marker_detector` (made if not given).
        refine: align each marker's pattern to the image (:func:`refine_corners`); ``False``
            keeps the detector's corners.

    Returns:
        The measurement.

    Raises:
        ValueError: the image has the wrong size or layout, a marker is missing or seen twice, or
            the tip lies beyond the segment's reach; the message names the image and the marker.
    """
    cam, markers = setup.camera, setup.markers
    if image.ndim != 2 or image.dtype != np.uint8:
        raise ValueError(f"{name}: expected an 8-bit grey image, got {image.dtype} of shape "
                         f"{image.shape}")
    if image.shape != (cam.height, cam.width):
        raise ValueError(f"{name}: image is {image.shape[1]}x{image.shape[0]} pixels, expected "
                         f"{cam.width}x{cam.height} (camera width x height in {SETUP_FILE})")
    if cam.distortion:
        image, cam = _undistorted(image, cam)
    found = detect_markers(image, detector or marker_detector(markers))
    quads, aligned = {}, 0
    for role, marker_id in (("base", markers.base_id), ("tip", markers.tip_id)):
        seen = found.get(marker_id, [])
        if not seen:
            others = sorted(found)
            raise ValueError(f"{name}: {role} marker id {marker_id} ({markers.dictionary}) not "
                             f"found; ids found: {others if others else 'none'}")
        if len(seen) > 1:
            raise ValueError(f"{name}: {role} marker id {marker_id} found {len(seen)} times: "
                             "expected one marker with each id")
        refined = refine_corners(image, seen[0], markers, marker_id) if refine else None
        quads[role] = seen[0] if refined is None else refined
        aligned += refined is not None
    fit = fit_marker_corners(quads["base"], quads["tip"], cam, markers)
    reach = math.hypot(fit.tip.x, fit.tip.z)
    if reach > (1.0 + REACH_SLACK) * setup.length:
        raise ValueError(f"{name}: the tip is {reach:.4f} m from the base, beyond the reach of a "
                         f"segment of length {setup.length:g} m; check length, markers.side "
                         f"and the marker offsets in {SETUP_FILE}")
    return ImageMeasurement(name=name, tip=fit.tip, rms_px=fit.rms_px, cam_T_base=fit.cam_T_base,
                            aligned=aligned)


def image_files(folder: str | Path) -> list[Path]:
    """The calibration images of a folder: its ``*.png`` files in name order."""
    return sorted(p for p in Path(folder).glob(IMAGE_PATTERN) if p.is_file())


def measure_folder(folder: str | Path
                   ) -> tuple[CalibrationImagesSetup, list[ImageMeasurement]]:
    """Read ``calibration.toml`` and measure the tip in every image of a folder.

    Raises:
        ValueError: a bad setup file, no images, an unreadable image or one of the wrong size,
            a marker missing or seen twice, a tip beyond reach; the message names the file.
    """
    folder = Path(folder)
    setup = load_setup(folder)
    files = image_files(folder)
    if not files:
        raise ValueError(f"{folder}: no calibration images (expected {IMAGE_PATTERN} files "
                         f"beside {SETUP_FILE})")
    detector = marker_detector(setup.markers)
    out = [measure_image(_read_gray(path), setup, str(path), detector) for path in files]
    if len(out) == 1 and math.hypot(out[0].tip.x, out[0].tip.z) >= setup.length:
        raise ValueError(f"{files[0]}: the tip is at or beyond the reach of a segment of length "
                         f"{setup.length:g} m; photograph the segment bent to theta_max")
    return setup, out


@dataclass(frozen=True)
class ImagesCalibration:
    """A calibration from a folder of images (:func:`calibrate_images`).

    Attributes:
        folder: the folder.
        setup: its ``calibration.toml``.
        measurements: one per image, in name order.
        report: the calibration and its APCC and PCC residuals.
    """

    folder: Path
    setup: CalibrationImagesSetup
    measurements: tuple[ImageMeasurement, ...]
    report: CalibrationReport

    @property
    def tip_measurements(self) -> TipMeasurements:
        """The measured tips as the calibration-file type."""
        return _tip_measurements(self.setup, self.measurements)


def _tip_measurements(setup: CalibrationImagesSetup,
                      measurements: Sequence[ImageMeasurement]) -> TipMeasurements:
    return TipMeasurements(
        length=setup.length,
        tip_positions=np.array([[m.tip.x, m.tip.z] for m in measurements]),
        tip_angles=np.array([m.tip.angle for m in measurements]),
        theta_max=setup.theta_max,
    )


def calibrate_images(folder: str | Path) -> ImagesCalibration:
    """Calibrate k and delta_max of a segment from a folder of marker images.

    One image: the paper's closed form; several: the least-squares sweep fit
    (:func:`~apcc_graph.calibration.files.calibrate_measurements`).

    Args:
        folder: a folder with ``calibration.toml`` and ``*.png`` images (module docstring).

    Returns:
        The measurements per image and the calibration report.

    Raises:
        ValueError: see :func:`measure_folder`; a calibration that fails (e.g. k outside
            ``0 < k < 0.5``) is reported with the folder's name.
    """
    folder = Path(folder)
    setup, measurements = measure_folder(folder)
    try:
        report = calibrate_measurements(_tip_measurements(setup, measurements))
    except ValueError as exc:
        raise ValueError(f"{folder}: {exc}") from None
    return ImagesCalibration(folder=folder, setup=setup, measurements=tuple(measurements),
                             report=report)
