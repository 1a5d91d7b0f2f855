"""Synthetic side-camera images of one segment with ArUco markers, for calibration tests.

Renders what the side camera of a calibration-images folder
(:mod:`apcc_graph.calibration.photos`, format ``apcc-graph/calibration-images@1``) would see of a
segment bent to ``theta``, and writes whole folders of such images that
:func:`~apcc_graph.calibration.photos.calibrate_images` reads back. The shipped folders in
``data/calibration/`` come from :func:`write_calibration_images` (commands in its README).

Conventions
-----------
- Frames, units and the marker mounting are those of
  :mod:`apcc_graph.calibration.marker_geometry`: metres and radians, the base frame with +z the
  base axis and bends toward +x positive, the markers flat in the bending plane facing a camera
  on the base frame's -y side, OpenCV pixel coordinates (pixel centres at integers) and
  distortion order. A camera pose is ``base_T_cam`` (4x4, the camera frame in the base frame,
  OpenCV camera axes).
- The tip drawn is the APCC tip (position and tangent from
  :func:`~apcc_graph.model.kinematics.apcc_in_plane`) of the
  :class:`~apcc_graph.model.segment.Segment`.
- Images are 8-bit grey, ``camera.height`` x ``camera.width``; noise is in grey levels.
- Randomness (background blotches and sensor noise) comes only from the
  ``numpy.random.Generator`` passed in; :func:`write_calibration_images` seeds one with
  ``numpy.random.default_rng(seed)`` and draws the images in bend order, so the same arguments
  write the same bytes.

Rendering
---------
:func:`render_calibration_image` draws a smooth noisy background, the rod as a thick cubic
Hermite curve from the base to the APCC tip, a short stalk to the tip marker, both markers
(``cv2.aruco.generateImageMarker`` with a white quiet zone one cell wide, warped by their plane
homography; :mod:`~apcc_graph.simulation.marker_drawing`), optional lens distortion, and Gaussian
sensor noise. The background and the rod are drawn at 4x the resolution, the markers at 16x, and
averaged down (``INTER_AREA``), so edges are the area-integrated ones of a real sensor.
:func:`side_camera_pose` places a camera parallel to the bending plane (optionally tilted) that
frames a whole sweep. :func:`write_calibration_images` writes a folder (``pose_00.png``,
``pose_01.png``, ... and ``calibration.toml``), each file atomically
(:mod:`apcc_graph.io.atomic`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from apcc_graph.calibration.image_setup import (
    SETUP_FILE,
    CalibrationImagesSetup,
    MarkerLayout,
    image_files,
    setup_to_toml,
)
from apcc_graph.calibration.marker_geometry import (
    TipPose,
    base_T_base_marker,
    base_T_tip_marker,
    marker_corners,
    pose_matrix,
)
from apcc_graph.io.atomic import atomic_write_bytes, atomic_write_text
from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.camera import TipCamera
from apcc_graph.model.kinematics import apcc_in_plane
from apcc_graph.model.segment import Segment
from apcc_graph.simulation.marker_drawing import distort_image, paste_marker, pixel_scale

DEFAULT_CAMERA = TipCamera(fx=600.0, fy=600.0, cx=319.5, cy=239.5, width=640, height=480)
"""The side camera of synthetic folders: 640 x 480 pixels, 600 px focal length, no distortion."""

_ROD = 75.0
"""Grey level of the rod."""

ROD_SUPERSAMPLE = 4
"""The background and the rod are drawn at 4x the image resolution and averaged down."""


def _hermite(tip: TipPose, length: float, n: int = 96) -> FloatArray:
    """``(n, 3)`` points (base frame, y = 0) of a cubic Hermite curve from the base to the tip
    with the base and tip tangents; a smooth stand-in for the rod's body."""
    s = np.linspace(0.0, 1.0, n)[:, None]
    p0, p1 = np.zeros(2), np.array([tip.x, tip.z])
    m0 = length * np.array([0.0, 1.0])
    m1 = length * np.array([math.sin(tip.angle), math.cos(tip.angle)])
    xz = ((2 * s**3 - 3 * s**2 + 1) * p0 + (s**3 - 2 * s**2 + s) * m0
          + (-2 * s**3 + 3 * s**2) * p1 + (s**3 - s**2) * m1)
    return np.column_stack([xz[:, 0], np.zeros(n), xz[:, 1]])


def _quiet_zone(markers: MarkerLayout) -> float:
    """Side of a marker with its white quiet zone (one cell on each side), metres."""
    cells = markers.aruco_dictionary.markerSize + 2
    return markers.side * (cells + 2) / cells


def _scene_points(segment: Segment, theta: float, markers: MarkerLayout) -> FloatArray:
    """Points (base frame) that must be in view: the rod and both markers' quiet zones."""
    planar = apcc_in_plane(theta, segment)
    tip = TipPose(float(planar.px), float(planar.pz), float(planar.beta))
    zone = marker_corners(_quiet_zone(markers))
    parts = [_hermite(tip, segment.length, 24)]
    for base_T_m in (base_T_base_marker(markers.base_offset),
                     base_T_tip_marker(tip, markers.tip_offset)):
        parts.append(zone @ base_T_m[:3, :3].T + base_T_m[:3, 3])
    return np.concatenate(parts)


def side_camera_pose(
    segment: Segment,
    bends: ArrayLike,
    camera: TipCamera = DEFAULT_CAMERA,
    markers: MarkerLayout | None = None,
    tilt: tuple[float, float] = (0.0, 0.0),
    margin: float = 0.06,
) -> FloatArray:
    """``base_T_cam`` of a side camera that frames every pose of a sweep.

    The camera looks along base +y (image right = base +x, image up = base +z) at the centre of
    the bounding box of the rod and both markers over all ``bends``, from the distance at which
    that box fills the image up to ``margin`` on each side; ``tilt`` then turns it about its own
    x and y axes (a rotation vector ``(tx, ty, 0)``, radians) around that centre.

    Args:
        segment: the segment (its APCC tip poses are framed).
        bends: the bends theta of the sweep, radians.
        camera: the side camera.
        markers: the marker layout (default
            :meth:`~apcc_graph.calibration.photos.MarkerLayout.for_length`).
        tilt: small rotation of the camera away from parallel, radians.
        margin: free border on each side, a fraction of the image.

    Returns:
        The 4x4 pose of the camera in the base frame.
    """
    markers = markers or MarkerLayout.for_length(segment.length)
    points = np.concatenate([_scene_points(segment, float(t), markers)
                             for t in np.atleast_1d(np.asarray(bends, dtype=float))])
    low, high = points.min(axis=0), points.max(axis=0)
    centre = 0.5 * (low + high)
    span = high - low
    usable = 1.0 - 2.0 * margin
    distance = max(camera.fx * span[0] / (camera.width * usable),
                   camera.fy * span[2] / (camera.height * usable))
    looking = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
    rotation = looking @ cv2.Rodrigues(np.array([tilt[0], tilt[1], 0.0]))[0]
    return pose_matrix(rotation, centre - distance * rotation[:, 2])



@dataclass(frozen=True)
class _View:
    """The side camera's view of the segment bent to ``theta`` (the bend is named in errors)."""

    camera: TipCamera
    cam_T_base: FloatArray
    theta: float

    def pixels(self, points_base: FloatArray) -> FloatArray:
        """``(N, 2)`` pixels of ``(N, 3)`` base-frame points (pinhole, no distortion).

        Raises:
            ValueError: a point is behind the camera.
        """
        cam = points_base @ self.cam_T_base[:3, :3].T + self.cam_T_base[:3, 3]
        if np.any(cam[:, 2] <= 0.0):
            raise ValueError(f"bend {math.degrees(self.theta):.2f} deg: part of the scene is "
                             "behind the camera")
        uvw = cam @ self.camera.intrinsic_matrix.T
        return uvw[:, :2] / uvw[:, 2:3]


def _check_in_view(view: _View, mounted: tuple[tuple[str, int, FloatArray], ...],
                   markers: MarkerLayout) -> None:
    """Raise ``ValueError`` unless both markers' quiet zones lie wholly inside the image."""
    width, height = view.camera.width, view.camera.height
    zone = marker_corners(_quiet_zone(markers))
    for role, _, base_T_m in mounted:
        outline = view.pixels(zone @ base_T_m[:3, :3].T + base_T_m[:3, 3])
        if np.any(outline < 0.0) or np.any(outline > [width - 1, height - 1]):
            raise ValueError(f"bend {math.degrees(view.theta):.2f} deg: the {role} marker is not "
                             f"wholly inside the {width}x{height} image; move the camera back")


def _draw_rod(view: _View, tip: TipPose, length: float, stalk_end: FloatArray,
              diameter: float, rng: np.random.Generator) -> NDArray[np.float32]:
    """The background and the rod at :data:`ROD_SUPERSAMPLE` x the resolution, averaged down:
    a smooth grey with a gentle gradient and low-frequency blotches, the rod, the stalk holding
    the tip marker (to ``stalk_end``, base frame) and a clamp at the base."""
    camera, cam_T_base = view.camera, view.cam_T_base
    width, height, ss = camera.width, camera.height, ROD_SUPERSAMPLE
    blotches = cv2.resize(rng.normal(0.0, 12.0, (6, 8)).astype(np.float32),
                          (width * ss, height * ss), interpolation=cv2.INTER_CUBIC)
    ramp = np.linspace(-10.0, 10.0, width * ss, dtype=np.float32)[None, :]
    canvas = 140.0 + ramp + blotches
    fine = pixel_scale(ss)[:2, :2]
    offset = pixel_scale(ss)[:2, 2]

    def fixed_point(points_base: FloatArray) -> NDArray[np.int32]:  # 4 fractional bits
        return np.round((view.pixels(points_base) @ fine.T + offset) * 16.0).astype(np.int32)

    depth = float((cam_T_base[:3, :3] @ [tip.x, 0.0, tip.z] + cam_T_base[:3, 3])[2])
    thick = max(int(round(diameter * camera.fx * ss / depth)), 1)
    cv2.polylines(canvas, [fixed_point(_hermite(tip, length))], False, _ROD, thick,
                  cv2.LINE_AA, shift=4)
    stalk = fixed_point(np.array([[tip.x, 0.0, tip.z], stalk_end]))
    cv2.line(canvas, tuple(map(int, stalk[0])), tuple(map(int, stalk[1])), _ROD,
             max(thick // 2, 1), cv2.LINE_AA, shift=4)
    d = diameter
    clamp = np.array([[-1.5 * d, 0.0, -0.2 * d], [1.5 * d, 0.0, -0.2 * d],
                      [1.5 * d, 0.0, 0.3 * d], [-1.5 * d, 0.0, 0.3 * d]])
    cv2.fillConvexPoly(canvas, fixed_point(clamp), 0.6 * _ROD, cv2.LINE_AA, shift=4)
    return cv2.resize(canvas, (width, height), interpolation=cv2.INTER_AREA)


def render_calibration_image(
    segment: Segment,
    theta: float,
    camera: TipCamera,
    base_T_cam: ArrayLike,
    markers: MarkerLayout,
    rng: np.random.Generator,
    noise: float = 1.0,
    rod_diameter: float | None = None,
) -> NDArray[np.uint8]:
    """What the side camera sees of ``segment`` bent to ``theta``, with its two markers.

    Args:
        segment: the segment (APCC tip from :func:`~apcc_graph.model.kinematics.apcc_in_plane`).
        theta: the bend, radians.
        camera: the side camera (intrinsics, distortion).
        base_T_cam: 4x4 pose of the camera in the base frame (e.g. :func:`side_camera_pose`).
        markers: the marker layout.
        rng: random generator for the background and the sensor noise.
        noise: standard deviation of the Gaussian sensor noise, grey levels.
        rod_diameter: the rod's drawn thickness, metres (default ``L / 30``).

    Returns:
        ``(height, width)`` uint8 image.

    Raises:
        ValueError: a negative noise, part of the scene behind the camera or a marker not
            wholly inside the image.
    """
    if not (math.isfinite(noise) and noise >= 0.0):
        raise ValueError(f"noise = {noise!r}: expected grey levels >= 0")
    cam_T_base = np.linalg.inv(np.asarray(base_T_cam, dtype=float))
    planar = apcc_in_plane(theta, segment)
    tip = TipPose(float(planar.px), float(planar.pz), float(planar.beta))
    view = _View(camera, cam_T_base, theta)
    mounted = (("base", markers.base_id, base_T_base_marker(markers.base_offset)),
               ("tip", markers.tip_id, base_T_tip_marker(tip, markers.tip_offset)))
    _check_in_view(view, mounted, markers)
    diameter = segment.length / 30.0 if rod_diameter is None else rod_diameter
    image = _draw_rod(view, tip, segment.length, mounted[1][2][:3, 3], diameter, rng)
    for _, marker_id, base_T_m in mounted:
        paste_marker(image, camera.intrinsic_matrix, cam_T_base @ base_T_m, markers, marker_id)
    if camera.distortion:
        image = distort_image(image, camera)
    image = image + rng.normal(0.0, noise, image.shape)
    return np.clip(np.round(image), 0, 255).astype(np.uint8)


def encode_png(image: NDArray[np.uint8]) -> bytes:
    """PNG bytes of an 8-bit image (OpenCV's encoder, default compression)."""
    ok, data = cv2.imencode(".png", image)
    if not ok:  # pragma: no cover - OpenCV fails only on unsupported layouts
        raise ValueError("OpenCV could not encode the image as PNG")
    return data.tobytes()


def _output_bends(folder: Path, bends: ArrayLike, force: bool) -> FloatArray:
    """The bends as a 1-D array, checked, and ``folder`` checked to be writable.

    Raises:
        ValueError: no bends, a non-finite bend, or a non-empty folder without ``force``.
    """
    thetas = np.atleast_1d(np.asarray(bends, dtype=float))
    if thetas.ndim != 1 or len(thetas) == 0 or not np.all(np.isfinite(thetas)):
        raise ValueError(f"bends = {bends!r}: expected one or more finite angles")
    if folder.exists() and not folder.is_dir():
        raise ValueError(f"{folder}: exists and is not a folder")
    if folder.is_dir() and any(folder.iterdir()) and not force:
        raise ValueError(f"{folder}: exists and is not empty; choose another folder or use "
                         "--force (replaces its calibration.toml and *.png)")
    return thetas


def _truth_comment(segment: Segment, thetas: FloatArray, seed: int, noise: float,
                   tilt: tuple[float, float]) -> str:
    """The header comment of a synthetic folder's ``calibration.toml``: how it was made."""
    return (
        "Synthetic calibration images "
        "(apcc_graph.simulation.calibration_photos.write_calibration_images).\n"
        f"True segment: length = {segment.length!r} m, k = {segment.k!r}, "
        f"delta_max_deg = {math.degrees(segment.delta_max):.6g}, "
        f"theta_max_deg = {math.degrees(segment.theta_max):.6g}\n"
        "Bends (deg), one per image: "
        + ", ".join(f"{math.degrees(t):g}" for t in thetas) + "\n"
        f"seed = {seed}, noise = {noise:g} grey levels, camera tilt = "
        f"({math.degrees(tilt[0]):g}, {math.degrees(tilt[1]):g}) deg"
    )


def write_calibration_images(
    folder: str | Path,
    segment: Segment,
    bends: ArrayLike,
    *,
    camera: TipCamera = DEFAULT_CAMERA,
    markers: MarkerLayout | None = None,
    seed: int = 0,
    noise: float = 1.0,
    tilt: tuple[float, float] = (0.0, 0.0),
    base_T_cam: ArrayLike | None = None,
    force: bool = False,
) -> list[Path]:
    """Render a seeded synthetic calibration-images folder of ``segment`` at ``bends``.

    Writes ``pose_00.png``, ``pose_01.png``, ... (one per bend, in the given order) and
    ``calibration.toml`` (with the true k, delta_max and bends in its header comment) atomically.
    The same arguments write the same bytes.

    Args:
        folder: output folder (created if needed).
        segment: the true segment; its ``theta_max`` is written as ``theta_max_deg``.
        bends: bends theta, radians.
        camera: the side camera.
        markers: the marker layout (default
            :meth:`~apcc_graph.calibration.photos.MarkerLayout.for_length`).
        seed: seed of ``numpy.random.default_rng`` (background and noise).
        noise: sensor noise, grey levels.
        tilt: camera tilt away from parallel (see :func:`side_camera_pose`), radians.
        base_T_cam: the camera pose; default :func:`side_camera_pose` framing all bends.
        force: write into a folder that already holds files, replacing its ``*.png`` files.

    Returns:
        The files written, images first, ``calibration.toml`` last.

    Raises:
        ValueError: no bends, a non-finite bend, a non-empty folder without ``force``, or a
            marker outside the image.
    """
    folder = Path(folder)
    thetas = _output_bends(folder, bends, force)
    markers = markers or MarkerLayout.for_length(segment.length)
    if base_T_cam is None:
        base_T_cam = side_camera_pose(segment, thetas, camera, markers, tilt)
    rng = np.random.default_rng(seed)
    images = [render_calibration_image(segment, float(t), camera, base_T_cam, markers, rng,
                                       noise=noise) for t in thetas]
    written = []
    for i, image in enumerate(images):
        path = folder / f"pose_{i:02d}.png"
        atomic_write_bytes(path, encode_png(image))
        written.append(path)
    for stale in set(image_files(folder)) - set(written):
        stale.unlink()
    setup = CalibrationImagesSetup(length=segment.length, theta_max=segment.theta_max,
                                   markers=markers, camera=camera)
    truth = _truth_comment(segment, thetas, seed, noise, tilt)
    config = folder / SETUP_FILE
    atomic_write_text(config, setup_to_toml(setup, truth))
    written.append(config)
    return written
