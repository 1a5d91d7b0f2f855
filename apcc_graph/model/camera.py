"""The tip camera: pinhole intrinsics, OpenCV distortion, and its mounting on the segment tip.

Conventions: pixels are ``(u, v)`` with the origin at the top-left pixel corner as in OpenCV;
the camera frame has +z along the optical axis, +x to the right of the image, +y down.
``tip_T_cam`` maps points in the camera frame to the tip frame (docs/estimation.md, "Conventions");
a camera looking straight along the backbone has ``tip_T_cam = identity``. Distortion coefficients
are in OpenCV order ``k1, k2, p1, p2[, k3[, k4, k5, k6[, s1, s2, s3, s4[, tx, ty]]]]``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import lru_cache

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.segment import require_finite

OPENCV_DISTORTION_SIZES = (0, 4, 5, 8, 12, 14)
"""Numbers of distortion coefficients that OpenCV accepts."""
CAMERA_MODELS = ("pinhole", "fisheye")
"""OpenCV's distortion models a :class:`TipCamera` takes: radial-tangential (``cv2``) and the
equidistant fisheye (``cv2.fisheye``)."""


def validate_pose(name: str, matrix: ArrayLike, tolerance: float = 1e-6) -> FloatArray:
    """Check that ``matrix`` is a 4x4 rigid transform and return it as a read-only float array.

    Args:
        name: the field name for the message.
        matrix: the candidate transform.
        tolerance: allowed deviation of ``R^T R`` from identity and of ``det R`` from 1.

    Raises:
        ValueError: wrong shape, non-finite values, a bottom row other than ``[0, 0, 0, 1]`` or a
            rotation block that is not orthonormal with determinant +1.
    """
    m = np.array(matrix, dtype=float)
    if m.shape != (4, 4):
        raise ValueError(f"{name}: expected a 4x4 homogeneous transform, got shape {m.shape}")
    if not np.all(np.isfinite(m)):
        raise ValueError(f"{name}: expected finite values, got {m.tolist()}")
    if not np.allclose(m[3], [0.0, 0.0, 0.0, 1.0], rtol=0.0, atol=tolerance):
        raise ValueError(f"{name}: bottom row must be [0, 0, 0, 1], got {m[3].tolist()}")
    rot = m[:3, :3]
    if (
        np.max(np.abs(rot.T @ rot - np.eye(3))) > tolerance
        or abs(np.linalg.det(rot) - 1.0) > tolerance
    ):
        raise ValueError(f"{name}: the 3x3 block must be a rotation (orthonormal, det +1)")
    m[3] = [0.0, 0.0, 0.0, 1.0]
    m.setflags(write=False)
    return m


def is_rigid(matrix: ArrayLike, tolerance: float = 1e-6) -> bool:
    """Whether ``matrix`` passes :func:`validate_pose`, answered in a few microseconds (plain
    floats, no copy): for per-call checks in hot paths, which then call
    :func:`validate_pose` for the message."""
    a = np.asarray(matrix, dtype=float)
    if a.shape != (4, 4):
        return False
    rows = a.tolist()
    if not all(math.isfinite(x) for row in rows for x in row):
        return False
    (a0, a1, a2, _), (b0, b1, b2, _), (c0, c1, c2, _), last = rows
    gram = (a0 * a0 + b0 * b0 + c0 * c0 - 1.0, a1 * a1 + b1 * b1 + c1 * c1 - 1.0,
            a2 * a2 + b2 * b2 + c2 * c2 - 1.0, a0 * a1 + b0 * b1 + c0 * c1,
            a0 * a2 + b0 * b2 + c0 * c2, a1 * a2 + b1 * b2 + c1 * c2,
            last[0], last[1], last[2], last[3] - 1.0)
    det = a0 * (b1 * c2 - b2 * c1) - a1 * (b0 * c2 - b2 * c0) + a2 * (b0 * c1 - b1 * c0)
    return max(abs(g) for g in gram) <= tolerance and abs(det - 1.0) <= tolerance


_UNDISTORT_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-15)
"""OpenCV's default stops after 5 iterations (errors ~3e-5 rad near the corners); iterate to
convergence instead, so that ``bearings`` inverts ``project`` to machine precision."""


def _undistort(uv: FloatArray, K: FloatArray, dist: FloatArray, model: str = "pinhole"
               ) -> FloatArray:
    """Normalised image coordinates of distorted pixels, iterated to convergence."""
    src = np.ascontiguousarray(uv, dtype=np.float64).reshape(-1, 1, 2)
    if model == "fisheye":
        return cv2.fisheye.undistortPoints(src, K, dist.reshape(4, 1), None, None, None,
                                           _UNDISTORT_CRITERIA).reshape(-1, 2)
    if hasattr(cv2, "undistortPointsIter"):  # OpenCV 4.x
        out = cv2.undistortPointsIter(src, K, dist, None, None, _UNDISTORT_CRITERIA)
    else:  # OpenCV 5 takes the criteria in undistortPoints itself
        out = cv2.undistortPoints(src, K, dist, None, None, None, _UNDISTORT_CRITERIA)
    return out.reshape(-1, 2)


_RAY_ANGLES = np.radians(np.linspace(0.0, 89.0, 891))
"""Angles of rays from the optical axis at which the distortion is checked (0.1 deg apart)."""
_HINT = "check the coefficients' values, order (OpenCV: k1, k2, p1, p2[, k3, ...]) and model"
ROUND_TRIP_PX = 0.1
"""How far a pixel may land from itself after undistorting it and projecting it back."""


@lru_cache(maxsize=256)
def _distortion_problem(camera: TipCamera) -> str | None:
    """Why a distortion cannot be inverted over the image, or ``None``: checked with the
    camera's own projection. Toward each image corner and edge middle, the distorted radius must
    grow with the ray's angle until it reaches that border (else some pixels are seen by two
    rays, or none); and pixels over the image, undistorted and projected back, must land where
    they were (else undistortion diverges there)."""
    fx, fy, cx, cy = camera.fx, camera.fy, camera.cx, camera.cy
    width, height = camera.width, camera.height
    border = np.array([[0.0, 0.0], [width, 0.0], [0.0, height], [width, height],
                       [width / 2, 0.0], [width / 2, height], [0.0, height / 2],
                       [width, height / 2]])
    toward = (border - [cx, cy]) / [fx, fy]
    needed = np.linalg.norm(toward, axis=1)
    r = np.tan(_RAY_ANGLES)
    for direction, reach, (bu, bv) in zip(toward, needed, border.tolist(), strict=True):
        if reach <= 0.0:
            continue
        unit = direction / reach
        pts = np.column_stack([r * unit[0], r * unit[1], np.ones_like(r)])
        uv = camera.project(pts)
        with np.errstate(all="ignore"):  # signed: a fold through the centre changes sign
            radius = ((uv - [cx, cy]) / [fx, fy]) @ unit
        reached = np.flatnonzero(radius >= reach)
        upto = int(reached[0]) + 1 if len(reached) else len(radius)
        grows = np.diff(radius[:upto]) > 0.0
        if not np.all(grows) or not np.all(np.isfinite(radius[:upto])):
            turn = int(np.argmin(grows)) if len(grows) else 0
            return (f"not invertible over the {width}x{height} image: toward pixel "
                    f"({bu:g}, {bv:g}) the image radius stops growing at "
                    f"{np.degrees(_RAY_ANGLES[turn]):.1f} deg from the optical axis, "
                    f"{radius[turn] * max(fx, fy):.4g} px from the principal point (the border "
                    f"is {reach * max(fx, fy):.4g} px away), so some pixels are seen by "
                    f"several rays; {_HINT}")
        if not len(reached):
            continue
        # rays beyond the border, up to well past where a pinhole would see it, stay outside
        # (a radius that falls back below the border, or through zero, crossed the image)
        limit = 1.25 * max(float(_RAY_ANGLES[upto - 1]), math.atan(reach))
        later = np.flatnonzero((_RAY_ANGLES > _RAY_ANGLES[upto - 1]) & (_RAY_ANGLES <= limit)
                               & (radius < reach))
        if len(later):
            back = int(later[0])
            return (f"not invertible over the {width}x{height} image: toward pixel "
                    f"({bu:g}, {bv:g}) rays reach the border at "
                    f"{np.degrees(_RAY_ANGLES[upto - 1]):.1f} deg from the optical axis, but "
                    f"rays at {np.degrees(_RAY_ANGLES[back]):.1f} deg land back inside the image, "
                    f"so some pixels are seen by several rays; {_HINT}")
    grid = np.stack(np.meshgrid(np.linspace(0.0, width - 1.0, 7),
                                np.linspace(0.0, height - 1.0, 7)), -1).reshape(-1, 2)
    with np.errstate(all="ignore"):
        back = camera.project(np.column_stack([camera.normalized(grid), np.ones(len(grid))]))
    miss = np.linalg.norm(back - grid, axis=1)
    miss[~np.isfinite(miss)] = np.inf
    worst = int(np.argmax(miss))
    if miss[worst] > ROUND_TRIP_PX:
        u, v = grid[worst].tolist()
        return (f"not invertible over the {width}x{height} image: pixel ({u:.0f}, {v:.0f}) "
                f"undistorted and projected back lands {miss[worst]:.3g} px away; {_HINT}")
    return None


@dataclass(frozen=True, eq=False)
class TipCamera:
    """A pinhole camera with OpenCV distortion, rigidly mounted on a segment tip.

    Args:
        fx, fy: focal lengths in pixels, > 0.
        cx, cy: principal point in pixels.
        width, height: image size in pixels, positive integers.
        distortion: OpenCV distortion coefficients: for ``model="pinhole"`` 0, 4, 5, 8, 12 or
            14 of them (radial-tangential: k1, k2, p1, p2[, k3, ...]); for ``"fisheye"`` the 4 of
            OpenCV's fisheye model (equidistant: k1, k2, k3, k4; ``cv2.fisheye``).
        tip_T_cam: 4x4 pose of the camera in the tip frame (default identity: looking along the
            backbone).
        model: ``"pinhole"`` (default) or ``"fisheye"``: which of OpenCV's distortion models
            ``distortion`` belongs to.

    Raises:
        ValueError: a field is not finite, out of range or of the wrong size; the message names it.
    """

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    distortion: tuple[float, ...] = ()
    tip_T_cam: FloatArray = field(default_factory=lambda: np.eye(4))
    model: str = "pinhole"

    def __post_init__(self) -> None:
        for name in ("fx", "fy", "cx", "cy"):
            value = require_finite("TipCamera", name, getattr(self, name))
            if name in ("fx", "fy") and value <= 0.0:
                raise ValueError(
                    f"TipCamera.{name} = {value!r}: expected a focal length > 0 (pixels)"
                )
            object.__setattr__(self, name, value)
        for name in ("width", "height"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value <= 0:
                raise ValueError(
                    f"TipCamera.{name} = {value!r}: expected a positive integer (pixels)"
                )
            object.__setattr__(self, name, int(value))
        dist = tuple(
            require_finite("TipCamera", f"distortion[{i}]", d)
            for i, d in enumerate(self.distortion)
        )
        if self.model not in CAMERA_MODELS:
            raise ValueError(f"TipCamera.model = {self.model!r}: expected one of {CAMERA_MODELS}")
        if self.model == "fisheye" and len(dist) != 4:
            raise ValueError(
                f"TipCamera.distortion has {len(dist)} coefficients: the fisheye model takes 4 "
                "(OpenCV's k1, k2, k3, k4)"
            )
        if len(dist) not in OPENCV_DISTORTION_SIZES:
            raise ValueError(
                f"TipCamera.distortion has {len(dist)} coefficients: expected one of "
                f"{OPENCV_DISTORTION_SIZES} (OpenCV order k1, k2, p1, p2[, k3, ...])"
            )
        object.__setattr__(self, "distortion", dist)
        object.__setattr__(self, "tip_T_cam", validate_pose("TipCamera.tip_T_cam", self.tip_T_cam))
        if dist and self.model == "pinhole":  # a fisheye's image circle may leave corners dark
            problem = _distortion_problem(self)  # every field is set and checked by now
            if problem:
                raise ValueError(f"TipCamera.distortion = {list(dist)}: {problem}")

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, TipCamera):
            return NotImplemented
        return (self.fx, self.fy, self.cx, self.cy, self.width, self.height, self.distortion,
                self.model) == (
            other.fx,
            other.fy,
            other.cx,
            other.cy,
            other.width,
            other.height,
            other.distortion,
            other.model,
        ) and bool(np.array_equal(self.tip_T_cam, other.tip_T_cam))

    def __hash__(self) -> int:
        return hash(
            (
                self.fx,
                self.fy,
                self.cx,
                self.cy,
                self.width,
                self.height,
                self.distortion,
                self.model,
                self.tip_T_cam.tobytes(),
            )
        )

    @property
    def intrinsic_matrix(self) -> FloatArray:
        """The 3x3 OpenCV camera matrix ``K``."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def distortion_coefficients(self) -> FloatArray:
        """Distortion coefficients as the float array OpenCV expects (possibly empty)."""
        return np.asarray(self.distortion, dtype=float)

    def project(self, points_cam: ArrayLike) -> FloatArray:
        """Project points given in the camera frame (metres) to pixels, with distortion.

        Args:
            points_cam: ``(N, 3)`` points in the camera frame; they should have ``z > 0``.

        Returns:
            ``(N, 2)`` pixel coordinates ``(u, v)``.
        """
        pts = np.asarray(points_cam, dtype=float).reshape(-1, 3)
        if len(pts) == 0:
            return np.zeros((0, 2))
        if not self.distortion:
            uvw = pts @ self.intrinsic_matrix.T
            return uvw[:, :2] / uvw[:, 2:3]
        if self.model == "fisheye":
            uv, _ = cv2.fisheye.projectPoints(
                pts.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), self.intrinsic_matrix,
                self.distortion_coefficients.reshape(4, 1))
            return uv.reshape(-1, 2)
        uv, _ = cv2.projectPoints(
            pts, np.zeros(3), np.zeros(3), self.intrinsic_matrix, self.distortion_coefficients
        )
        return uv.reshape(-1, 2)

    def bearings(self, pixels: ArrayLike) -> FloatArray:
        """Unit bearing vectors in the camera frame for pixels, undistorted by OpenCV.

        Args:
            pixels: ``(N, 2)`` pixel coordinates ``(u, v)``.

        Returns:
            ``(N, 3)`` unit vectors, ``z > 0``.
        """
        uv = np.asarray(pixels, dtype=float).reshape(-1, 2)
        if len(uv) == 0:
            return np.zeros((0, 3))
        if self.distortion:
            xy = _undistort(uv, self.intrinsic_matrix, self.distortion_coefficients, self.model)
        else:
            xy = np.column_stack([(uv[:, 0] - self.cx) / self.fx, (uv[:, 1] - self.cy) / self.fy])
        rays = np.column_stack([xy, np.ones(len(xy))])
        return rays / np.linalg.norm(rays, axis=1, keepdims=True)

    def normalized(self, pixels: ArrayLike) -> FloatArray:
        """Undistorted normalised image coordinates ``(x, y)`` of pixels (``pixel = K
        distort(x, y)``), ``(N, 2)``."""
        f = self.bearings(pixels)
        return f[:, :2] / f[:, 2:3]

    def pixel_jacobian(self, xy: ArrayLike) -> FloatArray:
        """``d pixel / d (x, y)`` at normalised points ``(N, 2)``: ``(N, 2, 2)``.

        ``diag(fx, fy)`` for a pinhole; with distortion, central differences of
        :meth:`project` (step 1e-6, error ~1e-9 relative).
        """
        xy = np.asarray(xy, dtype=float).reshape(-1, 2)
        if not self.distortion:
            out = np.zeros((len(xy), 2, 2))
            out[:, 0, 0], out[:, 1, 1] = self.fx, self.fy
            return out
        h = 1e-6
        out = np.empty((len(xy), 2, 2))
        for axis in range(2):
            step = np.zeros(2)
            step[axis] = h
            plus = self.project(np.column_stack([xy + step, np.ones(len(xy))]))
            minus = self.project(np.column_stack([xy - step, np.ones(len(xy))]))
            out[:, :, axis] = (plus - minus) / (2.0 * h)
        return out

    def in_image(self, pixels: ArrayLike) -> NDArray[np.bool_]:
        """Mask of pixels inside the image, ``0 <= u < width`` and ``0 <= v < height``."""
        uv = np.asarray(pixels, dtype=float).reshape(-1, 2)
        return (
            (uv[:, 0] >= 0.0)
            & (uv[:, 0] < self.width)
            & (uv[:, 1] >= 0.0)
            & (uv[:, 1] < self.height)
        )
