"""Where the two ArUco markers of calibration from photos sit, and the tip pose from their
corners (:mod:`~apcc_graph.calibration.photos`).

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

The tip pose (:func:`fit_marker_corners`)
-----------------------------------------
One plane pose ``cam_T_base`` (6 unknowns) and the tip pose ``(x, z, theta_hat)`` in that plane
(3 unknowns) minimise the reprojection error of all 8 corners (``scipy.optimize.least_squares``,
started from ``cv2.solvePnPGeneric(SOLVEPNP_IPPE_SQUARE)`` on the base marker, both of its
solutions tried, and the tip marker's corner rays intersected with that plane). It is the
maximum-likelihood estimate under corner noise with the coplanarity that the mounting guarantees,
and it takes the scale from both squares. Intersecting the tip marker's rays with the base
marker's plane takes the scale from the base marker alone; two independent ``solvePnP`` poses
are not coplanar and each carries its own depth error.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
import scipy.optimize
from numpy.typing import ArrayLike

from apcc_graph.calibration.image_setup import MarkerLayout
from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.camera import TipCamera

MARKER_FACING_BASE = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
"""Rotation ``base_R_marker`` of the base marker: marker +x = base +x, marker +y = base +z and
marker +z (its printed face) = base -y, toward a camera on the -y side."""


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
    if camera.model != "pinhole":
        raise ValueError(f"a {camera.model} camera: undistort the image first "
                         "(marker_detection.undistorted_image)")
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
