"""Measuring a new frame for the epipolar smoother: pairing, gating, relocation, factor building.

Camera by camera from the base, the new frame is paired with every earlier frame ``gap`` frames
back (``GraphOptions.gaps``) and with every keyframe, still in the window, with which the camera
shares at least ``min_shared`` tracks and whose camera position lies at least ``min_baseline``
away (no parallax otherwise). One generalized epipolar factor over those pairs
(:class:`apcc_graph.factors.epipolar.EpipolarFrameFactor`) gates the correspondences at the
prediction.

The front end's check: the correspondences with the latest earlier frame that shares tracks
with this one (the previous frame, or the last one before a blackout) must fall inside the gate
for at least ``agreement`` of them. Otherwise, or when the prediction shows no parallax to
check, 1-point RANSAC (:func:`apcc_graph.frontend.ransac.one_point_ransac`) re-initialises the
segment's angle from that pair and the factor is rebuilt there.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from typing import NamedTuple

import gtsam
import numpy as np
from numpy.typing import NDArray

from apcc_graph.estimation.epipolar_graph import angle_key
from apcc_graph.estimation.online_calibration import SYMBOL_KEYS, OnlineCalibration
from apcc_graph.estimation.options import GraphOptions, loss_scale, reuse_factor
from apcc_graph.estimation.smoother_options import EpipolarSmootherOptions
from apcc_graph.estimation.window import Window, observed_camera
from apcc_graph.factors.epipolar import EpipolarFrameFactor
from apcc_graph.frontend.ransac import one_point_ransac
from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.camera import TipCamera
from apcc_graph.model.robot import Robot
from apcc_graph.model.scalar_kinematics import apcc_transform_scalar
from apcc_graph.model.segment import Segment
from apcc_graph.model.sequence import FrameObservations

CHECK_BASELINE = 1e-4
"""Metres: below this the front end's check has no parallax to judge the prediction by."""


@dataclass
class StoredFrame:
    """What the epipolar smoother keeps of a frame while it can still be paired.

    Attributes:
        index: the frame's index.
        timestamp: seconds.
        base: ``(4, 4)`` world pose of the robot's base.
        ids: camera -> ``(n,)`` track ids, ascending.
        bearings: camera -> ``(n, 3)`` unit bearings, in the order of ``ids``.
        cam_positions: camera -> ``(3,)`` world position at the frame's latest estimate.
        stamp: gtsam timestamp of the frame's variables (seconds).
    """

    index: int
    timestamp: float
    base: FloatArray
    ids: dict[int, NDArray[np.int64]]
    bearings: dict[int, FloatArray]
    cam_positions: dict[int, FloatArray] = field(default_factory=dict)
    stamp: float = 0.0


class FramePair(NamedTuple):
    """One camera's correspondences between an earlier frame and the new one."""

    earlier: StoredFrame
    f_a: FloatArray  # (n, 3) unit bearings in the earlier frame
    f_b: FloatArray  # (n, 3) unit bearings in the new frame


class Measured(NamedTuple):
    """Camera ``camera``'s epipolar factor over its pairs with the new frame."""

    camera: int
    pairs: list[FramePair]
    factor: EpipolarFrameFactor


class EpipolarFrontEnd:
    """The frames the epipolar smoother can still pair with, and the measurement of a new one.

    Args:
        robot: the robot.
        options: graph construction (gaps, gates, losses).
        settings: the smoother's options (``agreement``, keyframes, ``seed``).
        window: the smoother's window (latest estimates; what is still inside).
        calibration: the online self-calibration (segments and values), possibly disabled.
    """

    def __init__(self, robot: Robot, options: GraphOptions, settings: EpipolarSmootherOptions,
                 window: Window, calibration: OnlineCalibration) -> None:
        self.robot = robot
        self.options = options
        self.settings = settings
        self.window = window
        self.calibration = calibration
        self.rng = np.random.default_rng(settings.seed)
        self.history: deque[StoredFrame] = deque()
        self.keyframes: deque[StoredFrame] = deque()

    # -------------------------------------------------------------------------- frames
    def ingest(self, f: int, t: float, obs: FrameObservations) -> StoredFrame:
        """Frame ``f``'s observations as bearings sorted by track id, kept for pairing."""
        base = np.eye(4) if obs.world_T_base is None else np.asarray(obs.world_T_base, float)
        ids: dict[int, NDArray[np.int64]] = {}
        bearings: dict[int, FloatArray] = {}
        for cam, (track_ids, uv) in obs.tracks.items():
            camera = observed_camera(self.robot, f, cam)
            track_ids = np.asarray(track_ids, dtype=np.int64)
            if len(track_ids) == 0:
                continue
            given = None if obs.bearings is None else obs.bearings.get(cam)
            fb = camera.bearings(np.asarray(uv, dtype=float)) if given is None else given
            order = np.argsort(track_ids, kind="stable")
            ids[cam] = track_ids[order]
            bearings[cam] = np.asarray(fb, dtype=float)[order]
        frame = StoredFrame(f, t, base, ids, bearings)
        self.history.append(frame)
        longest = max(self.options.gaps)
        while self.history and self.history[0].index < f - longest:
            self.history.popleft()
        return frame

    def by_index(self) -> dict[int, StoredFrame]:
        """The stored frames (recent ones and keyframes) by index."""
        found = {h.index: h for h in self.history}
        found.update({kf.index: kf for kf in self.keyframes})
        return found

    def keep_keyframe(self, frame: StoredFrame, estimated: bool) -> None:
        """Make every ``keyframe_every``-th frame a keyframe (if it has an estimate); the
        oldest beyond ``keyframes`` are no longer renewed and leave with the lag."""
        s = self.settings
        if s.keyframes and frame.index % s.keyframe_every == 0 and estimated:
            self.keyframes.append(frame)
            while len(self.keyframes) > s.keyframes:
                self.keyframes.popleft()

    def restart(self) -> None:
        """After a restart: no keyframes, and only the newest frame kept."""
        self.keyframes.clear()
        while len(self.history) > 1:
            self.history.popleft()

    def set_positions(self, frame: StoredFrame, thetas: FloatArray) -> None:
        """Camera positions of a frame at the given angles (for the baseline test)."""
        pose = frame.base
        for i, seg in enumerate(self.robot.segments):
            pose = pose @ apcc_transform_scalar(float(thetas[i]), seg)[0]
            camera = self.robot.cameras[i]
            if camera is not None:
                frame.cam_positions[i] = (pose @ camera.tip_T_cam)[:3, 3]

    # ------------------------------------------------------------------------- measure
    def measure(self, frame: StoredFrame, thetas: FloatArray,
                status: NDArray[np.str_]) -> list[Measured]:
        """Each camera's factor over its pairs with the new frame, gated at ``thetas`` (the
        prediction), which the front end corrects in place where it relocates a segment.
        ``status`` says why a camera has none."""
        by_index = {h.index: h for h in self.history}
        segments = self.calibration.segments()
        pose = frame.base
        out = []
        for i, seg in enumerate(segments):
            camera = self.robot.cameras[i]
            if camera is None or i not in frame.ids:
                status[i] = "no-camera" if camera is None else "no-tracks"
                pose = pose @ apcc_transform_scalar(float(thetas[i]), seg)[0]
                continue
            link, measured = self._camera(i, segments, camera, frame, by_index, pose, thetas,
                                          status)
            pose = pose @ link
            if measured is not None:
                out.append(measured)
        return out

    def _camera(self, i: int, segments: tuple[Segment, ...], camera: TipCamera,
                frame: StoredFrame, by_index: dict[int, StoredFrame], pose: FloatArray,
                thetas: FloatArray, status: NDArray[np.str_]
                ) -> tuple[FloatArray, Measured | None]:
        """Camera i's factor, relocated if the prediction fails the check, and the link of
        segment i at its angle."""
        seg = segments[i]
        link = apcc_transform_scalar(float(thetas[i]), seg)[0]
        world_T_cam = pose @ link @ camera.tip_T_cam
        pairs, latest = self._pairs(i, frame, by_index, world_T_cam)
        factor = self.factor(i, frame, pairs, thetas) if pairs else None
        if not self._agrees(i, frame, pairs, latest, factor, world_T_cam[:3, 3]):
            if self._relocate(i, segments, camera, latest, pose, thetas, status):
                link = apcc_transform_scalar(float(thetas[i]), seg)[0]
                pairs, _ = self._pairs(i, frame, by_index, pose @ link @ camera.tip_T_cam)
                factor = self.factor(i, frame, pairs, thetas) if pairs else None
        if factor is None:
            if status[i] == "ok":
                status[i] = "no-motion" if not pairs else "no-consensus"
            return link, None
        if not factor.mask.any():
            if status[i] == "ok":
                status[i] = "no-consensus"
            return link, None
        return link, Measured(i, pairs, factor)

    def _agrees(self, i: int, frame: StoredFrame, pairs: list[FramePair],
                latest: FramePair | None, factor: EpipolarFrameFactor | None,
                here: FloatArray) -> bool:
        """The front end's check: the correspondences of the newest pair fit the prediction.

        Without parallax at the prediction there is nothing to check: the answer is no, so
        that the 1-point RANSAC decides against the latest frame sharing tracks (which also
        recognises a camera that did not move)."""
        checkable = [k for k, p in enumerate(pairs) if np.linalg.norm(
            here - p.earlier.cam_positions[i]) >= CHECK_BASELINE]
        if latest is None:
            return True
        if factor is None or not checkable:
            return False
        agreement = self.settings.agreement
        if any(pairs[k] is latest for k in checkable):
            return factor.kept[next(k for k in checkable if pairs[k] is latest)] >= agreement
        if latest.earlier.index == frame.index - 1:
            # A slow camera: the previous frame lacks parallax, an older pair has it.
            newest = max(checkable, key=lambda k: pairs[k].earlier.index)
            return factor.kept[newest] >= agreement
        return False  # tracks resume after a gap: re-initialise from scratch

    def _pairs(self, i: int, frame: StoredFrame, by_index: dict[int, StoredFrame],
               world_T_cam: FloatArray) -> tuple[list[FramePair], FramePair | None]:
        """Earlier frames that camera i can be paired with (enough shared tracks and
        parallax), and, for the front end's check, the latest earlier frame that shares enough
        tracks whatever its parallax (the previous frame, or the last one before a gap in the
        tracks), or None."""
        o = self.options
        lag = self.settings.lag
        thetas = self.window.thetas
        pairs = []
        position = world_T_cam[:3, 3]
        candidates = [by_index.get(frame.index - gap) for gap in o.gaps]
        near = {frame.index - gap for gap in o.gaps}
        candidates += [kf for kf in self.keyframes
                       if kf.index not in near and kf.index < frame.index]
        for old in candidates:
            if old is None or i not in old.ids or old.index not in thetas:
                continue
            if frame.stamp - old.stamp >= lag:  # marginalised in this update
                continue
            entry = self._shared(i, old, frame)
            if entry is None:
                continue
            if np.linalg.norm(position - old.cam_positions[i]) >= o.min_baseline:
                pairs.append(entry)  # else no parallax: the motion prior carries it
        latest = None
        for old in reversed(self.history):
            if old.index >= frame.index or old.index not in thetas:
                continue
            if frame.stamp - old.stamp >= lag:
                break
            latest = next((p for p in pairs if p.earlier is old), None) or self._shared(
                i, old, frame)
            if latest is not None:
                break
        return pairs, latest

    def _shared(self, i: int, old: StoredFrame, frame: StoredFrame) -> FramePair | None:
        """The pair over the tracks camera i saw in both frames, if enough."""
        if i not in old.ids:
            return None
        _, ia, ib = np.intersect1d(old.ids[i], frame.ids[i], assume_unique=True,
                                   return_indices=True)
        if len(ia) < self.options.min_shared:
            return None
        return FramePair(old, old.bearings[i][ia], frame.bearings[i][ib])

    def _relocate(self, i: int, segments: tuple[Segment, ...], camera: TipCamera,
                  latest: FramePair | None, pose: FloatArray, thetas: FloatArray,
                  status: NDArray[np.str_]) -> bool:
        """1-point RANSAC against the latest frame sharing tracks; True if it moved."""
        if latest is None:
            return False
        prev = self.window.thetas[latest.earlier.index]
        base_a = latest.earlier.base
        for j in range(i):
            base_a = base_a @ apcc_transform_scalar(float(prev[j]), segments[j])[0]
        theta, info = one_point_ransac(latest.f_a, latest.f_b, float(prev[i]), segments[i],
                                       camera.tip_T_cam, np.linalg.inv(base_a) @ pose,
                                       threshold=self.options.threshold_px / camera.fx,
                                       rng=self.rng)
        if not info.success:
            status[i] = info.status
            return False
        thetas[i] = theta
        return True

    # ------------------------------------------------------------------------- factors
    def factor(self, i: int, frame: StoredFrame, pairs: list[FramePair],
               thetas: FloatArray) -> EpipolarFrameFactor:
        """Camera i's factor over ``pairs``, gated (evaluated once here) at ``thetas``."""
        o = self.options
        n_seg = self.robot.n_segments
        camera = self.robot.cameras[i]
        assert camera is not None
        factor = EpipolarFrameFactor(
            [angle_key(frame.index, j, n_seg) for j in range(i + 1)],
            [[angle_key(p.earlier.index, j, n_seg) for j in range(i + 1)] for p in pairs],
            self.robot.segments[: i + 1], camera.tip_T_cam, frame.base,
            [p.earlier.base for p in pairs], [p.f_a for p in pairs], [p.f_b for p in pairs],
            o.threshold_px * reuse_factor(o) / camera.fx, o.loss, loss_scale(o),
            calibration_keys=self.calibration.factor_keys(i),
            gate=o.gate_px / camera.fx, min_rows=o.min_shared)
        # Gates at its first evaluation; the linearisation is memoised for linear_factor.
        factor.factor.linearize(self.linearization_point(factor, frame.index, thetas))
        return factor

    def linearization_point(self, factor: EpipolarFrameFactor, f: int,
                            thetas: FloatArray) -> gtsam.Values:
        """The factor's variables: frame ``f``'s at ``thetas``, earlier frames' at their
        latest estimates, the calibration at its current value."""
        n_seg = self.robot.n_segments
        values = gtsam.Values()
        for key in factor.keys:
            frame, seg = divmod(key, n_seg) if key < SYMBOL_KEYS else (-1, -1)
            if frame == f:
                value = thetas[seg]
            elif frame >= 0:
                value = self.window.thetas[frame][seg]
            else:
                value = self.calibration.value(key)
            values.insert(key, np.array([value]))
        return values
