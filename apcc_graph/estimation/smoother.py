"""Streaming estimation: a fixed-lag smoother over the last ``lag`` seconds of frames (gtsam).

This is the epipolar smoother (``vision="epipolar"``), kept for comparison and for its online
self-calibration: it grows the epipolar graph (:mod:`apcc_graph.estimation.epipolar_graph`) one
frame at a time. The default smoother is the projection one
(:mod:`apcc_graph.estimation.projection_smoother`); ``docs/estimation.md`` says where each stands
against the Cramer-Rao bound.
Graph:

- variables ``theta[f, i]`` (Vector1, radians), key ``f * S + i`` (as the batch);
- a prior on the first frame (``theta0``), a random-walk motion prior between consecutive frames,
  soft joint limits;
- per camera and new frame b, one generalized epipolar factor against every earlier frame
  ``b - gap`` still in the window (:func:`factors.epipolar.epipolar_frame_factor`: one Python
  callback per camera and frame), correspondences gated at the current estimate;
- optionally (``calibrate=True``) each segment's k and delta_max as variables with priors, never
  marginalised (online self-calibration).

New frames are initialised by the 1-point front end, segment by segment from the base: the
prediction (constant angular velocity) is checked against the correspondences with the latest
earlier frame that shares tracks with this one (the previous frame, or the last one before a
blackout). When at least ``agreement`` of them fall inside the gate the prediction stands and the
graph refines it; otherwise, or when the prediction shows no parallax to check,
:func:`apcc_graph.frontend.one_point.one_point_ransac` re-initialises the angle from that pair.

Linearisation: by default each epipolar factor is linearised once, at the angles it was built at,
and enters gtsam as a C++ ``LinearContainerFactor`` (first-estimate Jacobians), so gtsam never
calls back into Python; ``linearization="relinearize"`` keeps the Python factor for iSAM2 to
re-linearise instead (5x slower on the benchmark, no more accurate).

Backends: gtsam's ``IncrementalFixedLagSmoother`` (iSAM2, default) or ``BatchFixedLagSmoother``
(Levenberg-Marquardt over the whole window at every frame). iSAM2 re-eliminates only the part of
the window a new frame touches, so it is the default; ``apcc-graph bench smoother`` measures
both.

Failure modes handled (each has a test):

- a frame without tracks in some or all cameras: the motion prior carries the angles, their
  uncertainty grows; if the motion prior is disabled, a weak prior at the prediction
  (``loose_sigma``) keeps the system determined;
- a robot standing still: pairs whose camera moved less than ``min_baseline`` carry no parallax
  and are left out (the motion prior holds the angles);
- gtsam's indeterminate-system exception: caught; the update is repaired by weak priors on the
  new frame's angles, and if that fails too the smoother restarts from its last estimate;
- marginalising a variable that only has a prior: every frame is linked to the previous one by
  the motion prior (or the weak prior above), and a test marginalises such variables;
- gtsam's marginalisation helper losing a variable's clique (``IndexError``, seen with the
  self-calibration variables): the smoother restarts from its last estimate;
- tracks resuming after a blackout: the front end re-initialises from the last frame that
  shares tracks instead of trusting the extrapolated prediction.

Frames leaving the window keep the estimate (and marginal sigma) of the last update in which they
were inside it; :meth:`FixedLagSmoother.finish` returns every frame's final estimate.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from typing import Any

import gtsam
import numpy as np
from numpy.typing import ArrayLike, NDArray
from tqdm import tqdm

from apcc_graph.estimation.epipolar_graph import angle_key
from apcc_graph.estimation.options import GraphOptions, loss_scale, reuse_factor
from apcc_graph.estimation.result import Estimate
from apcc_graph.frontend.one_point import one_point_ransac
from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.kinematics import apcc_transform_scalar
from apcc_graph.model.robot import Robot
from apcc_graph.model.sequence import FrameObservations, Sequence
from factors.epipolar import EpipolarFrameFactor, calibrated_segments
from factors.priors import angle_prior, joint_limit_factor, motion_prior

BACKENDS = ("incremental", "batch")
_CAL_BASE = gtsam.symbol("a", 0)
"""Angle keys are ``frame * S + segment``, far below any gtsam Symbol key (calibration)."""
LINEARIZATIONS = ("first-estimate", "relinearize")
_CHECK_BASELINE = 1e-4
"""Metres: below this the front end's check has no parallax to judge the prediction by."""


@dataclass(frozen=True)
class SmootherFrame:
    """One frame's estimate as the smoother returns it.

    Attributes:
        frame: 0-based frame index (the order of :meth:`FixedLagSmoother.update` calls).
        timestamp: seconds.
        thetas: ``(S,)`` angles (radians).
        sigmas: ``(S,)`` marginal standard deviations (radians; NaN without uncertainty).
        status: ``(S,)`` per segment: ``"ok"`` (measured), ``"no-tracks"``, ``"no-motion"``,
            ``"no-consensus"``, ``"no-camera"`` (the prior carries it), ``"initial"`` (first
            frame), ``"recovered"`` (after a gtsam failure); the projection smoother also
            ``"predicted"`` (no known point seen: the prediction stands).
        calibration: ``(S, 2)`` current ``k`` and ``delta_max`` (radians) when self-calibrating.
    """

    frame: int
    timestamp: float
    thetas: FloatArray
    sigmas: FloatArray
    status: NDArray[np.str_]
    calibration: FloatArray | None = None


@dataclass
class _Frame:
    """What the smoother keeps of a frame while it can still be paired."""

    index: int
    timestamp: float
    base: FloatArray
    ids: dict[int, NDArray[np.int64]]
    bearings: dict[int, FloatArray]
    cam_positions: dict[int, FloatArray] = field(default_factory=dict)
    stamp: float = 0.0


@dataclass
class _Active:
    """An epipolar factor in the smoother, kept so it can be rebuilt where it was built."""

    frame: int  # its newest frame b
    camera: int
    newest: _Frame  # frame b's observations
    pairs: list  # [(earlier _Frame, f_a, f_b)], before gating
    frames: NDArray[np.int64]  # frames a_0 .. a_P-1, b
    point: FloatArray  # (P + 1, i + 1) angles it was linearised at
    index: int = -1  # gtsam's factor index


def _calibration_keys(segment: int) -> tuple[int, int]:
    return gtsam.symbol("k", segment), gtsam.symbol("d", segment)


class FixedLagSmoother:
    """Streaming estimator of a robot's segment angles: ``update(frame)`` once per frame.

    Args:
        robot: the robot model.
        lag: window length (seconds); variables older than this are marginalised.
        options: graph construction (:class:`~apcc_graph.estimation.batch.GraphOptions`);
            ``gaps`` longer than the window are unused.
        theta0: ``(S,)`` starting configuration in radians (default straight).
        backend: ``"incremental"`` (iSAM2) or ``"batch"`` (LM over the window).
        uncertainty: compute marginal sigmas (a little slower).
        calibrate: add each segment's k and delta_max as variables (self-calibration).
            Experimental: on ``apcc-graph bench smoother`` (room scene, model off by +0.03 in
            k and +3 deg in delta_max) it made the angles worse, not better, and even with
            tight priors (0.01, 1 deg) the RMS grew 2-6x; k is only weakly observable from the
            epipolar geometry and delta_max trades off against the weakly observed absolute
            angles. The factors' calibration Jacobians are exact and, with the angles known,
            delta_max converges (tests/test_factors.py).
        calibration_sigmas: prior standard deviations of k and delta_max (radians) around the
            robot's values.
        relinearize_threshold: iSAM2 re-linearises a variable that moved more (radians).
        relinearize_skip: iSAM2 checks for re-linearisation every this many updates.
        loose_sigma: the weak prior (radians) that keeps a frame without any constraint
            determined when the motion prior is disabled.
        marginalise_every: frames leave the window in blocks of this many (gtsam re-eliminates
            the window whenever it marginalises, which re-linearises the Python factors; blocks
            pay that once per block instead of every frame). The window holds between ``lag``
            and ``lag`` plus one block of frames.
        linearization: ``"first-estimate"`` (default): each epipolar factor is linearised
            once, when its frame arrives, and enters gtsam as a C++ ``LinearContainerFactor``
            (first-estimate Jacobians, as in filter-based visual-inertial odometry): no Python
            runs inside gtsam. ``"relinearize"``: the Python factor itself, which iSAM2
            re-linearises when its variables move more than ``relinearize_threshold``.
        iterations: first-estimate factors of a new frame are linearised at the prediction;
            while the update then moves that frame's angles by more than
            ``iterate_threshold``, they are re-gated and re-linearised at the new estimate and
            swapped in, up to ``iterations`` linearisations in all (an iterated update, as in
            the iterated EKF; iSAM2 backend). 1 disables it. Prediction errors of a few tenths
            of a degree are enough to bias a one-shot linearisation where the absolute angles
            are weakly observed, and on accurate (image) tracks the bias can run away.
        iterate_threshold: see ``iterations`` (radians). Measured on six 150-frame room
            sequences (images and simulated 1 px tracks): 0.1 deg keeps the accuracy of 0.01 deg
            (mean RMS 0.11 vs 0.10 deg on images, 1.34 vs 1.35 deg on 1 px tracks; one-shot:
            3.84 and 2.20 deg) for 1.3-1.6x the update time of the one-shot update, against
            1.7-2.2x at 0.01 deg.
        rebuild_threshold: first-estimate factors whose variables have since moved more than
            this (radians) are rebuilt at the current estimate (re-gated and re-linearised) and
            swapped in, at most ``rebuilds_per_frame`` per update, largest move first (iSAM2
            backend). This keeps a factor linearised at a poor prediction from holding the
            estimate there.
        keyframe_every, keyframes: every ``keyframe_every``-th frame becomes a keyframe and
            the last ``keyframes`` of them stay in the window beyond ``lag`` (their timestamps
            are renewed); new frames are also paired with every keyframe they share tracks
            with. Long baselines are what observe the absolute configuration (docs/estimation.md,
            "Two frames"); keyframes give them at the cost of more pairs per frame and of a
            window gtsam must re-eliminate whole at every update. Off by default
            (``keyframes=0``): on three 300-frame room-scene sequences, 6 keyframes every 10
            frames cut the RMS on some segments and raised it on others, at 4x the update time.
        agreement: fraction of the correspondences with the latest frame that must fall inside
            the gate for the prediction to stand (otherwise the 1-point RANSAC re-initialises).
        rebuilds_per_frame: see ``rebuild_threshold``; 0 (default) disables rebuilding: on
            the benchmark it cost 5 ms per frame for a mixed effect on accuracy.
        limit_margin: soft joint limits are added to frames whose initial angle is within
            this of the limit (radians); elsewhere they are inactive anyway.
        seed: random seed of the front end's RANSAC.

    Example::

        smoother = FixedLagSmoother(robot, lag=1.0)
        for f in range(sequence.n_frames):
            now = smoother.update(sequence.frame(f))   # that frame's estimate
        final = smoother.finish()                      # every frame, smoothed
    """

    def __init__(
        self,
        robot: Robot,
        lag: float = 1.0,
        options: GraphOptions | None = None,
        theta0: ArrayLike | None = None,
        backend: str = "incremental",
        uncertainty: bool = True,
        calibrate: bool = False,
        calibration_sigmas: tuple[float, float] = (0.05, math.radians(5.0)),
        relinearize_threshold: float = 1e-3,
        relinearize_skip: int = 1,
        loose_sigma: float = math.radians(30.0),
        marginalise_every: int = 10,
        limit_margin: float = math.radians(10.0),
        linearization: str = "first-estimate",
        rebuild_threshold: float = math.radians(0.1),
        rebuilds_per_frame: int = 0,
        iterations: int = 3,
        iterate_threshold: float = math.radians(0.1),
        keyframe_every: int = 10,
        keyframes: int = 0,
        agreement: float = 0.5,
        seed: int = 0,
    ) -> None:
        if not isinstance(robot, Robot):
            raise ValueError(f"FixedLagSmoother.robot: expected a Robot, got "
                             f"{type(robot).__name__}")
        if not (math.isfinite(lag) and lag > 0.0):
            raise ValueError(f"FixedLagSmoother.lag = {lag!r}: expected a positive number of "
                             "seconds")
        if backend not in BACKENDS:
            raise ValueError(f"FixedLagSmoother.backend = {backend!r}: expected one of "
                             f"{BACKENDS}")
        n_seg = robot.n_segments
        theta0 = np.zeros(n_seg) if theta0 is None else np.asarray(theta0, dtype=float)
        if theta0.shape != (n_seg,) or not np.all(np.isfinite(theta0)):
            raise ValueError(f"FixedLagSmoother.theta0 has shape {theta0.shape}: expected "
                             f"({n_seg},) finite angles in radians")
        self.robot = robot
        self.lag = float(lag)
        self.options = GraphOptions() if options is None else options
        self.theta0 = theta0
        self.backend = backend
        self.uncertainty = uncertainty
        self.calibrate = calibrate
        self.calibration_sigmas = calibration_sigmas
        self.relinearize_threshold = relinearize_threshold
        self.relinearize_skip = relinearize_skip
        self.loose_sigma = loose_sigma
        self.limit_margin = limit_margin
        if linearization not in LINEARIZATIONS:
            raise ValueError(f"FixedLagSmoother.linearization = {linearization!r}: expected "
                             f"one of {LINEARIZATIONS}")
        self.linearization = linearization
        self.rebuild_threshold = rebuild_threshold
        self.rebuilds_per_frame = int(rebuilds_per_frame)
        if int(iterations) < 1 or not iterate_threshold >= 0.0:
            raise ValueError(f"FixedLagSmoother: iterations = {iterations!r} and "
                             f"iterate_threshold = {iterate_threshold!r}: expected >= 1 and "
                             ">= 0")
        self.iterations = int(iterations)
        self.iterate_threshold = float(iterate_threshold)
        self._fresh: list[tuple[int, int, list]] = []  # the new frame's (position, camera, pairs)
        if int(keyframe_every) < 1 or int(keyframes) < 0:
            raise ValueError(f"FixedLagSmoother: keyframe_every = {keyframe_every!r} and "
                             f"keyframes = {keyframes!r}: expected >= 1 and >= 0")
        if not 0.0 <= agreement <= 1.0:
            raise ValueError(f"FixedLagSmoother.agreement = {agreement!r}: expected a fraction "
                             "in [0, 1]")
        self.agreement = float(agreement)
        self.keyframe_every = int(keyframe_every)
        self.n_keyframes = int(keyframes)
        self._keyframes: deque[_Frame] = deque()
        self._active: dict[tuple[int, int], _Active] = {}
        self._pending: list[tuple[int, _Active]] = []  # (position in the new graph, entry)
        self._rebuilds = 0
        if int(marginalise_every) < 1:
            raise ValueError(f"FixedLagSmoother.marginalise_every = {marginalise_every!r}: "
                             "expected a positive number of frames")
        self.marginalise_every = int(marginalise_every)
        self._block_stamp = 0.0
        self._rng = np.random.default_rng(seed)
        self._anchor_unconstrained = True  # tests turn this off to provoke gtsam's failure
        self._smoother = self._new_smoother()
        self._history: deque[_Frame] = deque()
        self._window: dict[int, float] = {}  # frame -> gtsam stamp, frames inside the window
        self._times: dict[int, float] = {}  # frame -> timestamp, frames inside the window
        self._thetas: dict[int, FloatArray] = {}  # latest estimate of every frame in the window
        self._final: dict[int, SmootherFrame] = {}  # frames that left the window
        self._status: dict[int, NDArray[np.str_]] = {}
        self._count = 0
        self._recoveries = 0

    # ---------------------------------------------------------------------------- set-up
    def _new_smoother(self) -> gtsam.FixedLagSmoother:
        if self.backend == "batch":
            return gtsam.BatchFixedLagSmoother(self.lag)
        params = gtsam.ISAM2Params()
        params.setRelinearizeThreshold(self.relinearize_threshold)
        params.relinearizeSkip = self.relinearize_skip
        params.findUnusedFactorSlots = False
        return gtsam.IncrementalFixedLagSmoother(self.lag, params)

    @property
    def n_frames(self) -> int:
        """Frames received so far."""
        return self._count

    @property
    def rebuilds(self) -> int:
        """How many first-estimate factors were rebuilt at a moved estimate."""
        return self._rebuilds

    @property
    def recoveries(self) -> int:
        """How many times a gtsam failure was caught and recovered from."""
        return self._recoveries

    # ---------------------------------------------------------------------------- update
    def update(self, observations: FrameObservations) -> SmootherFrame:
        """Add one frame; returns that frame's estimate (filtered: only past frames seen).

        Raises:
            ValueError: a timestamp not after the previous frame's, or observations of a
                segment without a camera.
        """
        f = self._count
        t = float(observations.timestamp)
        if not math.isfinite(t) or (self._history and t <= self._history[-1].timestamp):
            last = self._history[-1].timestamp if self._history else float("nan")
            raise ValueError(f"frame {f}: timestamp {t!r} s is not after the previous frame's "
                             f"{last!r} s")
        frame = self._ingest(f, t, observations)
        n_seg = self.robot.n_segments
        o = self.options
        if f % self.marginalise_every == 0:
            self._block_stamp = t
        stamp = self._block_stamp  # gtsam's timestamp of this frame's variables
        frame.stamp = stamp
        # Frames that leave the window in this update keep their current estimate.
        self._retire(stamp)
        status = np.full(n_seg, "initial" if f == 0 else "ok", dtype="<U24")
        graph = gtsam.NonlinearFactorGraph()
        if f == 0:
            thetas = self.theta0.copy()
            n_epipolar = 0
        else:
            thetas = self._predict(f)
            n_epipolar = self._measure(graph, frame, thetas, status)
        self._set_positions(frame, thetas)
        values = gtsam.Values()
        stamps = gtsam.FixedLagSmootherKeyTimestampMap()
        keys = [angle_key(f, i, n_seg) for i in range(n_seg)]
        for kf in self._keyframes:  # keyframes stay: renew their timestamps
            kf.stamp = self._window[kf.index] = stamp
            for i in range(n_seg):
                stamps.insert((angle_key(kf.index, i, n_seg), stamp))
        for i, key in enumerate(keys):
            values.insert(key, np.array([thetas[i]]))
            stamps.insert((key, stamp))
            theta_max = self.robot.segments[i].theta_max
            if abs(thetas[i]) > theta_max - self.limit_margin:
                # Soft limits only where they can act (a Python factor costs time).
                graph.add(joint_limit_factor(key, theta_max, o.limit_sigma))
        if f == 0:
            for i, key in enumerate(keys):
                graph.add(angle_prior(key, self.theta0[i], o.theta0_sigma))
            if self.calibrate:
                self._add_calibration(graph, values)
        elif o.motion_sigma is not None:
            dt = t - self._history[-2].timestamp
            for i, key in enumerate(keys):
                graph.add(motion_prior(angle_key(f - 1, i, n_seg), key, o.motion_sigma, dt))
        if self.calibrate:
            for i in range(n_seg):
                for key in _calibration_keys(i):
                    stamps.insert((key, stamp))  # never marginalised
        if (f > 0 and o.motion_sigma is None and n_epipolar == 0
                and self._anchor_unconstrained):
            for i, key in enumerate(keys):
                graph.add(angle_prior(key, thetas[i], self.loose_sigma))
        remove = self._rebuild_moved(graph, stamp)
        fresh, self._fresh = self._fresh, []
        self._solve(graph, values, stamps, f, thetas, status, remove)
        if fresh and self.iterations > 1 and "recovered" not in status:
            self._iterate(frame, fresh, thetas, status)
        self._window[f] = stamp
        self._times[f] = t
        self._status[f] = status
        if self.n_keyframes and f % self.keyframe_every == 0 and f in self._thetas:
            self._keyframes.append(frame)
            while len(self._keyframes) > self.n_keyframes:
                self._keyframes.popleft()  # no longer renewed: leaves with the lag
        self._count += 1
        return self._frame_estimate(f, t, status)

    def _ingest(self, f: int, t: float, obs: FrameObservations) -> _Frame:
        base = np.eye(4) if obs.world_T_base is None else np.asarray(obs.world_T_base, float)
        ids: dict[int, NDArray[np.int64]] = {}
        bearings: dict[int, FloatArray] = {}
        for cam, (track_ids, uv) in obs.tracks.items():
            camera = self.robot.cameras[cam] if 0 <= cam < self.robot.n_segments else None
            if camera is None:
                raise ValueError(f"frame {f}: observations of camera {cam}, but segment {cam} "
                                 f"has no camera (cameras ride on {self.robot.camera_segments})")
            track_ids = np.asarray(track_ids, dtype=np.int64)
            if len(track_ids) == 0:
                continue
            given = None if obs.bearings is None else obs.bearings.get(cam)
            fb = camera.bearings(np.asarray(uv, dtype=float)) if given is None else given
            order = np.argsort(track_ids, kind="stable")
            ids[cam] = track_ids[order]
            bearings[cam] = np.asarray(fb, dtype=float)[order]
        frame = _Frame(f, t, base, ids, bearings)
        self._history.append(frame)
        longest = max(self.options.gaps)
        while self._history and self._history[0].index < f - longest:
            self._history.popleft()
        return frame

    def _retire(self, stamp: float) -> None:
        """Record the final estimate of frames that the coming update marginalises."""
        leaving = [g for g, sg in self._window.items() if sg < stamp - self.lag]
        if not leaving:
            return
        estimate = self._smoother.calculateEstimate()
        n_seg = self.robot.n_segments
        for g in leaving:
            thetas = np.array([estimate.atVector(angle_key(g, i, n_seg))[0]
                               for i in range(n_seg)])
            sigmas = self._sigmas(g) if self.uncertainty else np.full(n_seg, np.nan)
            self._window.pop(g)
            self._final[g] = SmootherFrame(g, self._times.pop(g), thetas, sigmas,
                                           self._status.pop(g))
            self._thetas.pop(g, None)
        gone = set(leaving)
        for key in [k for k, e in self._active.items() if gone.intersection(e.frames.tolist())]:
            del self._active[key]  # absorbed into the marginal: can no longer be swapped

    def _add_calibration(self, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values,
                         start: FloatArray | None = None) -> None:
        """k and delta_max variables with priors around the robot's values, starting at
        ``start`` (``(S, 2)``, after a restart) or at the robot's values."""
        sk, sd = self.calibration_sigmas
        for i, seg in enumerate(self.robot.segments):
            k_key, d_key = _calibration_keys(i)
            k0, d0 = (seg.k, seg.delta_max) if start is None else start[i]
            values.insert(k_key, np.array([k0]))
            values.insert(d_key, np.array([d0]))
            graph.add(angle_prior(k_key, seg.k, sk))
            graph.add(angle_prior(d_key, seg.delta_max, sd))

    # ----------------------------------------------------------------------- front end
    def _segments(self) -> tuple:
        """The segments with the current calibration."""
        if not self.calibrate or self._count == 0:
            return self.robot.segments
        keys = [_calibration_keys(i) for i in range(self.robot.n_segments)]
        return tuple(calibrated_segments(self.robot.segments, self._smoother.calculateEstimate(),
                                         keys))

    def _predict(self, f: int) -> FloatArray:
        """Constant angular velocity from the two previous frames' estimates."""
        prev = self._thetas[f - 1]
        older = self._thetas.get(f - 2)
        prediction = prev if older is None else 2.0 * prev - older
        lim = np.array([s.theta_max for s in self.robot.segments])
        return np.clip(prediction, -lim, lim)

    def _set_positions(self, frame: _Frame, thetas: FloatArray) -> None:
        """Camera positions of a frame at the given angles (for the baseline test)."""
        pose = frame.base
        for i, seg in enumerate(self.robot.segments):
            pose = pose @ apcc_transform_scalar(float(thetas[i]), seg)[0]
            camera = self.robot.cameras[i]
            if camera is not None:
                frame.cam_positions[i] = (pose @ camera.tip_T_cam)[:3, 3]

    def _measure(self, graph: gtsam.NonlinearFactorGraph, frame: _Frame, thetas: FloatArray,
                 status: NDArray[np.str_]) -> int:
        """Front end and epipolar factors of a new frame, camera by camera from the base.

        For camera i: the pairs (a, frame) with enough shared tracks and parallax, one factor
        over them, gated at the current angles (the prediction). If most correspondences with
        the previous frame fall outside the gate, the 1-point RANSAC re-initialises
        ``thetas[i]`` and the factor is rebuilt. ``thetas`` is updated in place.
        """
        f = frame.index
        by_index = {h.index: h for h in self._history}
        segments = self._segments()
        pose = frame.base
        added = 0
        for i, seg in enumerate(segments):
            camera = self.robot.cameras[i]
            link = apcc_transform_scalar(float(thetas[i]), seg)[0]
            if camera is None or i not in frame.ids:
                status[i] = "no-camera" if camera is None else "no-tracks"
                pose = pose @ link
                continue
            pairs, latest = self._pairs(i, frame, by_index, (pose @ link @ camera.tip_T_cam))
            factor = self._factor(i, frame, pairs, thetas) if pairs else None
            # The front end's check: the correspondences of the newest pair fit the prediction.
            # Without parallax at the prediction there is nothing to check: ask the 1-point
            # RANSAC against the latest frame sharing tracks (which also recognises a camera
            # that did not move).
            here = (pose @ link @ camera.tip_T_cam)[:3, 3]
            checkable = [k for k, p in enumerate(pairs) if np.linalg.norm(
                here - p[0].cam_positions[i]) >= _CHECK_BASELINE]
            if latest is None:
                agree = True
            elif factor is None or not checkable:
                agree = False
            elif any(pairs[k] is latest for k in checkable):
                agree = factor.kept[next(k for k in checkable if pairs[k] is latest)] >= (
                    self.agreement)
            elif latest[0].index == frame.index - 1:
                # A slow camera: the previous frame lacks parallax, an older pair has it.
                newest = max(checkable, key=lambda k: pairs[k][0].index)
                agree = factor.kept[newest] >= self.agreement
            else:
                agree = False  # tracks resume after a gap: re-initialise from scratch
            if not agree:
                if self._relocate(i, seg, camera, latest, pose, thetas, status):
                    link = apcc_transform_scalar(float(thetas[i]), seg)[0]
                    pairs, _ = self._pairs(i, frame, by_index,
                                           (pose @ link @ camera.tip_T_cam))
                    factor = self._factor(i, frame, pairs, thetas) if pairs else None
            pose = pose @ link
            if factor is None:
                if status[i] == "ok":
                    status[i] = "no-motion" if not pairs else "no-consensus"
                continue
            if not factor.mask.any():
                if status[i] == "ok":
                    status[i] = "no-consensus"
                continue
            if self.linearization == "first-estimate" and self.rebuilds_per_frame > 0:
                self._fresh.append((graph.size(), i, pairs))
                self._pending.append((graph.size(), _Active(
                    f, i, frame, pairs, np.array([p[0].index for p in pairs] + [f]),
                    np.array([self._thetas[p[0].index][: i + 1] for p in pairs]
                             + [thetas[: i + 1]]))))
                graph.add(factor.linear_factor(self._linearization_point(factor, f, thetas)))
            elif self.linearization == "first-estimate":
                self._fresh.append((graph.size(), i, pairs))
                graph.add(factor.linear_factor(self._linearization_point(factor, f, thetas)))
            else:
                graph.add(factor.factor)
            added += 1
        return added

    def _pairs(self, i: int, frame: _Frame, by_index: dict[int, _Frame],
               world_T_cam: FloatArray) -> tuple[list, tuple | None]:  # noqa: D417
        """Earlier frames that camera i can be paired with: ``[(frame, f_a, f_b)]`` (enough
        shared tracks and parallax), and, for the front end's check, the latest earlier frame
        that shares enough tracks whatever its parallax (the previous frame, or the last one
        before a gap in the tracks), or None."""
        o = self.options
        pairs = []
        position = world_T_cam[:3, 3]
        candidates = [(gap, by_index.get(frame.index - gap)) for gap in o.gaps]
        near = {frame.index - gap for gap in o.gaps}
        candidates += [(frame.index - kf.index, kf) for kf in self._keyframes
                       if kf.index not in near and kf.index < frame.index]
        for _, old in candidates:
            if old is None or i not in old.ids or old.index not in self._thetas:
                continue
            if frame.stamp - old.stamp >= self.lag:  # marginalised in this update
                continue
            entry = self._shared(i, old, frame)
            if entry is None:
                continue
            if np.linalg.norm(position - old.cam_positions[i]) >= o.min_baseline:
                pairs.append(entry)  # else no parallax: the motion prior carries it
        latest = None
        for old in reversed(self._history):
            if old.index >= frame.index or old.index not in self._thetas:
                continue
            if frame.stamp - old.stamp >= self.lag:
                break
            latest = next((p for p in pairs if p[0] is old), None) or self._shared(i, old,
                                                                                  frame)
            if latest is not None:
                break
        return pairs, latest

    def _shared(self, i: int, old: _Frame, frame: _Frame) -> tuple | None:
        """``(old, f_a, f_b)`` over the tracks camera i saw in both frames, if enough."""
        if i not in old.ids:
            return None
        _, ia, ib = np.intersect1d(old.ids[i], frame.ids[i], assume_unique=True,
                                   return_indices=True)
        if len(ia) < self.options.min_shared:
            return None
        return (old, old.bearings[i][ia], frame.bearings[i][ib])

    def _factor(self, i: int, frame: _Frame, pairs: list,
                thetas: FloatArray) -> EpipolarFrameFactor | None:
        """Camera i's factor over ``pairs``, gated (evaluated once here) at ``thetas``."""
        o = self.options
        n_seg = self.robot.n_segments
        camera = self.robot.cameras[i]
        factor = EpipolarFrameFactor(
            [angle_key(frame.index, j, n_seg) for j in range(i + 1)],
            [[angle_key(p[0].index, j, n_seg) for j in range(i + 1)] for p in pairs],
            self.robot.segments[: i + 1], camera.tip_T_cam, frame.base,
            [p[0].base for p in pairs], [p[1] for p in pairs], [p[2] for p in pairs],
            o.threshold_px * reuse_factor(o) / camera.fx, o.loss, loss_scale(o),
            calibration_keys=([_calibration_keys(j) for j in range(i + 1)]
                              if self.calibrate else None),
            gate=o.gate_px / camera.fx, min_rows=o.min_shared)
        # Gates at its first evaluation; the linearisation is memoised for linear_factor.
        factor.factor.linearize(self._linearization_point(factor, frame.index, thetas))
        return factor

    def _linearization_point(self, factor: EpipolarFrameFactor, f: int,
                             thetas: FloatArray) -> gtsam.Values:
        n_seg = self.robot.n_segments
        values = gtsam.Values()
        for key in factor.keys:
            frame, seg = divmod(key, n_seg) if key < _CAL_BASE else (-1, -1)
            if frame == f:
                value = thetas[seg]
            elif frame >= 0:
                value = self._thetas[frame][seg]
            else:
                value = self._calibration_value(key)
            values.insert(key, np.array([value]))
        return values

    def _calibration_value(self, key: int) -> float:
        if self._count == 0:
            symbol = gtsam.Symbol(key)
            seg = self.robot.segments[symbol.index()]
            return seg.k if chr(symbol.chr()) == "k" else seg.delta_max
        return float(self._smoother.calculateEstimateVector(key)[0])

    def _relocate(self, i: int, seg, camera, latest: tuple | None,  # noqa: ANN001
                  pose: FloatArray, thetas: FloatArray, status: NDArray[np.str_]) -> bool:
        """1-point RANSAC against the latest frame sharing tracks; True if it moved."""
        if latest is None:
            return False
        old, f_a, f_b = latest
        prev = self._thetas[old.index]
        segments = self._segments()
        base_a = old.base
        for j in range(i):
            base_a = base_a @ apcc_transform_scalar(float(prev[j]), segments[j])[0]
        theta, info = one_point_ransac(f_a, f_b, float(prev[i]), seg, camera.tip_T_cam,
                                       np.linalg.inv(base_a) @ pose,
                                       threshold=self.options.threshold_px / camera.fx,
                                       rng=self._rng)
        if not info.success:
            status[i] = info.status
            return False
        thetas[i] = theta
        return True

    # -------------------------------------------------------------------------- solve
    def _solve(self, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values,
               stamps: gtsam.FixedLagSmootherKeyTimestampMap, f: int, thetas: FloatArray,
               status: NDArray[np.str_], remove: list[int] | None = None) -> None:
        """``smoother.update`` with recovery from gtsam's indeterminate-system failure."""
        n_seg = self.robot.n_segments
        pending, self._pending = self._pending, []
        try:
            self._smoother.update(graph, values, stamps, remove or [])
            self._register(pending)
        except IndexError:
            # gtsam's marginalisation helper lost track of a variable's clique (known
            # IncrementalFixedLagSmoother failures): the state cannot be trusted, start afresh.
            self._recoveries += 1
            status[:] = "recovered"
            self._restart(f, thetas)
        except RuntimeError:
            self._recoveries += 1
            status[:] = "recovered"
            self._active.clear()  # factor indices are no longer trustworthy
            repair = gtsam.NonlinearFactorGraph()
            for i in range(n_seg):
                repair.add(angle_prior(angle_key(f, i, n_seg), thetas[i], self.loose_sigma))
            try:
                self._smoother.update(repair, gtsam.Values(),
                                      gtsam.FixedLagSmootherKeyTimestampMap())
            except (RuntimeError, IndexError):
                self._restart(f, thetas)
        self._read_window()

    def _iterate(self, frame: _Frame, fresh: list[tuple[int, int, list]], point: FloatArray,
                 status: NDArray[np.str_]) -> None:
        """Re-linearise the new frame's factors at its updated estimate while it moves (see
        ``iterations``); ``fresh`` holds each factor's position in the last update's graph.

        Camera i's factor depends on the angles of segments 0..i, so it is rebuilt only when
        those moved more than ``iterate_threshold`` since it was linearised."""
        if self.backend != "incremental":
            return
        f = frame.index
        indices = self._smoother.getISAM2Result().getNewFactorsIndices()
        # camera -> (gtsam index, pairs, angles of frame f it was linearised at)
        live = {i: (int(indices[pos]), pairs, point.copy()) for pos, i, pairs in fresh}
        for _ in range(self.iterations - 1):
            needed = {f} | {p[0].index for _, pairs, _ in live.values() for p in pairs}
            self._read_window(frames=needed)
            now = self._thetas[f].copy()
            graph = gtsam.NonlinearFactorGraph()
            remove, positions = [], []
            for i, (index, pairs, at) in live.items():
                if float(np.max(np.abs(now[: i + 1] - at[: i + 1]))) <= self.iterate_threshold:
                    continue
                factor = self._factor(i, frame, pairs, now)
                if factor is None or not factor.mask.any():
                    continue  # keep the factor linearised where it was
                remove.append(index)
                positions.append((graph.size(), i))
                graph.add(factor.linear_factor(self._linearization_point(factor, f, now)))
            if not positions:
                return
            self._solve(graph, gtsam.Values(), gtsam.FixedLagSmootherKeyTimestampMap(), f, now,
                        status, remove)
            if "recovered" in status:
                return
            new_indices = self._smoother.getISAM2Result().getNewFactorsIndices()
            for position, i in positions:
                live[i] = (int(new_indices[position]), live[i][1], now)
                entry = self._active.get((f, i))
                if entry is not None:  # the rebuild bookkeeping follows the swap
                    entry.index = live[i][0]
                    entry.point = np.array([self._thetas[g][: i + 1] for g in entry.frames[:-1]]
                                           + [now[: i + 1]])

    def _register(self, pending: list[tuple[int, _Active]]) -> None:
        """Remember where gtsam put the new first-estimate factors (iSAM2 backend only)."""
        if self.backend != "incremental" or not pending:
            return
        indices = self._smoother.getISAM2Result().getNewFactorsIndices()
        for position, entry in pending:
            entry.index = int(indices[position])
            self._active[(entry.frame, entry.camera)] = entry

    def _rebuild_moved(self, graph: gtsam.NonlinearFactorGraph, stamp: float) -> list[int]:
        """Rebuild the factors whose variables moved most since they were linearised.

        Only factors whose frames all stay in the window through this update qualify. The
        rebuilt factors are added to ``graph``; returns the gtsam indices to remove.
        """
        if (self.linearization != "first-estimate" or self.backend != "incremental"
                or self.rebuilds_per_frame <= 0 or not self._active):
            return []
        self._read_window(everything=True)
        moved = []
        for key, entry in list(self._active.items()):
            if any(g not in self._window or self._window[g] < stamp - self.lag
                   for g in entry.frames):
                del self._active[key]  # about to be (or already) marginalised
                continue
            now = np.array([self._thetas[g][: entry.camera + 1] for g in entry.frames])
            change = float(np.max(np.abs(now - entry.point)))
            if change > self.rebuild_threshold:
                moved.append((change, key))
        remove = []
        for _, key in sorted(moved, reverse=True)[: self.rebuilds_per_frame]:
            entry = self._active.pop(key)
            b = entry.frame
            thetas = self._thetas[b].copy()
            factor = self._factor(entry.camera, entry.newest, entry.pairs, thetas)
            if factor is None or not factor.mask.any():
                continue
            remove.append(entry.index)
            self._pending.append((graph.size(), _Active(
                b, entry.camera, entry.newest, entry.pairs, entry.frames,
                np.array([self._thetas[g][: entry.camera + 1] for g in entry.frames]))))
            graph.add(factor.linear_factor(self._linearization_point(factor, b, thetas)))
            self._rebuilds += 1
        return remove

    def _restart(self, f: int, thetas: FloatArray) -> None:
        """A fresh smoother anchored at the last estimates (the window's history is lost)."""
        n_seg = self.robot.n_segments
        o = self.options
        calibration = None
        if self.calibrate:
            try:
                calibration = self._calibration_now()
            except (RuntimeError, IndexError):
                calibration = None  # the broken state cannot say: back to the robot's values
        self._smoother = self._new_smoother()
        self._active.clear()
        self._keyframes.clear()
        graph = gtsam.NonlinearFactorGraph()
        values = gtsam.Values()
        stamps = gtsam.FixedLagSmootherKeyTimestampMap()
        t = self._history[-1].stamp
        for i in range(n_seg):
            key = angle_key(f, i, n_seg)
            values.insert(key, np.array([thetas[i]]))
            stamps.insert((key, t))
            graph.add(angle_prior(key, thetas[i], self.loose_sigma))
            graph.add(joint_limit_factor(key, self.robot.segments[i].theta_max, o.limit_sigma))
        if self.calibrate:
            self._add_calibration(graph, values, calibration)
            for i in range(n_seg):
                for key in _calibration_keys(i):
                    stamps.insert((key, t))
        self._smoother.update(graph, values, stamps)
        # Older frames can no longer be referenced: keep their estimates as final.
        for g in [g for g in self._window if g != f]:
            est = self._thetas.get(g, thetas)
            self._window.pop(g)
            self._final[g] = SmootherFrame(g, self._times.pop(g), est.copy(),
                                           np.full(n_seg, np.nan), self._status.pop(g))
            self._thetas.pop(g, None)
        for h in list(self._history)[:-1]:
            self._history.remove(h)

    def _read_window(self, everything: bool = False, frames: set[int] | None = None) -> None:
        """Refresh the estimates the next frame needs (the frames it will be paired with and
        the two it is predicted from), or every frame in the window, or ``frames``."""
        n_seg = self.robot.n_segments
        f = self._count
        if frames is not None:
            wanted = set(frames)
        elif everything:
            wanted = set(self._window) | {f}
        else:
            wanted = ({f, f - 1} | {f + 1 - gap for gap in self.options.gaps}
                      | {kf.index for kf in self._keyframes})
        by_index = {h.index: h for h in self._history}
        by_index.update({kf.index: kf for kf in self._keyframes})
        for g in sorted(wanted):
            if g < 0 or (g not in self._window and g != f):
                continue
            try:
                self._thetas[g] = np.array([
                    self._smoother.calculateEstimateVector(angle_key(g, i, n_seg))[0]
                    for i in range(n_seg)])
            except (RuntimeError, IndexError, KeyError):
                continue  # already marginalised
            if g in by_index:
                self._set_positions(by_index[g], self._thetas[g])

    def _sigmas(self, g: int) -> FloatArray:
        n_seg = self.robot.n_segments
        out = np.full(n_seg, np.nan)
        if self.backend == "batch":
            return out  # BatchFixedLagSmoother has no marginalCovariance
        for i in range(n_seg):
            try:
                cov = self._smoother.marginalCovariance(angle_key(g, i, n_seg))
                out[i] = math.sqrt(max(float(cov[0, 0]), 0.0))
            except (RuntimeError, IndexError, ValueError):
                pass  # not in gtsam's Bayes tree (an unconstrained variable): unknown, NaN
        return out

    def _calibration_now(self) -> FloatArray | None:
        if not self.calibrate:
            return None
        est = self._smoother.calculateEstimate()
        return np.array([[est.atVector(key)[0] for key in _calibration_keys(i)]
                         for i in range(self.robot.n_segments)])

    def _frame_estimate(self, f: int, t: float, status: NDArray[np.str_]) -> SmootherFrame:
        n_seg = self.robot.n_segments
        sigmas = self._sigmas(f) if self.uncertainty else np.full(n_seg, np.nan)
        return SmootherFrame(f, t, self._thetas[f].copy(), sigmas, status.copy(),
                             self._calibration_now())

    def pop_final(self) -> list[SmootherFrame]:
        """The frames that left the window since the last call, in order, and forget them.

        For long or endless streams: memory then stays bounded by the window.
        """
        out = [self._final[g] for g in sorted(self._final)]
        self._final.clear()
        return out

    def refine(self, iterations: int = 1) -> None:
        """Spend spare time: more Gauss-Newton steps on the current window (no new frame).

        With ``linearization="relinearize"`` this converges to the window's optimum; with
        first-estimate factors, to the optimum of their linearisation.
        """
        for _ in range(int(iterations)):
            try:
                self._smoother.update(gtsam.NonlinearFactorGraph(), gtsam.Values(),
                                      gtsam.FixedLagSmootherKeyTimestampMap())
            except RuntimeError:
                self._recoveries += 1
                break
        self._read_window(everything=True)

    # ------------------------------------------------------------------------- output
    def finish(self) -> list[SmootherFrame]:
        """Every frame's final estimate, in order (frames still in the window: their current
        smoothed estimate), except frames already taken by :meth:`pop_final`. The smoother can
        keep receiving frames afterwards."""
        n_seg = self.robot.n_segments
        self._read_window(everything=True)
        out = dict(self._final)
        for g in self._window:
            sigmas = self._sigmas(g) if self.uncertainty else np.full(n_seg, np.nan)
            out[g] = SmootherFrame(g, self._times[g], self._thetas[g].copy(), sigmas,
                                   self._status[g].copy(), self._calibration_now())
        return [out[g] for g in sorted(out)]

    def calibration(self) -> Mapping[int, tuple[float, float]] | None:
        """Current ``{segment: (k, delta_max)}`` when self-calibrating, else ``None``."""
        now = self._calibration_now()
        if now is None:
            return None
        return {i: (float(k), float(d)) for i, (k, d) in enumerate(now)}

    def __iter__(self) -> Iterator[SmootherFrame]:
        return iter(self.finish())


def smoother_estimate(
    sequence: Sequence,
    theta0: ArrayLike | None = None,
    lag: float = 1.0,
    options: GraphOptions | None = None,
    progress: bool = False,
    vision: str = "projection",
    **smoother_options: Any,
) -> Estimate:
    """Run a fixed-lag smoother over a recorded sequence, frame by frame.

    Each frame's angles are its final smoothed estimate (the last update in which it was inside
    the window). Ground-truth columns are never read.

    Args:
        sequence: the sequence.
        theta0: ``(S,)`` starting configuration in radians (default straight).
        lag: window length in seconds.
        options: graph construction (:class:`~apcc_graph.estimation.batch.GraphOptions`).
        progress: show a progress bar.
        vision: ``"projection"`` (default:
            :class:`~apcc_graph.estimation.projection_smoother.ProjectionFixedLagSmoother`,
            every observation once) or ``"epipolar"`` (:class:`FixedLagSmoother`, the
            generalized epipolar model, for comparison; it also self-calibrates).
        **smoother_options: further smoother arguments.

    Returns:
        The estimate, ``method = "smoother"``; ``inliers`` is 0 (the factors weigh each
        correspondence instead of classifying it).
    """
    if vision == "projection":
        from apcc_graph.estimation.projection_smoother import projection_smoother_estimate

        if smoother_options.get("calibrate"):
            raise ValueError("calibrate=True: the projection smoother does not self-calibrate; "
                             "use the batch (method 'batch', calibrate=True) or the epipolar "
                             "smoother (vision='epipolar')")
        smoother_options.pop("calibrate", None)

        return projection_smoother_estimate(sequence, theta0=theta0, lag=lag, options=options,
                                            progress=progress, **smoother_options)
    if vision != "epipolar":
        raise ValueError(f"vision = {vision!r}: expected 'epipolar' or 'projection'")
    smoother = FixedLagSmoother(sequence.robot, lag=lag, options=options, theta0=theta0,
                                **smoother_options)
    for f in tqdm(range(sequence.n_frames), desc="smoother", disable=not progress):
        smoother.update(sequence.frame(f))
    frames = smoother.finish()
    n_seg = sequence.n_segments
    return Estimate(
        method="smoother", robot=sequence.robot, timestamps=sequence.timestamps.copy(),
        thetas=np.array([fr.thetas for fr in frames]),
        sigmas=np.array([fr.sigmas for fr in frames]),
        status=np.array([fr.status for fr in frames], dtype="<U24"),
        inliers=np.zeros((sequence.n_frames, n_seg), dtype=np.int64),
        world_T_base=sequence.world_T_base)
