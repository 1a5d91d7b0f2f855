"""Finding the two ArUco markers in a calibration photo and aligning their corners to it
(calibration from photos, :mod:`~apcc_graph.calibration.photos`).

1. Detection (:func:`marker_detector`, :func:`detect_markers`):
   :class:`cv2.aruco.ArucoDetector` with sub-pixel corner refinement (``CORNER_REFINE_SUBPIX``,
   iterated to 0.01 px).
2. Corner alignment (:func:`refine_corners`): each marker's known pattern is aligned to the image
   by ``cv2.findTransformECC`` (a homography, started from the detector's corners), so that every
   edge of every bit takes part. ``cornerSubPix`` on the L-shaped corner of a small marker puts
   the corners slightly inside the square; every distance in the plane then comes out too long,
   and k, which moves against that scale error, comes out low. The aligned corners have no such
   bias.
3. Images from a camera with distortion are first remapped to the pinhole camera with the same
   intrinsics (:func:`undistorted_image`): a marker is a homography of its pattern only there.
"""

from __future__ import annotations

import functools

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from apcc_graph.calibration.image_setup import MarkerLayout
from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.camera import TipCamera


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
    aligned corners inward.
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


@functools.lru_cache(maxsize=4)
def _undistortion_maps(camera: TipCamera) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    size, K = (camera.width, camera.height), camera.intrinsic_matrix
    if camera.model == "fisheye":
        return cv2.fisheye.initUndistortRectifyMap(
            K, camera.distortion_coefficients.reshape(4, 1), np.eye(3), K, size, cv2.CV_32FC1)
    return cv2.initUndistortRectifyMap(K, camera.distortion_coefficients, None, K, size,
                                       cv2.CV_32FC1)


def undistorted_image(image: NDArray[np.uint8], camera: TipCamera
                      ) -> tuple[NDArray[np.uint8], TipCamera]:
    """The image as a pinhole camera with the same intrinsics and no distortion sees it.

    A marker is a homography of its pattern only in a pinhole image; aligning it in the
    distorted image bends its corners, and the error grows toward the border.

    Returns:
        The remapped image and that pinhole camera.
    """
    map_x, map_y = _undistortion_maps(camera)
    pinhole = TipCamera(camera.fx, camera.fy, camera.cx, camera.cy, camera.width, camera.height)
    return cv2.remap(image, map_x, map_y, cv2.INTER_LINEAR), pinhole
