"""Feature tracks from tip-camera images: Shi-Tomasi corners followed by pyramidal Lucas-Kanade.

Per camera, frame by frame (:class:`KLTTracker`):

1. the live tracks are followed from the previous image into the new one with
   ``cv2.calcOpticalFlowPyrLK`` and back again (forward-backward check): a track survives when it
   was found both ways, its round trip ends within ``fb_threshold`` pixels of where it started,
   and it stays inside the image (``border`` pixels from the edge);
2. where tracks have thinned out (fewer than ``min_tracks``), new corners are detected with
   ``cv2.goodFeaturesToTrack`` away from the surviving ones (``min_distance`` pixels) and start new
   tracks with fresh ids.

**Speed** (tracking must keep up with the cameras beside the smoother, live). The pyramid can
be *sized to the motion* (``motion_levels``, off by default: on the live benchmark's rendered
videos it tracked in 0.85x the time at 1.0-1.35x the offline smoother's RMS per segment, two
seeds: ``python tests/tracker_options.py 600 1,2 "" motion_levels=1``). Lucas-Kanade with a
window of radius ``r`` recovers about ``r (2^(L+1) - 1)`` pixels of motion with ``L`` levels
above the image, so a frame uses the fewest levels that cover :data:`MOTION_MARGIN` times the
last frame's 90th-percentile track motion, at most ``levels``; when fewer than half the tracks
survive with fewer levels, the frame is followed again with all of them (a sudden jump loses
no tracks to the smaller pyramid). The mask that keeps new corners away from live tracks is
stamped with numpy in one pass (a drawing call per track made hundreds of calls into OpenCV,
each a wait for the interpreter when another thread holds it).

Pixels follow OpenCV: ``(u, v)`` with the origin at the top-left pixel's centre. Track ids are
non-negative and never reused within one tracker, so the output is the ``Tracks`` of the
sequence format (``tracks/cam_<i>.csv``).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from apcc_graph.io.atomic import atomic_write_text
from apcc_graph.io.console import progress_bar
from apcc_graph.model.arrays import FloatArray, IntArray
from apcc_graph.model.sequence import Tracks

MOTION_MARGIN = 5.0
"""The pyramid covers this many times the last frame's 90th-percentile track motion (pixels)."""


@dataclass(frozen=True)
class TrackerOptions:
    """Parameters of :class:`KLTTracker` (pixels unless stated).

    Attributes:
        max_tracks: corners detected at most per image.
        min_tracks: below this many live tracks, new corners are detected.
        quality: ``goodFeaturesToTrack`` quality level (fraction of the best corner's score).
        min_distance: minimum distance between corners (and to live tracks).
        window: Lucas-Kanade window size.
        levels: pyramid levels above the full image.
        fb_threshold: largest forward-backward round-trip error of a surviving track.
        border: tracks closer than this to the image edge end.
        motion_levels: size the pyramid to the last frame's motion, at most ``levels``
            (module docstring); ``False`` (the default): always ``levels``.
    """

    max_tracks: int = 300
    min_tracks: int = 150
    quality: float = 0.01
    min_distance: float = 10.0
    window: int = 21
    levels: int = 3
    fb_threshold: float = 0.5
    border: float = 2.0
    motion_levels: bool = False

    def __post_init__(self) -> None:
        if not 0 < self.min_tracks <= self.max_tracks:
            raise ValueError(f"TrackerOptions: min_tracks = {self.min_tracks}, max_tracks = "
                             f"{self.max_tracks}: expected 0 < min_tracks <= max_tracks")
        if self.window < 3 or self.window % 2 == 0:
            raise ValueError(f"TrackerOptions.window = {self.window}: expected an odd size >= 3")
        if not (self.fb_threshold > 0 and self.min_distance > 0 and 0 < self.quality < 1
                and self.levels >= 0 and self.border >= 0):
            raise ValueError("TrackerOptions: expected fb_threshold > 0, min_distance > 0, "
                             "0 < quality < 1, levels >= 0, border >= 0")


def gray_image(image: NDArray, shape: tuple[int, int] | None, where: str) -> NDArray[np.uint8]:
    """An 8-bit grey image, checked against the expected ``(height, width)``."""
    image = np.asarray(image)
    if image.ndim == 3 and image.shape[2] in (3, 4):
        image = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY if image.shape[2] == 3
                             else cv2.COLOR_BGRA2GRAY)
    if image.ndim != 2:
        raise ValueError(f"{where}: image of shape {image.shape}: expected (H, W) grey or "
                         "(H, W, 3) colour")
    if shape is not None and image.shape != shape:
        raise ValueError(f"{where}: image is {image.shape[1]}x{image.shape[0]} pixels, expected "
                         f"{shape[1]}x{shape[0]} (the camera's width x height)")
    if image.dtype != np.uint8:
        if np.issubdtype(image.dtype, np.floating) and image.max(initial=0.0) <= 1.0:
            image = image * 255.0
        image = np.clip(image, 0, 255).astype(np.uint8)
    return image


class KLTTracker:
    """Streaming tracker of one camera: :meth:`update` with each image, in order.

    Args:
        size: ``(width, height)`` the images must have (the camera's), or ``None`` to take the
            first image's.
        options: tracker parameters.
    """

    def __init__(self, size: tuple[int, int] | None = None,
                 options: TrackerOptions | None = None) -> None:
        self.options = TrackerOptions() if options is None else options
        self._shape = None if size is None else (int(size[1]), int(size[0]))
        self._previous: NDArray[np.uint8] | None = None
        self._motion: float | None = None  # the last frame's 90th-percentile motion (pixels)
        self.refollowed = 0  # frames followed again with every level (module docstring)
        self._uv = np.zeros((0, 2), dtype=np.float32)
        self._ids = np.zeros(0, dtype=np.int64)
        self._next_id = 0
        self._frame = 0
        o = self.options
        self._lk = dict(winSize=(o.window, o.window), maxLevel=o.levels,
                        criteria=(cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.01))

    def update(self, image: NDArray) -> tuple[IntArray, FloatArray]:
        """Track into the next image; returns the live track ids ``(n,)`` and pixels ``(n, 2)``.

        Raises:
            ValueError: an image of the wrong size or layout (the message names the frame).
        """
        where = f"frame {self._frame}"
        gray = gray_image(image, self._shape, where)
        if self._shape is None:
            self._shape = gray.shape
        if self._previous is not None and len(self._uv):
            self._follow(gray)
        else:
            self._motion = None
        if len(self._uv) < self.options.min_tracks:
            self._detect(gray)
        self._previous = gray
        self._frame += 1
        order = np.argsort(self._ids)
        return self._ids[order].copy(), self._uv[order].astype(float)

    def levels_for(self, motion: float | None) -> int:
        """Pyramid levels above the image for a frame after one whose tracks moved ``motion``
        pixels (90th percentile; ``None``: not known, all ``levels``)."""
        o = self.options
        if motion is None or not o.motion_levels:
            return o.levels
        radius = o.window // 2
        for levels in range(o.levels):
            if radius * (2 ** (levels + 1) - 1) >= MOTION_MARGIN * motion:
                return levels
        return o.levels

    def _follow(self, gray: NDArray[np.uint8]) -> None:
        """Follow the live tracks into ``gray`` (module docstring)."""
        levels = self.levels_for(self._motion)
        fwd, keep = self._flow(gray, levels)
        if levels < self.options.levels and keep.sum() < 0.5 * len(keep):
            self.refollowed += 1  # a jump the smaller pyramid missed: every level
            fwd, keep = self._flow(gray, self.options.levels)
        if self.options.motion_levels:  # only then is the motion used
            moved = np.linalg.norm(fwd[keep] - self._uv[keep], axis=1)
            self._motion = float(np.percentile(moved, 90)) if len(moved) else None
        self._uv, self._ids = fwd[keep].astype(np.float32), self._ids[keep]

    def _flow(self, gray: NDArray[np.uint8], levels: int) -> tuple[NDArray, NDArray[np.bool_]]:
        """The tracks' pixels in ``gray`` with ``levels`` pyramid levels, and which survive the
        check."""
        o = self.options
        assert self._previous is not None
        lk = dict(self._lk, maxLevel=levels)
        prev = self._uv.reshape(-1, 1, 2)
        fwd, st1, _ = cv2.calcOpticalFlowPyrLK(self._previous, gray, prev, None, **lk)
        back, st2, _ = cv2.calcOpticalFlowPyrLK(gray, self._previous, fwd, None, **lk)
        fwd, back = fwd.reshape(-1, 2), back.reshape(-1, 2)
        round_trip = np.linalg.norm(back - self._uv, axis=1)
        h, w = gray.shape
        inside = ((fwd[:, 0] >= o.border) & (fwd[:, 0] <= w - 1 - o.border)
                  & (fwd[:, 1] >= o.border) & (fwd[:, 1] <= h - 1 - o.border))
        keep = (st1.ravel() == 1) & (st2.ravel() == 1) & (round_trip < o.fb_threshold) & inside
        return fwd, keep

    def _detect(self, gray: NDArray[np.uint8]) -> None:
        o = self.options
        mask = away_from(gray.shape, self._uv, int(o.min_distance))
        wanted = o.max_tracks - len(self._uv)
        if wanted <= 0:
            return
        corners = cv2.goodFeaturesToTrack(gray, wanted, o.quality, o.min_distance, mask=mask,
                                          blockSize=7)
        if corners is None:
            return
        corners = corners.reshape(-1, 2)
        if len(corners):
            cv2.cornerSubPix(gray, corners, (5, 5), (-1, -1),
                             (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 20, 0.01))
        ids = np.arange(self._next_id, self._next_id + len(corners), dtype=np.int64)
        self._next_id += len(corners)
        self._uv = np.concatenate([self._uv, corners.astype(np.float32)])
        self._ids = np.concatenate([self._ids, ids])


def away_from(shape: tuple[int, ...], uv: NDArray, radius: int) -> NDArray[np.uint8]:
    """A mask of an image of ``shape`` ``(H, W)``: 255, but 0 within ``radius`` pixels of each
    point ``uv`` ``(N, 2)`` (rounded to the nearest pixel), as ``cv2.circle`` fills them."""
    h, w = shape[:2]
    mask = np.full((h, w), 255, dtype=np.uint8)
    if len(uv) == 0:
        return mask
    dv, du = np.mgrid[-radius:radius + 1, -radius:radius + 1]
    disk = du**2 + dv**2 <= radius**2
    du, dv = du[disk], dv[disk]
    centres = np.rint(np.asarray(uv, dtype=float)).astype(np.int64)
    u = (centres[:, :1] + du).ravel()
    v = (centres[:, 1:] + dv).ravel()
    inside = (u >= 0) & (u < w) & (v >= 0) & (v < h)
    mask[v[inside], u[inside]] = 0
    return mask


def track_images(images: Iterable[NDArray], size: tuple[int, int] | None = None,
                 options: TrackerOptions | None = None) -> Tracks:
    """Track a camera's images (in frame order) into the sequence format's :class:`Tracks`."""
    return tracks_of(KLTTracker(size, options),
                     ((f, image, f"frame {f}") for f, image in enumerate(images)))


def tracks_of(tracker: KLTTracker, images: Iterable[tuple[int, NDArray, str]],
              on_image: Callable[[], object] | None = None) -> Tracks:
    """The :class:`Tracks` of ``(frame, image, where)`` in order, followed by ``tracker``
    (``where`` names the image in errors; ``on_image`` is called after each).

    Raises:
        ValueError: an image of the wrong size or layout, named by its ``where``.
    """
    frames, ids, uvs = [], [], []
    for f, image, where in images:
        try:
            track_ids, uv = tracker.update(image)
        except ValueError as error:
            raise ValueError(f"{where}: {error}") from None
        frames.append(np.full(len(track_ids), f, dtype=np.int64))
        ids.append(track_ids)
        uvs.append(uv)
        if on_image is not None:
            on_image()
    if not frames:
        return Tracks(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 2)))
    return Tracks(np.concatenate(frames), np.concatenate(ids), np.concatenate(uvs))


def track_sequence(folder: str | Path, force: bool = False,
                   options: TrackerOptions | None = None, progress: bool = False) -> list[Path]:
    """Track the images of a sequence folder and write ``tracks/cam_<i>.csv``.

    Every camera with an ``images/cam_<i>/`` folder must have one image per frame. The
    ``tracks/`` folder is replaced whole, and only after every camera was tracked, so a failure
    or Ctrl-C leaves the folder as it was.

    Args:
        folder: the sequence folder (``robot.toml``, ``frames.csv``, ``images/``).
        force: replace tracks files that already hold observations.
        options: tracker parameters.
        progress: show a progress bar.

    Returns:
        The tracks files written.

    Raises:
        ValueError: no images, an image missing or unreadable, of the wrong size for its camera,
            or existing tracks without ``force``; the message names the file.
    """
    from apcc_graph.io.sequence_folder import load_sequence, tracks_csv

    folder = Path(folder)
    sequence = load_sequence(folder)
    if not sequence.images:
        raise ValueError(f"{folder / 'images'}: no images to track (expected "
                         "images/cam_<i>/<frame:06d>.png)")
    targets = {cam: folder / "tracks" / f"cam_{cam + 1}.csv" for cam in sequence.images}
    if not force:
        for cam, target in targets.items():
            if cam in sequence.tracks and len(sequence.tracks[cam]):
                raise ValueError(f"{target}: already holds {len(sequence.tracks[cam])} "
                                 "observations; use --force to replace them")
    texts = {}
    total = sum(sequence.n_frames for _ in sequence.images)
    with progress_bar(total=total, desc="track", unit="image", progress=progress) as bar:
        for cam, files in sequence.images.items():
            camera = sequence.robot.cameras[cam]
            assert camera is not None
            tracker = KLTTracker((camera.width, camera.height), options)
            images = _folder_images(folder, cam, files, sequence.n_frames)
            texts[cam] = tracks_csv(tracks_of(tracker, images, bar.update))
    return _write_tracks(folder / "tracks", {targets[cam].name: text
                                             for cam, text in texts.items()})


def _write_tracks(tracks_dir: Path, texts: dict[str, str]) -> list[Path]:
    """The ``tracks/`` folder replaced whole by one holding ``texts`` (file name -> text) and
    everything else it held (sub-folders, hidden files and symlinks as they are): written
    beside it and swapped in when complete."""
    import shutil

    from apcc_graph.io.output_folder import staged_folder

    with staged_folder(tracks_dir, replace=True) as staging:
        if tracks_dir.is_dir():
            for kept in tracks_dir.iterdir():
                if kept.name in texts or kept == staging:
                    continue
                if kept.is_dir() and not kept.is_symlink():
                    shutil.copytree(kept, staging / kept.name, symlinks=True)
                else:
                    shutil.copy2(kept, staging / kept.name, follow_symlinks=False)
        for name, text in texts.items():
            atomic_write_text(staging / name, text)
    return [tracks_dir / name for name in texts]


def _folder_images(folder: Path, cam: int, files: dict[int, Path], n_frames: int
                   ) -> Iterator[tuple[int, NDArray, str]]:
    """Camera ``cam``'s images of a sequence folder, one per frame, read in order.

    Raises:
        ValueError: an image missing or unreadable, named by its file.
    """
    for f in range(n_frames):
        path = files.get(f, folder / "images" / f"cam_{cam + 1}" / f"{f:06d}.png")
        if f not in files or not path.is_file():
            raise ValueError(f"{path}: missing; camera {cam + 1} needs one image per frame "
                             f"(0..{n_frames - 1})")
        image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        if image is None:
            raise ValueError(f"{path}: not a readable image")
        yield f, image, str(path)
