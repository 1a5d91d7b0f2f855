"""What the tip cameras saw, frame by frame: the in-memory sequence.

A :class:`Sequence` holds the robot, one timestamp per frame, per camera the tracks (frame,
track id, pixel), and optionally a base pose per frame (absent: the base is fixed at the world
origin), the ground-truth angles and the image files. Cameras are keyed by the 0-based index of
the segment they ride on (files number them 1..S). Frames are 0-based and consecutive; timestamps
in seconds, strictly increasing; pixels ``(u, v)`` as in OpenCV; angles in radians.

Estimators need two things fast: the observations of camera i in frame f, and the correspondences
of camera i between frames a and b. Tracks are stored sorted by (frame, track id) with an offset per
frame, so both are a slice and a sorted intersection; bearings (unit vectors through
``cv2.undistortPoints``, so distortion is honoured) are computed once per camera.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike

from apcc_graph.model.arrays import FloatArray, IntArray
from apcc_graph.model.camera import validate_pose
from apcc_graph.model.robot import Robot


class Tracks:
    """The observations of one camera, sorted by (frame, track id).

    Args:
        frames: ``(N,)`` 0-based frame of each observation.
        track_ids: ``(N,)`` track id of each observation (non-negative integers).
        uv: ``(N, 2)`` pixel coordinates.

    Raises:
        ValueError: shapes disagree, negative or non-integer ids, non-finite pixels, or a track id
            twice in one frame.
    """

    def __init__(self, frames: ArrayLike, track_ids: ArrayLike, uv: ArrayLike) -> None:
        frames = np.asarray(frames)
        track_ids = np.asarray(track_ids)
        uv = np.asarray(uv, dtype=float).reshape(-1, 2)
        if frames.shape != (len(uv),) or track_ids.shape != (len(uv),):
            raise ValueError(
                f"Tracks: frames {frames.shape}, track_ids {track_ids.shape} and uv {uv.shape} "
                "must describe the same N observations: (N,), (N,), (N, 2)"
            )
        for name, arr in (("frames", frames), ("track_ids", track_ids)):
            if len(arr) and (not np.all(np.isfinite(arr.astype(float)))
                             or np.any(arr != np.round(arr)) or np.any(arr < 0)):
                raise ValueError(f"Tracks.{name}: expected non-negative integers")
        if not np.all(np.isfinite(uv)):
            raise ValueError("Tracks.uv: expected finite pixel coordinates")
        frames = frames.astype(np.int64)
        track_ids = track_ids.astype(np.int64)
        d_frame, d_id = np.diff(frames), np.diff(track_ids)
        if np.all((d_frame > 0) | ((d_frame == 0) & (d_id > 0))):  # sorted, no duplicates
            self.frames, self.track_ids, self.uv = frames, track_ids, uv.copy()
        else:
            order = np.lexsort((track_ids, frames))
            self.frames, self.track_ids, self.uv = frames[order], track_ids[order], uv[order]
        same = (np.diff(self.frames) == 0) & (np.diff(self.track_ids) == 0)
        if same.any():
            i = int(np.flatnonzero(same)[0])
            raise ValueError(
                f"Tracks: track id {self.track_ids[i]} appears twice in frame {self.frames[i]}"
            )
        for arr in (self.frames, self.track_ids, self.uv):
            arr.setflags(write=False)

    def __len__(self) -> int:
        return len(self.frames)

    def offsets(self, n_frames: int) -> IntArray:
        """``(n_frames + 1,)``: the rows of frame f are ``offsets[f]:offsets[f + 1]``."""
        return np.searchsorted(self.frames, np.arange(n_frames + 1)).astype(np.int64)

    def equals(self, other: Tracks) -> bool:
        """Same observations, exactly."""
        return (np.array_equal(self.frames, other.frames)
                and np.array_equal(self.track_ids, other.track_ids)
                and np.array_equal(self.uv, other.uv))


@dataclass(frozen=True)
class Correspondences:
    """The tracks one camera saw in both frames a and b (common track ids, ascending).

    Attributes:
        track_ids: ``(M,)`` the common track ids.
        uv_a, uv_b: ``(M, 2)`` pixels in frames a and b.
        f_a, f_b: ``(M, 3)`` unit bearings in the camera frame at a and b.
    """

    track_ids: IntArray
    uv_a: FloatArray
    uv_b: FloatArray
    f_a: FloatArray
    f_b: FloatArray

    def __len__(self) -> int:
        return len(self.track_ids)


@dataclass(frozen=True)
class FrameObservations:
    """What the tip cameras saw in one frame: the input of the streaming smoother.

    Attributes:
        timestamp: seconds (strictly increasing from frame to frame).
        tracks: camera (0-based segment index) -> ``(track_ids (n,), uv (n, 2))``, pixels as in
            OpenCV; a camera missing here saw nothing in this frame.
        world_T_base: ``(4, 4)`` robot base pose, or ``None`` for a fixed base at the origin.
        bearings: optional camera -> ``(n, 3)`` unit bearings of those pixels (rows as in
            ``tracks``); computed from the camera model when absent.
    """

    timestamp: float
    tracks: Mapping[int, tuple[IntArray, FloatArray]]
    world_T_base: FloatArray | None = None
    bearings: Mapping[int, FloatArray] | None = None


class Sequence:
    """A recorded or simulated sequence (see the module docstring for conventions).

    Args:
        robot: the robot (its cameras say which segments can have tracks).
        timestamps: ``(F,)`` seconds, finite and strictly increasing; F >= 1.
        tracks: camera (0-based segment index) -> :class:`Tracks`; cameras without an entry (or
            with empty Tracks, which are dropped) saw nothing.
        world_T_base: ``(F, 4, 4)`` robot base pose per frame, or ``None`` for a fixed base.
        thetas: ``(F, S)`` ground-truth bending angles (radians), or ``None``.
        psis: ``(F, S)`` ground-truth bending-plane angles (radians), or ``None``.
        images: camera -> {frame: image file}, or ``None``.
        truth_tips: ``(F, S, 4, 4)`` measured ``world_T_tip`` of every segment end (a
            real-motion replay's ground truth), or ``None``.

    Raises:
        ValueError: a value or shape that breaks the conventions; the message names the field.
    """

    def __init__(
        self,
        robot: Robot,
        timestamps: ArrayLike,
        tracks: Mapping[int, Tracks] | None = None,
        world_T_base: ArrayLike | None = None,
        thetas: ArrayLike | None = None,
        psis: ArrayLike | None = None,
        images: Mapping[int, Mapping[int, Path]] | None = None,
        truth_tips: ArrayLike | None = None,
    ) -> None:
        if not isinstance(robot, Robot):
            raise ValueError(f"Sequence.robot: expected a Robot, got {type(robot).__name__}")
        self.robot = robot
        self.timestamps: FloatArray = self._timestamps(timestamps)
        n_frames, n_seg = len(self.timestamps), robot.n_segments
        self.tracks: dict[int, Tracks] = self._tracks(tracks or {}, robot, n_frames)
        self.world_T_base: FloatArray | None = self._base_poses(world_T_base, n_frames)
        self.thetas = self._angles("thetas", thetas, n_frames, n_seg)
        self.psis = self._angles("psis", psis, n_frames, n_seg)
        self.images: dict[int, dict[int, Path]] = self._images(images or {}, robot, n_frames)
        self.truth_tips: FloatArray | None = self._tips(truth_tips, n_frames, n_seg)
        self._offsets: dict[int, IntArray] = {}
        self._bearings: dict[int, FloatArray] = {}

    @staticmethod
    def _timestamps(values: ArrayLike) -> FloatArray:
        ts = np.array(values, dtype=float)
        if ts.ndim != 1 or len(ts) == 0:
            raise ValueError(f"Sequence.timestamps has shape {ts.shape}: expected (F,), F >= 1")
        if not np.all(np.isfinite(ts)):
            raise ValueError("Sequence.timestamps: expected finite values (seconds)")
        if np.any(np.diff(ts) <= 0):
            f = int(np.flatnonzero(np.diff(ts) <= 0)[0]) + 1
            raise ValueError(
                f"Sequence.timestamps: frame {f} at {ts[f]!r} s is not after frame {f - 1} at "
                f"{ts[f - 1]!r} s; expected strictly increasing timestamps"
            )
        ts.setflags(write=False)
        return ts

    @staticmethod
    def _tracks(tracks: Mapping[int, Tracks], robot: Robot, n_frames: int) -> dict[int, Tracks]:
        checked: dict[int, Tracks] = {}
        for cam, trk in sorted(tracks.items()):
            if cam not in robot.camera_segments:
                raise ValueError(
                    f"Sequence.tracks[{cam}]: segment {cam} (camera file cam_{cam + 1}) has no "
                    f"camera in the robot; cameras ride on segments {robot.camera_segments}"
                )
            if not isinstance(trk, Tracks):
                raise ValueError(f"Sequence.tracks[{cam}]: expected Tracks")
            if len(trk) == 0:
                continue  # a camera that saw nothing has no entry
            if len(trk) and trk.frames[-1] >= n_frames:
                raise ValueError(
                    f"Sequence.tracks[{cam}]: an observation in frame {trk.frames[-1]} but the "
                    f"sequence has {n_frames} frames (0..{n_frames - 1})"
                )
            checked[cam] = trk
        return checked

    @staticmethod
    def _base_poses(values: ArrayLike | None, n_frames: int) -> FloatArray | None:
        if values is None:
            return None
        base = np.array(values, dtype=float)
        if base.shape != (n_frames, 4, 4):
            raise ValueError(f"Sequence.world_T_base has shape {base.shape}: expected "
                             f"({n_frames}, 4, 4)")
        for f in range(n_frames):
            base[f] = validate_pose(f"Sequence.world_T_base[{f}]", base[f])
        base.setflags(write=False)
        return base

    @staticmethod
    def _tips(values: ArrayLike | None, n_frames: int, n_seg: int) -> FloatArray | None:
        if values is None:
            return None
        tips = np.array(values, dtype=float)
        if tips.shape != (n_frames, n_seg, 4, 4):
            raise ValueError(f"Sequence.truth_tips has shape {tips.shape}: expected "
                             f"({n_frames}, {n_seg}, 4, 4)")
        for f, i in np.ndindex(n_frames, n_seg):
            tips[f, i] = validate_pose(f"Sequence.truth_tips[{f}, {i}]", tips[f, i])
        tips.setflags(write=False)
        return tips

    @staticmethod
    def _images(images: Mapping[int, Mapping[int, Path]], robot: Robot,
                n_frames: int) -> dict[int, dict[int, Path]]:
        files_of = {cam: {int(f): Path(p) for f, p in sorted(files.items())}
                    for cam, files in sorted(images.items())}
        for cam, files in files_of.items():
            if cam not in robot.camera_segments:
                raise ValueError(f"Sequence.images[{cam}]: segment {cam} has no camera")
            if files and (min(files) < 0 or max(files) >= n_frames):
                raise ValueError(f"Sequence.images[{cam}]: frames must be in 0..{n_frames - 1}")
        return files_of

    @staticmethod
    def _angles(name: str, values: ArrayLike | None, n_frames: int,
                n_seg: int) -> FloatArray | None:
        if values is None:
            return None
        arr = np.array(values, dtype=float)
        if arr.shape != (n_frames, n_seg):
            raise ValueError(f"Sequence.{name} has shape {arr.shape}: expected "
                             f"({n_frames}, {n_seg}), radians per frame and segment")
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"Sequence.{name}: expected finite values (radians)")
        arr.setflags(write=False)
        return arr

    # ------------------------------------------------------------------------------ access
    @property
    def n_frames(self) -> int:
        """Number of frames F."""
        return len(self.timestamps)

    @property
    def n_segments(self) -> int:
        """Number of segments S."""
        return self.robot.n_segments

    @property
    def cameras(self) -> tuple[int, ...]:
        """0-based segments whose camera has tracks in this sequence."""
        return tuple(self.tracks)

    @property
    def has_truth(self) -> bool:
        """Whether ground-truth angles are known."""
        return self.thetas is not None

    def _rows(self, cam: int, frame: int) -> slice:
        if cam not in self.tracks:
            if cam in self.robot.camera_segments:
                return slice(0, 0)
            raise KeyError(f"segment {cam} has no camera")
        if not 0 <= frame < self.n_frames:
            raise IndexError(f"frame {frame} outside 0..{self.n_frames - 1}")
        offsets = self._offsets.get(cam)
        if offsets is None:
            offsets = self._offsets[cam] = self.tracks[cam].offsets(self.n_frames)
        return slice(int(offsets[frame]), int(offsets[frame + 1]))

    def bearings(self, cam: int) -> FloatArray:
        """``(N, 3)`` unit bearings of every observation of a camera (rows as in its Tracks)."""
        out = self._bearings.get(cam)
        if out is None:
            camera = self.robot.cameras[cam]
            assert camera is not None
            out = camera.bearings(self.tracks[cam].uv)
            out.setflags(write=False)
            self._bearings[cam] = out
        return out

    def observations(self, cam: int, frame: int) -> tuple[IntArray, FloatArray]:
        """Track ids ``(n,)`` (ascending) and pixels ``(n, 2)`` of camera ``cam`` in ``frame``."""
        rows = self._rows(cam, frame)
        if cam not in self.tracks:
            return np.zeros(0, np.int64), np.zeros((0, 2))
        trk = self.tracks[cam]
        return trk.track_ids[rows], trk.uv[rows]

    def frame(self, frame: int) -> FrameObservations:
        """Frame ``frame``'s observations, as a streaming estimator receives them.

        Ground truth is not part of it. Bearings come from the per-camera cache.
        """
        tracks: dict[int, tuple[IntArray, FloatArray]] = {}
        bearings: dict[int, FloatArray] = {}
        for cam in self.tracks:
            rows = self._rows(cam, frame)
            if rows.stop > rows.start:
                trk = self.tracks[cam]
                tracks[cam] = (trk.track_ids[rows], trk.uv[rows])
                bearings[cam] = self.bearings(cam)[rows]
        base = None if self.world_T_base is None else self.world_T_base[frame]
        return FrameObservations(float(self.timestamps[frame]), tracks, base, bearings)

    def head(self, n_frames: int) -> Sequence:
        """The first ``n_frames`` frames (tracks, base poses, truth and images cut there).

        Raises:
            ValueError: ``n_frames`` not in ``1 .. F``.
        """
        if not 1 <= n_frames <= self.n_frames:
            raise ValueError(f"Sequence.head: n_frames = {n_frames!r}: expected 1 to "
                             f"{self.n_frames}")
        tracks = {}
        for cam, trk in self.tracks.items():
            keep = trk.frames < n_frames
            tracks[cam] = Tracks(trk.frames[keep], trk.track_ids[keep], trk.uv[keep])
        images = {cam: {f: p for f, p in files.items() if f < n_frames}
                  for cam, files in self.images.items()}

        def cut(x: FloatArray | None) -> FloatArray | None:
            return None if x is None else x[:n_frames]

        return Sequence(self.robot, self.timestamps[:n_frames], tracks, cut(self.world_T_base),
                        cut(self.thetas), cut(self.psis), images)

    def with_robot(self, robot: Robot) -> Sequence:
        """The same recording seen through another model of the robot (e.g. a calibrated one:
        the same cameras, other segment models or mounts).

        Raises:
            ValueError: ``robot`` lacks a camera this sequence has tracks of, or has another
                number of segments than the truth columns.
        """
        return Sequence(robot, self.timestamps, self.tracks, self.world_T_base, self.thetas,
                        self.psis, self.images, self.truth_tips)

    def correspondences(self, cam: int, a: int, b: int) -> Correspondences:
        """The tracks camera ``cam`` saw in both frames a and b, as pixels and bearings."""
        rows_a, rows_b = self._rows(cam, a), self._rows(cam, b)
        if cam not in self.tracks:
            empty2, empty3 = np.zeros((0, 2)), np.zeros((0, 3))
            return Correspondences(np.zeros(0, np.int64), empty2, empty2, empty3, empty3)
        trk = self.tracks[cam]
        ids, ia, ib = np.intersect1d(trk.track_ids[rows_a], trk.track_ids[rows_b],
                                     assume_unique=True, return_indices=True)
        ia = ia + rows_a.start
        ib = ib + rows_b.start
        bearings = self.bearings(cam)
        return Correspondences(ids, trk.uv[ia], trk.uv[ib], bearings[ia], bearings[ib])

    def equals(self, other: Sequence) -> bool:
        """Same robot, timestamps, tracks, base poses and truth, exactly (images not compared)."""

        def same(x: FloatArray | None, y: FloatArray | None) -> bool:
            return (x is None and y is None) or (
                x is not None and y is not None and np.array_equal(x, y))

        return (
            self.robot == other.robot
            and np.array_equal(self.timestamps, other.timestamps)
            and self.tracks.keys() == other.tracks.keys()
            and all(self.tracks[c].equals(other.tracks[c]) for c in self.tracks)
            and same(self.world_T_base, other.world_T_base)
            and same(self.thetas, other.thetas)
            and same(self.psis, other.psis)
        )
