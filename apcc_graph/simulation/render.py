"""Rendered tip-camera images of a textured room, so the pipeline can be tested on pixels.

The scene is the simulator's ``"room"``: an axis-aligned box (``centre``, ``half_size``, metres,
world frame) seen from inside. Each of its six walls carries a greyscale texture, tiled at
``texels_per_metre``. A view is rendered by casting one ray per (sub)pixel: the ray's bearing comes
from :meth:`TipCamera.bearings` (so lens distortion is honoured), the nearest wall it hits gives
the texture coordinates, and one ``cv2.remap`` over a texture atlas does the bilinear lookup.
``supersample`` rays per pixel side are averaged by ``cv2.resize(INTER_AREA)`` against aliasing.

Wall order and texture axes, for wall ``(axis, side)`` with ``side`` -1 (the ``min`` wall) or +1:
walls are ``-x, +x, -y, +y, -z, +z``; the texture's column runs along the first of the other two
world axes and its row along the second (for the x walls: y then z; y walls: x then z; z walls:
x then y), from the box's minimum corner.

Sensor effects (:class:`SensorModel`) act on the rendered irradiance in [0, 1]: an exposure gain,
an optional Gaussian blur, Gaussian read noise in grey levels, then rounding to 8 bits.

Textures come from scikit-image's bundled images (``texture_source="skimage"``; they ship inside
the wheel and load offline: ``pip install apcc-graph[images]``) or from seeded multi-scale noise
(``"procedural"``, no extra dependency). Same seed, same images.
"""

from __future__ import annotations

import math
import os
import shutil
import tempfile
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from apcc_graph.io.atomic import folder_mode
from apcc_graph.io.console import progress_bar
from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.camera import TipCamera

TEXTURE_SOURCES = ("skimage", "procedural")
SKIMAGE_TEXTURES = ("brick", "camera", "grass", "astronaut", "coffee", "gravel")
"""scikit-image images for the walls ``-x, +x, -y, +y, -z, +z`` (all ship with the wheel). The
ceiling (+z), which tip cameras of an upright robot see most, gets the richest texture."""
TEXTURE_SIZE = 512
"""Side of a texture tile (texels)."""
_PAD = 2
"""Wrap-around border of each atlas tile, so bilinear lookups at a tile's edge stay seamless."""


@dataclass(frozen=True, eq=False)
class TexturedRoom:
    """A box seen from inside, with one texture tile per wall.

    Attributes:
        centre: ``(3,)`` box centre in the world frame (metres).
        half_size: ``(3,)`` half extents (metres), all > 0.
        textures: six ``(TEXTURE_SIZE, TEXTURE_SIZE)`` float32 tiles in [0, 1], in wall order.
        texels_per_metre: texture scale on the walls.
    """

    centre: FloatArray
    half_size: FloatArray
    textures: tuple[NDArray[np.float32], ...]
    texels_per_metre: float = 256.0
    _atlas: NDArray[np.float32] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        centre = np.asarray(self.centre, dtype=float).reshape(-1)
        half = np.asarray(self.half_size, dtype=float).reshape(-1)
        if centre.shape != (3,) or not np.all(np.isfinite(centre)):
            raise ValueError(f"centre = {self.centre!r}: expected 3 finite numbers (metres)")
        if half.shape != (3,) or not np.all(np.isfinite(half)) or not np.all(half > 0):
            raise ValueError(f"half_size = {self.half_size!r}: expected 3 numbers > 0 (metres)")
        if len(self.textures) != 6:
            raise ValueError(f"textures: expected 6 tiles (one per wall), got {len(self.textures)}")
        for i, tile in enumerate(self.textures):
            if tile.shape != (TEXTURE_SIZE, TEXTURE_SIZE):
                raise ValueError(f"textures[{i}]: shape {tile.shape}, expected "
                                 f"({TEXTURE_SIZE}, {TEXTURE_SIZE})")
        if not (math.isfinite(self.texels_per_metre) and self.texels_per_metre > 0):
            raise ValueError(f"texels_per_metre = {self.texels_per_metre!r}: expected > 0")
        object.__setattr__(self, "centre", centre)
        object.__setattr__(self, "half_size", half)
        tiles = [np.pad(t.astype(np.float32), _PAD, mode="wrap") for t in self.textures]
        object.__setattr__(self, "_atlas", np.ascontiguousarray(np.hstack(tiles)))

    def contains(self, point: FloatArray, margin: float = 0.0) -> bool:
        """True if ``point`` lies inside the box, at least ``margin`` metres from every wall."""
        return bool(np.all(np.abs(np.asarray(point) - self.centre) < self.half_size - margin))

    def intersect(self, origin: FloatArray, directions: NDArray,
                  ) -> tuple[NDArray, NDArray[np.int64]]:
        """Distance along each ray to the wall it hits, and that wall's index.

        Args:
            origin: ``(3,)`` ray origin inside the box (world, metres).
            directions: ``(3, N)`` ray directions, one per column (any length; the distance is
                in their units). float32 or float64; the result has the same precision.

        Returns:
            ``t`` ``(N,)`` with ``origin + t direction`` on the wall, and the wall index ``(N,)``
            (``2 axis + (direction[axis] >= 0)``).
        """
        d = np.asarray(directions)
        dtype = d.dtype.type
        p = np.asarray(origin, dtype=float).reshape(3)
        to_hi = (self.centre + self.half_size - p).astype(dtype)
        to_lo = (self.centre - self.half_size - p).astype(dtype)
        t_axis = []
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            for a in range(3):
                inv = 1 / d[a]
                # From inside the box one of the two walls is ahead (t > 0), the other behind.
                t_axis.append(np.maximum(to_hi[a] * inv, to_lo[a] * inv))
        t = np.minimum(np.minimum(t_axis[0], t_axis[1]), t_axis[2])
        axis = np.where(t_axis[0] == t, 0, np.where(t_axis[1] == t, 1, 2))
        positive = np.where(axis == 0, d[0], np.where(axis == 1, d[1], d[2])) >= 0
        return t, 2 * axis + positive

    def _texels(self, origin: FloatArray, directions: NDArray, t: NDArray,
                wall: NDArray[np.int64]) -> tuple[NDArray, NDArray]:
        """Atlas column and row of the points ``origin + t directions`` (``(3, N)``)."""
        axis = wall // 2
        dtype = directions.dtype.type
        rel = (np.asarray(origin) - (self.centre - self.half_size)).astype(dtype)
        s = dtype(self.texels_per_metre)
        x = rel[0] + t * directions[0]
        y = rel[1] + t * directions[1]
        z = rel[2] + t * directions[2]
        col = np.where(axis == 0, y, x) * s
        row = np.where(axis == 2, y, z) * s
        # Tiles repeat: a non-periodic image shows a straight seam every tile, which is a fixed
        # edge of the wall like any other. (Mirrored tiles would hide the seam but make
        # kaleidoscope patterns whose look-alike patches pull Lucas-Kanade onto the wrong twin.)
        period = TEXTURE_SIZE
        inv = dtype(1.0 / period)
        col -= np.floor(col * inv) * dtype(period)  # np.mod, without its sign handling
        row -= np.floor(row * inv) * dtype(period)
        col += wall.astype(dtype) * dtype(period + 2 * _PAD) + dtype(_PAD)
        row += dtype(_PAD)
        return col, row

    def render(self, camera: TipCamera, world_T_cam: FloatArray, supersample: int = 2,
               ) -> NDArray[np.float32]:
        """The irradiance image ``(height, width)`` in [0, 1] seen by ``camera`` at a pose.

        Args:
            camera: the tip camera (intrinsics and distortion; its ``tip_T_cam`` is not used).
            world_T_cam: ``(4, 4)`` camera pose in the world frame; the camera must be inside
                the box.
            supersample: rays per pixel side (1 = one ray through each pixel centre).

        Raises:
            ValueError: the camera is outside the box, or ``supersample < 1``.
        """
        if supersample < 1:
            raise ValueError(f"supersample = {supersample}: expected >= 1")
        pose = np.asarray(world_T_cam, dtype=float)
        origin = pose[:3, 3]
        if not self.contains(origin):
            raise ValueError(f"camera at {np.round(origin, 3).tolist()} is outside the "
                             f"room (centre {self.centre.tolist()}, half size "
                             f"{self.half_size.tolist()})")
        rays = _ray_grid(camera, supersample)
        directions = pose[:3, :3].astype(np.float32) @ rays
        t, wall = self.intersect(origin, directions)
        col, row = self._texels(origin, directions, t, wall)
        h, w = camera.height * supersample, camera.width * supersample
        big = cv2.remap(self._atlas, col.reshape(h, w), row.reshape(h, w), cv2.INTER_LINEAR)
        if supersample == 1:
            return big
        return cv2.resize(big, (camera.width, camera.height), interpolation=cv2.INTER_AREA)

    def backproject(self, camera: TipCamera, world_T_cam: FloatArray, pixels: FloatArray,
                    ) -> FloatArray:
        """``(N, 3)`` world points on the walls seen at ``pixels`` (the renderer's geometry)."""
        pose = np.asarray(world_T_cam, dtype=float)
        directions = pose[:3, :3] @ camera.bearings(pixels).T
        t, _ = self.intersect(pose[:3, 3], directions)
        return pose[:3, 3] + (t * directions).T


_RAY_CACHE: dict[tuple[TipCamera, int], FloatArray] = {}


def _ray_grid(camera: TipCamera, supersample: int) -> FloatArray:
    """Camera-frame bearings ``(3, H s * W s)`` through the sub-pixel centres (row-major)."""
    key = (camera, supersample)
    rays = _RAY_CACHE.get(key)
    if rays is None:
        s = supersample
        # Sub-pixel centres: pixel u covers [u - 1/2, u + 1/2] (OpenCV's centre convention).
        us = (np.arange(camera.width * s) + 0.5) / s - 0.5
        vs = (np.arange(camera.height * s) + 0.5) / s - 0.5
        uu, vv = np.meshgrid(us, vs)
        uv = np.column_stack([uu.ravel(), vv.ravel()])
        rays = np.ascontiguousarray(camera.bearings(uv).T, dtype=np.float32)
        if len(_RAY_CACHE) > 8:
            _RAY_CACHE.clear()
        _RAY_CACHE[key] = rays
    return rays  # type: ignore[return-value]


# ------------------------------------------------------------------------------------ textures
def _normalise(image: NDArray) -> NDArray[np.float32]:
    """A greyscale float tile of TEXTURE_SIZE, contrast-stretched to the 1st-99th percentile."""
    img = np.asarray(image)
    if img.ndim == 3:
        img = cv2.cvtColor(img[..., :3].astype(np.uint8), cv2.COLOR_RGB2GRAY)
    img = img.astype(np.float32)
    side = min(img.shape)
    r0, c0 = (img.shape[0] - side) // 2, (img.shape[1] - side) // 2
    img = img[r0:r0 + side, c0:c0 + side]
    img = cv2.resize(img, (TEXTURE_SIZE, TEXTURE_SIZE), interpolation=cv2.INTER_AREA)
    lo, hi = np.percentile(img, [1.0, 99.0])
    return np.clip((img - lo) / max(hi - lo, 1e-6), 0.0, 1.0).astype(np.float32)


def skimage_textures() -> tuple[NDArray[np.float32], ...]:
    """The six wall tiles from scikit-image's bundled images (:data:`SKIMAGE_TEXTURES`).

    Raises:
        ImportError: scikit-image is not installed (with the install command).
    """
    try:
        import skimage.data
    except ImportError as error:
        raise ImportError("rendered textures from scikit-image need the images extra: pip "
                          "install 'apcc-graph[images]' (or use texture_source='procedural')"
                          ) from error
    return tuple(_normalise(getattr(skimage.data, name)()) for name in SKIMAGE_TEXTURES)


def procedural_textures(seed: int = 0) -> tuple[NDArray[np.float32], ...]:
    """Six seeded multi-scale noise tiles (no extra dependency); they tile seamlessly."""
    rng = np.random.default_rng(seed)
    tiles = []
    for _ in range(6):
        acc = np.zeros((TEXTURE_SIZE, TEXTURE_SIZE), np.float32)
        for octave, weight in ((8, 1.0), (32, 0.6), (128, 0.4), (512, 0.25)):
            coarse = rng.random((octave, octave)).astype(np.float32)
            # Periodic upsampling: wrap-pad, resize, crop, so the tile repeats without a seam.
            pad = np.pad(coarse, 1, mode="wrap")
            scale = TEXTURE_SIZE // octave
            big = cv2.resize(pad, ((octave + 2) * scale, (octave + 2) * scale),
                             interpolation=cv2.INTER_CUBIC)
            acc += weight * big[scale:scale + TEXTURE_SIZE, scale:scale + TEXTURE_SIZE]
        tiles.append(_normalise(acc))
    return tuple(tiles)


def textured_room(centre: FloatArray, half_size: FloatArray, texture_source: str = "skimage",
                  seed: int = 0, texels_per_metre: float = 256.0) -> TexturedRoom:
    """A :class:`TexturedRoom` with textures from ``texture_source`` (see :data:`TEXTURE_SOURCES`).

    ``seed`` seeds the procedural textures; the scikit-image walls are always the same.
    """
    if texture_source == "skimage":
        textures = skimage_textures()
    elif texture_source == "procedural":
        textures = procedural_textures(seed)
    else:
        raise ValueError(f"texture_source = {texture_source!r}: expected one of "
                         f"{TEXTURE_SOURCES}")
    return TexturedRoom(np.asarray(centre, float), np.asarray(half_size, float), textures,
                        texels_per_metre)


# ------------------------------------------------------------------------------------- sensor
@dataclass(frozen=True)
class SensorModel:
    """What the camera does to the irradiance: exposure, blur, noise, 8-bit quantisation.

    Attributes:
        noise_grey: standard deviation of Gaussian read noise (grey levels of 255).
        blur_sigma: Gaussian blur (pixels); 0 for none.
        exposure_change: largest relative change of the exposure gain over a sequence (the
            gain follows a smooth random curve within ``1 +/- exposure_change``); 0 for none.
        brightness: grey level of irradiance 1 at gain 1 (the image's white).
    """

    noise_grey: float = 2.0
    blur_sigma: float = 0.0
    exposure_change: float = 0.0
    brightness: float = 220.0

    def __post_init__(self) -> None:
        for name in ("noise_grey", "blur_sigma", "exposure_change"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"{name} = {value!r}: expected a finite value >= 0")
        if self.exposure_change >= 1.0:
            raise ValueError(f"exposure_change = {self.exposure_change!r}: expected < 1")
        if not 0 < self.brightness <= 255:
            raise ValueError(f"brightness = {self.brightness!r}: expected 0 < b <= 255")

    def gains(self, n_frames: int, rng: np.random.Generator) -> FloatArray:
        """``(n_frames,)`` exposure gains: a smooth random curve in ``1 +/- exposure_change``."""
        if self.exposure_change == 0.0:
            return np.ones(n_frames)
        t = np.arange(n_frames) / 30.0
        freqs = rng.uniform(0.1, 0.5, 3)
        phases = rng.uniform(0, 2 * math.pi, 3)
        curve = np.mean(np.sin(2 * math.pi * freqs * t[:, None] + phases), axis=1)
        return 1.0 + self.exposure_change * curve / max(np.max(np.abs(curve)), 1e-9)

    def expose(self, irradiance: NDArray[np.float32], rng: np.random.Generator,
               gain: float = 1.0) -> NDArray[np.uint8]:
        """An 8-bit image from an irradiance image in [0, 1]."""
        img = irradiance.astype(np.float32) * np.float32(self.brightness * gain)
        if self.blur_sigma > 0:
            img = cv2.GaussianBlur(img, (0, 0), self.blur_sigma)
        if self.noise_grey > 0:
            img = img + rng.normal(0.0, self.noise_grey, img.shape).astype(np.float32)
        return np.clip(np.rint(img), 0, 255).astype(np.uint8)


# --------------------------------------------------------------------------------- sequences
def render_images(room: TexturedRoom, camera: TipCamera, world_T_cam: FloatArray,
                  sensor: SensorModel | None = None, seed: int = 0, supersample: int = 2,
                  ) -> Iterator[NDArray[np.uint8]]:
    """8-bit images of one camera along its poses ``(F, 4, 4)``, in frame order (lazily)."""
    sensor = SensorModel() if sensor is None else sensor
    rng = np.random.default_rng(seed)
    gains = sensor.gains(len(world_T_cam), rng)
    for pose, gain in zip(world_T_cam, gains, strict=True):
        yield sensor.expose(room.render(camera, pose, supersample), rng, float(gain))


def write_sequence_images(folder: str | Path, room: TexturedRoom,
                          cameras: dict[int, TipCamera], world_T_cam: dict[int, FloatArray],
                          sensor: SensorModel | None = None, seed: int = 0,
                          supersample: int = 2, progress: bool = False,
                          on_image: Callable[[], None] | None = None) -> Path:
    """Render every camera's images into ``folder/images/cam_<i>/<frame:06d>.png``.

    Images are written into a temporary folder next to ``images/`` and moved into place when all
    are done, so a failure leaves no half-written image set. An existing ``images/`` is replaced.

    Args:
        folder: the sequence folder.
        room: the textured scene.
        cameras: camera index (0-based segment) -> camera.
        world_T_cam: camera index -> ``(F, 4, 4)`` poses.
        sensor: sensor effects (default :class:`SensorModel`).
        seed: seed of the sensor noise and exposure (camera ``i`` uses ``seed + i``).
        supersample: rays per pixel side.
        progress: show a progress bar.
        on_image: called after each image (for progress reporting by callers).

    Returns:
        The ``images`` folder.
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=".images-", dir=folder))
    os.chmod(staging, folder_mode())  # as a folder made with mkdir, not mkdtemp's 0700
    total = sum(len(p) for p in world_T_cam.values())
    try:
        with progress_bar(total=total, desc="render", unit="image", progress=progress) as bar:
            for cam, poses in world_T_cam.items():
                cam_dir = staging / f"cam_{cam + 1}"
                cam_dir.mkdir()
                images = render_images(room, cameras[cam], poses, sensor, seed + cam,
                                       supersample)
                for f, image in enumerate(images):
                    path = cam_dir / f"{f:06d}.png"
                    if not cv2.imwrite(str(path), image):
                        raise OSError(f"{path}: could not write the image")
                    bar.update()
                    if on_image is not None:
                        on_image()
        target = folder / "images"
        if target.exists():
            old = Path(tempfile.mkdtemp(prefix=".images-old-", dir=folder))
            os.replace(target, old / "images")
            os.replace(staging, target)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(staging, target)
        return target
    finally:
        if staging.exists():
            shutil.rmtree(staging, ignore_errors=True)
