"""The epipolar fixed-lag smoother (:class:`FixedLagSmoother`) and :func:`smoother_estimate`,
which runs either smoother over a recorded sequence.

The epipolar smoother (``vision="epipolar"``) is kept for comparison and for its online
self-calibration: it grows the epipolar graph (:mod:`apcc_graph.estimation.epipolar_graph`) one
frame at a time. The default smoother is the projection one
(:mod:`apcc_graph.estimation.projection_smoother`); ``docs/estimation.md`` compares them. Graph:

- variables ``theta[f, i]`` (Vector1, radians), key ``f * S + i`` (as the batch);
- a prior on the first frame (``theta0``), a random-walk motion prior between consecutive frames,
  soft joint limits;
- per camera and new frame b, one generalized epipolar factor against every earlier frame
  ``b - gap`` (and keyframe) still in the window, built by the front end
  (:mod:`apcc_graph.estimation.epipolar_front_end`), first-estimate by default
  (:mod:`apcc_graph.estimation.first_estimate`);
- optionally each segment's k and delta_max as variables
  (:mod:`apcc_graph.estimation.online_calibration`).

gtsam's ``IncrementalFixedLagSmoother`` (iSAM2, default) or ``BatchFixedLagSmoother`` holds the
window (:mod:`apcc_graph.estimation.epipolar_window`). Failure modes handled (each has a test):

- a frame without tracks in some or all cameras: the motion prior carries the angles; if the
  motion prior is disabled, a weak prior at the prediction (``loose_sigma``) keeps the system
  determined;
- a robot standing still: pairs without parallax are left out (the motion prior holds it);
- gtsam's indeterminate-system exception: caught; the update is repaired by weak priors on the
  new frame's angles, and if that fails too the smoother restarts from its last estimate;
- gtsam's marginalisation helper losing a variable's clique (``IndexError``): the smoother
  restarts from its last estimate;
- tracks resuming after a blackout: the front end re-initialises from the last frame that
  shares tracks instead of trusting the extrapolated prediction.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import gtsam
import numpy as np
from numpy.typing import ArrayLike, NDArray

from apcc_graph.estimation.epipolar_front_end import EpipolarFrontEnd, StoredFrame
from apcc_graph.estimation.epipolar_graph import angle_key
from apcc_graph.estimation.epipolar_window import EpipolarWindow
from apcc_graph.estimation.first_estimate import FirstEstimateFactors, Fresh
from apcc_graph.estimation.initial_guess import predict
from apcc_graph.estimation.online_calibration import OnlineCalibration
from apcc_graph.estimation.options import GraphOptions
from apcc_graph.estimation.smoother_options import EpipolarSmootherOptions, smoother_settings
from apcc_graph.estimation.window import (
    SmootherFrame,
    StreamingSmoother,
    key_stamps,
    start_angles,
    warn_restart,
)
from apcc_graph.factors.priors import angle_prior, joint_limit_factor, motion_prior
from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.robot import Robot
from apcc_graph.model.sequence import FrameObservations

__all__ = ["FixedLagSmoother"]


class FixedLagSmoother(StreamingSmoother):
    """Streaming estimator of a robot's segment angles: ``update(frame)`` once per frame.

    Args:
        robot: the robot model.
        lag: window length (seconds); default ``settings.lag`` (1 s).
        options: graph construction (:class:`~apcc_graph.estimation.options.GraphOptions`);
            ``gaps`` longer than the window are unused.
        theta0: ``(S,)`` starting configuration in radians (default straight).
        settings: the smoother's options
            (:class:`~apcc_graph.estimation.smoother_options.EpipolarSmootherOptions`).
        **keywords: fields of :class:`EpipolarSmootherOptions` (``backend``, ``calibrate``,
            ``iterations``, ...), overriding ``settings``; they read back as attributes.

    Frames leaving the window keep the estimate (and marginal sigma) of the last update in which
    they were inside it; :meth:`finish` returns every frame's final estimate.

    Example::

        smoother = FixedLagSmoother(robot, lag=1.0)
        for f in range(sequence.n_frames):
            now = smoother.update(sequence.frame(f))   # that frame's estimate
        final = smoother.finish()                      # every frame, smoothed
    """

    settings: EpipolarSmootherOptions
    _window: EpipolarWindow

    def __init__(self, robot: Robot, lag: float | None = None,
                 options: GraphOptions | None = None, theta0: ArrayLike | None = None,
                 settings: EpipolarSmootherOptions | None = None, **keywords: Any) -> None:
        name = type(self).__name__
        start_angles(name, robot, None)  # the robot first
        self.settings = s = smoother_settings(EpipolarSmootherOptions, settings, lag, keywords,
                                              name)
        self.theta0 = start_angles(name, robot, theta0)
        self.robot = robot
        self.options = GraphOptions() if options is None else options
        self._window = EpipolarWindow(s, robot.n_segments)
        self._calibration = OnlineCalibration(robot, s.calibration_sigmas, s.calibrate,
                                              self._window)
        self._front = EpipolarFrontEnd(robot, self.options, s, self._window, self._calibration)
        self._linear = FirstEstimateFactors(s, self._front, self._window)
        self._block_stamp = 0.0
        self._renewed: list[int] = []
        self._anchor_unconstrained = True  # tests turn this off to provoke gtsam's failure

    @property
    def rebuilds(self) -> int:
        """How many first-estimate factors were rebuilt at a moved estimate."""
        return self._linear.rebuilds

    # ---------------------------------------------------------------------------- update
    def update(self, observations: FrameObservations) -> SmootherFrame:
        """Add one frame; returns that frame's estimate (filtered: only past frames seen).

        Raises:
            ValueError: a timestamp not after the previous frame's, or observations of a
                segment without a camera.
        """
        window = self._window
        f = window.count
        t = window.check_time(f, observations.timestamp)
        frame = self._front.ingest(f, t, observations)
        previous, window.last_time = window.last_time, t
        if f % self.settings.marginalise_every == 0:
            self._block_stamp = t
        stamp = frame.stamp = self._block_stamp  # gtsam's timestamp of this frame's variables
        self._renewed = self._keep_previous(f, stamp)
        # Frames leaving in this update keep their current estimate.
        self._linear.forget(set(window.retire(stamp)))
        status = np.full(self.robot.n_segments, "initial" if f == 0 else "ok", dtype="<U24")
        graph = gtsam.NonlinearFactorGraph()
        thetas, measured = self.theta0.copy(), []
        if f > 0:
            thetas = predict(window.latest(f - 1), window.latest(f - 2), self.robot)
            measured = self._front.measure(frame, thetas, status)
            self._linear.add(graph, measured, frame, thetas)
        self._front.set_positions(frame, thetas)
        dt = 0.0 if previous is None else t - previous
        values, stamps = self._new_frame(graph, f, dt, stamp, thetas, unconstrained=not measured)
        remove = []
        if self._linear.rebuilding():
            self._read_window(everything=True)
            remove = self._linear.rebuild_moved(graph, stamp)
        fresh = self._linear.take_fresh()
        self._solve(graph, values, stamps, f, thetas, status, remove)
        if fresh and self.settings.iterations > 1 and "recovered" not in status:
            self._iterate(frame, fresh, thetas, status)
        window.enter(f, t, stamp, status)
        self._front.keep_keyframe(frame, f in window.thetas)
        window.count += 1
        return self._frame_estimate(f, t, status)

    def _new_frame(self, graph: gtsam.NonlinearFactorGraph, f: int, dt: float, stamp: float,
                   thetas: FloatArray, unconstrained: bool
                   ) -> tuple[gtsam.Values, gtsam.FixedLagSmootherKeyTimestampMap]:
        """The new frame's variables at ``thetas`` and their priors (start, motion ``dt``
        seconds after the previous frame, limits near them, the anchor of a frame without
        epipolar factors), the keyframes' renewed timestamps, the calibration at frame 0."""
        n_seg = self.robot.n_segments
        o, s = self.options, self.settings
        values = gtsam.Values()
        stamps: list[tuple[int, float]] = []
        keys = [angle_key(f, i, n_seg) for i in range(n_seg)]
        for g in self._renewed:  # the previous frame stays across a long pause
            stamps += [(angle_key(g, i, n_seg), stamp) for i in range(n_seg)]
        for kf in self._front.keyframes:  # keyframes stay: renew their timestamps
            kf.stamp = self._window.stamps[kf.index] = stamp
            stamps += [(angle_key(kf.index, i, n_seg), stamp) for i in range(n_seg)]
        for i, key in enumerate(keys):
            values.insert(key, np.array([thetas[i]]))
            stamps.append((key, stamp))
            theta_max = self.robot.segments[i].theta_max
            if abs(thetas[i]) > theta_max - s.limit_margin:
                # Soft limits only where they can act (a Python factor costs time).
                graph.add(joint_limit_factor(key, theta_max, o.limit_sigma))
        if f == 0:
            for i, key in enumerate(keys):
                graph.add(angle_prior(key, self.theta0[i], o.theta0_sigma))
            if s.calibrate:
                self._calibration.add(graph, values)
        elif o.motion_sigma is not None:
            self._add_motion(graph, f, keys, dt)
        stamps += self._calibration.stamps(stamp)  # never marginalised
        if f > 0 and o.motion_sigma is None and unconstrained and self._anchor_unconstrained:
            for i, key in enumerate(keys):
                graph.add(angle_prior(key, thetas[i], s.loose_sigma))
        return values, key_stamps(stamps)

    def _keep_previous(self, f: int, stamp: float) -> list[int]:
        """After a pause longer than the lag (or with a lag shorter than a marginalisation
        block) the previous frame would leave the window just before the new one arrives: it
        stays instead (its timestamp renewed to ``stamp``), so that the new frame is measured
        against it and tied to it by the motion prior. Returns the frames renewed."""
        window = self._window
        if f == 0 or not window.inside(f - 1) or window.stamps[f - 1] >= stamp - window.lag:
            return []
        window.stamps[f - 1] = stamp
        for old in self._front.history:
            if old.index == f - 1:
                old.stamp = stamp
        return [f - 1]

    def _add_motion(self, graph: gtsam.NonlinearFactorGraph, f: int, keys: list[int],
                    dt: float) -> None:
        """The random-walk prior from the previous frame, ``dt`` seconds earlier; a prior at its
        last estimate when it has already left the window (a pause longer than the lag)."""
        o, n_seg = self.options, self.robot.n_segments
        if self._window.inside(f - 1):
            for i, key in enumerate(keys):
                graph.add(motion_prior(angle_key(f - 1, i, n_seg), key, o.motion_sigma, dt))
            return
        previous = self._window.latest(f - 1)
        sigma = o.motion_sigma * math.sqrt(max(dt, 1e-9))
        for i, key in enumerate(keys):
            graph.add(angle_prior(key, previous[i], sigma))

    def _iterate(self, frame: StoredFrame, fresh: list[Fresh], point: FloatArray,
                 status: NDArray[np.str_]) -> None:
        """Re-linearise the new frame's factors at its updated estimate while it moves (see
        ``iterations``; iSAM2 backend only)."""
        if not self._linear.incremental:
            return
        f = frame.index
        live = self._linear.live(fresh, point)
        for _ in range(self.settings.iterations - 1):
            self._read_window(frames=self._linear.needed(f, live))
            now = self._window.thetas[f].copy()
            graph, remove, positions = self._linear.relinearized(frame, live, now)
            if not positions:
                return
            self._solve(graph, gtsam.Values(), key_stamps(), f, now, status, remove)
            if "recovered" in status:
                return
            self._linear.swapped(f, live, positions, now)

    # -------------------------------------------------------------------------- solve
    def _solve(self, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values,
               stamps: gtsam.FixedLagSmootherKeyTimestampMap, f: int, thetas: FloatArray,
               status: NDArray[np.str_], remove: list[int] | None = None) -> None:
        """``smoother.update`` with recovery from gtsam's indeterminate-system failure."""
        n_seg = self.robot.n_segments
        pending = self._linear.take_pending()
        try:
            self._smoother.update(graph, values, stamps, remove or [])
            self._linear.register(pending)
        except IndexError as error:
            # gtsam's marginalisation helper lost track of a variable's clique (known
            # IncrementalFixedLagSmoother failures): the state cannot be trusted, start afresh.
            self._window.recoveries += 1
            status[:] = "recovered"
            warn_restart(f, self._window.times.get(f, math.nan), error)
            self._restart(f, thetas)
        except RuntimeError:
            self._window.recoveries += 1
            status[:] = "recovered"
            self._linear.active.clear()  # factor indices are no longer trustworthy
            repair = gtsam.NonlinearFactorGraph()
            for i in range(n_seg):
                repair.add(angle_prior(angle_key(f, i, n_seg), thetas[i],
                                       self.settings.loose_sigma))
            try:
                self._smoother.update(repair, gtsam.Values(), key_stamps())
            except (RuntimeError, IndexError) as error:
                warn_restart(f, self._window.times.get(f, math.nan), error)
                self._restart(f, thetas)
        self._read_window()

    def _restart(self, f: int, thetas: FloatArray) -> None:
        """A fresh smoother anchored at the last estimates (the window's history is lost)."""
        n_seg = self.robot.n_segments
        calibration = None
        if self.settings.calibrate:
            try:
                calibration = self._calibration.current()
            except (RuntimeError, IndexError):
                calibration = None  # the broken state cannot say: back to the robot's values
        self._window.renew()
        self._linear.active.clear()
        graph = gtsam.NonlinearFactorGraph()
        values = gtsam.Values()
        t = self._front.history[-1].stamp
        stamps = []
        for i in range(n_seg):
            key = angle_key(f, i, n_seg)
            values.insert(key, np.array([thetas[i]]))
            stamps.append((key, t))
            graph.add(angle_prior(key, thetas[i], self.settings.loose_sigma))
            graph.add(joint_limit_factor(key, self.robot.segments[i].theta_max,
                                         self.options.limit_sigma))
        if self.settings.calibrate:
            self._calibration.add(graph, values, calibration)
        self._smoother.update(graph, values, key_stamps(stamps + self._calibration.stamps(t)))
        # Older frames can no longer be referenced: keep their estimates as final.
        self._window.leave_all_but(f, thetas)
        self._front.restart()

    def _read_window(self, everything: bool = False, frames: set[int] | None = None) -> None:
        """Refresh the estimates the next frame needs (the frames it will be paired with and
        the two it is predicted from), or every frame in the window, or ``frames``."""
        window = self._window
        f = window.count
        if frames is not None:
            wanted = set(frames)
        elif everything:
            wanted = set(window.stamps) | {f}
        else:
            wanted = ({f, f - 1} | {f + 1 - gap for gap in self.options.gaps}
                      | {kf.index for kf in self._front.keyframes})
        by_index = self._front.by_index()
        for g in window.read(wanted):
            if g in by_index:
                self._front.set_positions(by_index[g], window.thetas[g])

    def _frame_estimate(self, f: int, t: float, status: NDArray[np.str_]) -> SmootherFrame:
        return SmootherFrame(f, t, self._window.thetas[f].copy(), self._window.sigmas(f),
                             status.copy(), self._calibration.current())

    # ------------------------------------------------------------------------- output
    def refine(self, iterations: int = 1) -> None:
        """Spend spare time: more Gauss-Newton steps on the current window (no new frame).

        With ``linearization="relinearize"`` this converges to the window's optimum; with
        first-estimate factors, to the optimum of their linearisation.
        """
        for _ in range(int(iterations)):
            try:
                self._smoother.update(gtsam.NonlinearFactorGraph(), gtsam.Values(),
                                      key_stamps())
            except RuntimeError:
                self._window.recoveries += 1
                break
        self._read_window(everything=True)

    def finish(self) -> list[SmootherFrame]:
        """Every frame's final estimate, in order (frames still in the window: their current
        smoothed estimate), except frames already taken by :meth:`pop_final`. The smoother can
        keep receiving frames afterwards."""
        self._read_window(everything=True)
        return self._window.frames(self._window.sigmas, self._calibration.current)

    def calibration(self) -> Mapping[int, tuple[float, float]] | None:
        """Current ``{segment: (k, delta_max)}`` when self-calibrating, else ``None``."""
        return self._calibration.as_mapping()
