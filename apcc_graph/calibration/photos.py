"""Calibration of one segment from photos with ArUco markers (paper III.C "visual sampling"):
measuring the tip in each photo of a folder and calibrating from those measurements.

The paper photographs the segment with a camera parallel to its bending plane and reads the chord
angle, the tip tangent angle and the point P off the photo. Here two ArUco markers make the same
measurement automatic: one on the base, one on the tip. Each image gives one tip pose ``(x, z)``
and tip angle ``theta_hat``, exactly the inputs of
:func:`~apcc_graph.calibration.closed_form.calibrate_from_tip` (one image) and
:func:`~apcc_graph.calibration.fit.fit_segment` (a sweep); :func:`calibrate_images` runs both
through :func:`~apcc_graph.calibration.files.calibrate_measurements`.

One photo is measured (:func:`measure_image`) by remapping it to a pinhole camera if the camera
has distortion, finding both markers and aligning their corners
(:mod:`~apcc_graph.calibration.marker_detection`), and fitting the tip pose to all 8 corners
(:mod:`~apcc_graph.calibration.marker_geometry`, which also states the frames and the marker
mounting). The folder and ``calibration.toml`` are described in
:mod:`~apcc_graph.calibration.image_setup`. Synthetic folders of this format, rendered from the
APCC model, come from :mod:`apcc_graph.simulation.calibration_photos`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from apcc_graph.calibration.files import (
    CalibrationReport,
    TipMeasurements,
    calibrate_measurements,
)
from apcc_graph.calibration.fit import REACH_SLACK
from apcc_graph.calibration.image_setup import (
    IMAGE_PATTERN,
    SETUP_FILE,
    CalibrationImagesSetup,
    image_files,
    load_setup,
)
from apcc_graph.calibration.marker_detection import (
    detect_markers,
    marker_detector,
    refine_corners,
    undistorted_image,
)
from apcc_graph.calibration.marker_geometry import TipPose, fit_marker_corners
from apcc_graph.model.arrays import FloatArray


@dataclass(frozen=True)
class ImageMeasurement:
    """The tip pose measured in one image.

    Attributes:
        name: the image (file name or a label), for messages and reports.
        tip: tip ``(x, z, angle)`` in the bending plane.
        rms_px: RMS corner reprojection error of the joint fit, pixels.
        cam_T_base: 4x4 pose of the base frame in the camera frame.
        aligned: how many of the two markers' corners
            :func:`~apcc_graph.calibration.marker_detection.refine_corners` refined (the
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
        detector: a detector from
            :func:`~apcc_graph.calibration.marker_detection.marker_detector` (made if not given).
        refine: align each marker's pattern to the image
            (:func:`~apcc_graph.calibration.marker_detection.refine_corners`); ``False``
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
        image, cam = undistorted_image(image, cam)
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
