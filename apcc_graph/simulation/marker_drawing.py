"""Drawing primitives of the synthetic calibration photos
(:mod:`~apcc_graph.simulation.calibration_photos`): an ArUco marker with its white quiet zone
pasted into an image by its plane homography, area-integrated like a real sensor, and the lens
distortion of a pinhole image.

Pixel coordinates are OpenCV's (pixel centres at integers); images are float32 grey levels.
"""

from __future__ import annotations

import functools

import cv2
import numpy as np
from numpy.typing import NDArray

from apcc_graph.calibration.image_setup import MarkerLayout
from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.camera import TipCamera

INK, PAPER = 30.0, 225.0
"""Grey levels of the markers' black and white."""

MARKER_SUPERSAMPLE = 16
"""Markers are rendered at 16x the image resolution and averaged down, so that the corners of the
rendered markers lie close to their projection; a coarser grid biases every image of a sweep the
same way through the fixed base marker."""


def _marker_texture(markers: MarkerLayout, marker_id: int, cell: int
                    ) -> tuple[NDArray[np.float32], float]:
    """The marker image with a one-cell white quiet zone, and its pixels per metre."""
    cells = markers.aruco_dictionary.markerSize + 2
    image = cv2.aruco.generateImageMarker(markers.aruco_dictionary, marker_id, cells * cell,
                                          borderBits=1)
    image = cv2.copyMakeBorder(image, cell, cell, cell, cell, cv2.BORDER_CONSTANT, value=255)
    texture = (INK + (image.astype(np.float32) / 255.0) * (PAPER - INK)).astype(np.float32)
    return texture, cells * cell / markers.side


def pixel_scale(factor: int) -> FloatArray:
    """Maps image pixels to a grid ``factor`` times finer (pixel centres at integers)."""
    offset = 0.5 * (factor - 1)
    return np.array([[factor, 0.0, offset], [0.0, factor, offset], [0.0, 0.0, 1.0]])


def paste_marker(canvas: NDArray[np.float32], camera_matrix: FloatArray, cam_T_m: FloatArray,
                 markers: MarkerLayout, marker_id: int) -> None:
    """Draw one marker with its quiet zone into ``canvas`` (in place) by its plane homography.

    The marker's neighbourhood is rendered at :data:`MARKER_SUPERSAMPLE` times the resolution
    (a texture no coarser than that grid, bilinear), averaged down to whole pixels
    (``INTER_AREA``) and blended with the canvas by the area it covers.
    """
    texture, per_metre = _marker_texture(markers, marker_id, cell=32)
    n = texture.shape[0]
    centre = 0.5 * (n - 1)
    # Texture pixel (u, v) -> marker point (x, y, 1): pixel centres at integers, +y up.
    texture_to_marker = np.array([[1.0 / per_metre, 0.0, -centre / per_metre],
                                  [0.0, -1.0 / per_metre, centre / per_metre],
                                  [0.0, 0.0, 1.0]])
    plane = np.column_stack([cam_T_m[:3, 0], cam_T_m[:3, 1], cam_T_m[:3, 3]])
    homography = camera_matrix @ plane @ texture_to_marker
    outline = cv2.perspectiveTransform(
        np.array([[[-0.5, -0.5]], [[n - 0.5, -0.5]], [[n - 0.5, n - 0.5]], [[-0.5, n - 0.5]]]),
        homography).reshape(4, 2)
    x0, y0 = np.maximum(np.floor(outline.min(axis=0)).astype(int) - 1, 0)
    x1, y1 = np.minimum(np.ceil(outline.max(axis=0)).astype(int) + 2,
                        [canvas.shape[1], canvas.shape[0]])
    ss = MARKER_SUPERSAMPLE
    to_fine = pixel_scale(ss) @ np.array([[1.0, 0.0, -x0], [0.0, 1.0, -y0], [0.0, 0.0, 1.0]])
    size = (int(x1 - x0), int(y1 - y0))
    fine = (size[0] * ss, size[1] * ss)
    paint = np.zeros((size[1], size[0], 2), np.float32)
    for channel, source in enumerate((texture, np.ones_like(texture))):
        warped = cv2.warpPerspective(source, to_fine @ homography, fine, flags=cv2.INTER_LINEAR,
                                     borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        paint[..., channel] = cv2.resize(warped, size, interpolation=cv2.INTER_AREA)
    roi = canvas[y0:y1, x0:x1]
    roi[:] = paint[..., 0] + (1.0 - paint[..., 1]) * roi


@functools.lru_cache(maxsize=4)
def _distortion_maps(camera: TipCamera) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """For every pixel of the distorted image, where it lies in the pinhole image."""
    v, u = np.mgrid[0:camera.height, 0:camera.width].astype(np.float64)
    rays = camera.bearings(np.column_stack([u.ravel(), v.ravel()]))
    ideal = rays[:, :2] / rays[:, 2:3] * [camera.fx, camera.fy] + [camera.cx, camera.cy]
    return (ideal[:, 0].reshape(u.shape).astype(np.float32),
            ideal[:, 1].reshape(u.shape).astype(np.float32))


def distort_image(image: NDArray[np.float32], camera: TipCamera) -> NDArray[np.float32]:
    """The pinhole image as the camera with ``camera.distortion`` would record it."""
    map_x, map_y = _distortion_maps(camera)
    return cv2.remap(image, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
