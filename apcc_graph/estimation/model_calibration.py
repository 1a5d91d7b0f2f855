"""What a self-calibrating batch estimates beside the frames: each segment's ``k`` and
``delta_max``, and each observed camera's mounting ``tip_T_cam`` (docs/estimation.md,
"Self-calibration").

Variables: a ``Vector2`` ``(k, delta_max)`` per segment
(:func:`~apcc_graph.factors.keys.calibration_key`) and a ``Pose3`` per camera
(:func:`~apcc_graph.factors.keys.mount_key`), each with a prior around the robot file's
value. A mount's tangent is gtsam's, ``tip_T_cam . Exp(xi)`` with ``xi = (omega, v)`` in the
camera frame, so its standard deviations are three rotations (radians) then three translations
(metres) about and along the camera's axes.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass, replace

import gtsam
import numpy as np

from apcc_graph.factors.keys import calibration_key, mount_key
from apcc_graph.factors.projection import calibrated
from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.robot import Robot
from apcc_graph.model.segment import Segment

MOUNT_SIGMAS = (math.radians(5.0), 0.01)
"""Default prior standard deviations of a calibrated mount around the robot file's: 5 deg and
10 mm on each axis, looser than a mount measured by hand is off (a few degrees and
millimetres)."""


@dataclass(frozen=True)
class ModelCalibration:
    """The calibrated model parameters (a value, or their standard deviations).

    Attributes:
        segments: ``(S, 2)`` each segment's ``(k, delta_max)`` (radians), or ``None`` when
            the segment models are held.
        mounts: ``(camera, value)`` per calibrated camera: its ``(4, 4)`` ``tip_T_cam`` or,
            for standard deviations, ``(6,)`` (radians, then metres).
    """

    segments: FloatArray | None = None
    mounts: tuple[tuple[int, FloatArray], ...] = ()

    @classmethod
    def of(cls, robot: Robot, segments: bool, cameras: Iterable[int]) -> ModelCalibration:
        """The robot file's values of what is calibrated: the segment models when
        ``segments``, the mounts of ``cameras``."""
        seg = np.array([[s.k, s.delta_max] for s in robot.segments]) if segments else None
        mounts = []
        for c in cameras:
            camera = robot.cameras[c]
            if camera is None:
                raise ValueError(f"segment {c + 1} has no camera: its mount cannot be calibrated")
            mounts.append((int(c), np.array(camera.tip_T_cam, dtype=float)))
        return cls(seg, tuple(mounts))

    @property
    def empty(self) -> bool:
        """Nothing is calibrated."""
        return self.segments is None and not self.mounts

    @property
    def size(self) -> int:
        """The variables' tangent dimension: two per segment, six per mount."""
        return (0 if self.segments is None else self.segments.size) + 6 * len(self.mounts)

    def keys(self) -> list[int]:
        """The variables' keys: the segments', then the mounts'."""
        seg = [] if self.segments is None else [calibration_key(j)
                                                 for j in range(len(self.segments))]
        return seg + [mount_key(c) for c, _ in self.mounts]

    def insert(self, values: gtsam.Values) -> None:
        """Insert the variables into ``values``."""
        if self.segments is not None:
            for j, kd in enumerate(self.segments):
                values.insert(calibration_key(j), np.asarray(kd, dtype=float))
        for c, tip_T_cam in self.mounts:
            values.insert(mount_key(c), gtsam.Pose3(tip_T_cam))

    def read(self, values: gtsam.Values) -> ModelCalibration:
        """The same variables' values in ``values``."""
        seg = (None if self.segments is None else
               np.array([values.atVector(calibration_key(j)) for j in range(len(self.segments))]))
        return ModelCalibration(seg, tuple((c, values.atPose3(mount_key(c)).matrix())
                                           for c, _ in self.mounts))

    def sigmas_from(self, tail: FloatArray) -> ModelCalibration:
        """Standard deviations from ``tail``, the variables' in :meth:`keys` order (two per
        segment, six per mount)."""
        tail = np.asarray(tail, dtype=float)
        n = 0 if self.segments is None else 2 * len(self.segments)
        seg = None if self.segments is None else tail[:n].reshape(-1, 2)
        return ModelCalibration(seg, tuple((c, tail[n + 6 * i:n + 6 * i + 6])
                                           for i, (c, _) in enumerate(self.mounts)))

    def segment_models(self, robot: Robot) -> tuple[Segment, ...] | None:
        """The robot's segments with the calibrated ``k`` and ``delta_max`` (clamped to their
        valid ranges), or ``None`` when they are held."""
        if self.segments is None:
            return None
        return tuple(calibrated(s, k, d)
                     for s, (k, d) in zip(robot.segments, self.segments, strict=True))

    def mount(self, camera: int) -> FloatArray | None:
        """Camera ``camera``'s calibrated ``tip_T_cam``, or ``None`` when it is held."""
        return next((m for c, m in self.mounts if c == camera), None)

    def robot(self, robot: Robot) -> Robot:
        """``robot`` with the calibrated segment models and mounts."""
        segments = self.segment_models(robot) or robot.segments
        cameras = list(robot.cameras)
        for c, tip_T_cam in self.mounts:
            camera = cameras[c]
            assert camera is not None
            cameras[c] = replace(camera, tip_T_cam=tip_T_cam)
        return Robot(segments, cameras)

    def mount_table(self, n_segments: int) -> FloatArray | None:
        """``(S, 6)`` the mounts' values (standard deviations) per segment's camera, NaN where
        a mount is held; ``None`` when none is calibrated."""
        if not self.mounts:
            return None
        out = np.full((n_segments, 6), np.nan)
        for c, v in self.mounts:
            out[c] = v
        return out


def mount_change(found: FloatArray, given: FloatArray) -> FloatArray:
    """``(6,)`` how far mount ``found`` is from ``given`` in the mount's tangent
    (``found = given . Exp(xi)``): rotations about the camera's axes (radians), then
    translations along them (metres); the units of the mount sigmas."""
    return np.asarray(gtsam.Pose3(np.asarray(given, dtype=float)).localCoordinates(
        gtsam.Pose3(np.asarray(found, dtype=float))), dtype=float)


def mount_error(found: FloatArray, truth: FloatArray) -> tuple[float, float]:
    """The rotation angle (radians) and translation length (metres) of
    ``truth^-1 . found``, the error of a mount ``found`` against ``truth``."""
    error = gtsam.Pose3(np.asarray(truth, dtype=float)).between(
        gtsam.Pose3(np.asarray(found, dtype=float)))
    return (float(np.linalg.norm(gtsam.Rot3.Logmap(error.rotation()))),
            float(np.linalg.norm(error.translation())))
