"""The fixed-lag smoother with model error as noise: :class:`PoseSmoother`, behind
``estimate(..., method="smoother", graph=GraphOptions(model_sigma=...))``
(``docs/estimation.md``, "Model error as noise").

The window holds the batch-with-model-noise's graph (:mod:`~apcc_graph.estimation.pose_batch`)
over the last ``lag`` seconds:

- per frame its vector ``x_f`` (start prior, motion prior and joint limits as in the exact
  smoother: :func:`~apcc_graph.estimation.frame_priors.frame_priors`) and every segment tip's
  pose, tied to its base through the segment's APCC transform at ``x_f`` with the model noise
  ``GraphOptions.model_sigma`` (:func:`~apcc_graph.factors.kinematic.segment_tie_factor`);
- per track a point and gtsam's C++ projection factors on the tip poses
  (:mod:`~apcc_graph.estimation.pose_points`, which also holds the model-free outlier
  decisions).

A new frame starts at the two-frame front end's answer from the previous frame's estimate, its
tips at the model's tips there moved by the previous frame's departure from the model (the
model error changes slowly); the points a new frame's rows complete are made in the same
update. gtsam's iSAM2 holds the window (:mod:`~apcc_graph.estimation.fixed_lag`). A gtsam
failure restarts the window at the last estimate
(:class:`~apcc_graph.estimation.window.RestartWarning`).

What the exact smoother does and this one does not (yet): the still-frame hold, the
re-acquisition after a blackout or a pause, the check of the start, the residual test of the
final frames.
"""

from __future__ import annotations

import math

import gtsam
import numpy as np
from numpy.typing import ArrayLike

from apcc_graph.estimation.bends import parameterisation, start_vector
from apcc_graph.estimation.frame_priors import frame_priors
from apcc_graph.estimation.front_end import front_end_guess
from apcc_graph.estimation.initial_guess import predict
from apcc_graph.estimation.options import GraphOptions, Robustness
from apcc_graph.estimation.pose_batch import forward_tips
from apcc_graph.estimation.pose_points import PosePoints
from apcc_graph.estimation.projection_tracks import Rows, frame_rows
from apcc_graph.estimation.rotation_gate import judge_frame
from apcc_graph.estimation.smoother_options import SmootherOptions, smoother_settings
from apcc_graph.estimation.window import (
    SmootherFrame,
    Window,
    new_gtsam_smoother,
    present_frame,
    start_angles,
    warn_restart,
)
from apcc_graph.factors.keys import elimination_group, frame_key, tip_key
from apcc_graph.factors.kinematic import segment_tie_factor
from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.robot import Robot
from apcc_graph.model.sequence import FrameObservations

FINAL_STEPS = 3
"""Gauss-Newton steps of the whole window at :meth:`PoseSmoother.finish` (each update makes
one; the frames still inside have not converged as far as those that left)."""

GATE = 0.02
"""The model-free outlier gate's threshold (radians of bearing) when the settings name none:
the batch with model noise decides its first outliers with the same."""


class PoseSmoother:
    """Streaming estimator with model error as noise: ``update(frame)`` once per frame.

    Args:
        robot: the robot model.
        lag: window length (seconds); default ``settings.lag`` (1 s).
        options: the measurement model; its ``model_sigma`` (position m, rotation rad) is
            required.
        theta0, psi0, spatial, robustness: as
            :class:`~apcc_graph.estimation.smoother.FixedLagSmoother`.
        settings: the smoother's options; this one reads ``lag``, ``uncertainty``,
            ``relinearize_threshold``, ``factorization``, ``reproducible``, ``loose_sigma`` and
            ``rotation_gate`` (default :data:`GATE`).

    Raises:
        ValueError: ``options.model_sigma`` is ``None`` (the exact model: use
            :class:`~apcc_graph.estimation.smoother.FixedLagSmoother`).
    """

    def __init__(self, robot: Robot, lag: float | None = None,
                 options: GraphOptions | None = None, theta0: ArrayLike | None = None,
                 settings: SmootherOptions | None = None, spatial: bool = False,
                 psi0: ArrayLike | None = None, robustness: Robustness | None = None) -> None:
        name = type(self).__name__
        start_angles(name, robot, None)
        self.options = o = GraphOptions() if options is None else options
        if o.model_sigma is None:
            raise ValueError(f"{name}: GraphOptions.model_sigma is None (the exact model); "
                             "give the model noise (position m, rotation rad) or use "
                             "FixedLagSmoother")
        self.settings = s = smoother_settings(settings, lag, name)
        self.robot = robot
        self.spatial = bool(spatial)
        self.bending = b = parameterisation(robot, self.spatial)
        self.theta0 = start_vector(robot, b, start_angles(name, robot, theta0), psi0)
        position, rotation = o.model_sigma
        self._tie_noise = [rotation] * 3 + [position] * 3
        self._gate = GATE if s.rotation_gate is None else s.rotation_gate
        self._window = Window(s.lag, b.width**2 * robot.n_segments,
                              lambda: new_gtsam_smoother(s.lag, s.relinearize_threshold,
                                                         s.factorization, s.reproducible,
                                                         elimination_group),
                              lambda frame: present_frame(b, frame))
        inliers = (robustness or Robustness()).inlier_sigmas
        self._points = PosePoints({c: robot.cameras[c].tip_T_cam  # type: ignore[union-attr]
                                   for c in robot.camera_segments}, s.lag, inliers)
        self._tips: dict[int, FloatArray] = {}  # frame -> (S, 4, 4), frames in the window
        self._models: dict[int, FloatArray] = {}  # frame -> the model's tips at its estimate
        self._bases: dict[int, FloatArray] = {}
        self._previous_rows: Rows = {}
        self._rng = np.random.default_rng(0)

    @property
    def recoveries(self) -> int:
        """How many times a gtsam failure was caught and recovered from."""
        return self._window.recoveries

    @property
    def committed_observations(self) -> int:
        """Observations that became factors so far."""
        return self._points.committed

    @property
    def outlier_observations(self) -> int:
        """Observations left out so far."""
        return self._points.outliers

    def update(self, observations: FrameObservations) -> SmootherFrame:
        """Add one frame; returns that frame's estimate (filtered: only past frames seen).

        Raises:
            ValueError: a timestamp not after the previous frame's, or observations of a
                segment without a camera.
        """
        w = self._window
        f = w.count
        t = w.check_time(f, observations.timestamp)
        rows = frame_rows(self.robot, f, observations, self.options.threshold_px)
        base = (np.eye(4) if observations.world_T_base is None
                else np.asarray(observations.world_T_base, dtype=float))
        verdicts = judge_frame(f, rows, self._previous_rows if w.inside(f - 1) else {},
                               self._points, self._gate)
        previous, w.last_time = w.last_time, t
        graph, values, stamps = gtsam.NonlinearFactorGraph(), gtsam.Values(), {}
        leaving = w.leaving(t)
        self._points.make(graph, values, stamps, t, self._tips, set(leaving))
        for g in sorted(leaving):
            w.leave(g, w.thetas[g].copy(), self._sigmas(g))
            for held in (self._tips, self._models, self._bases):
                held.pop(g, None)
        x = self._guess(f, rows, base)
        w.enter(f, t, t, np.full(self.robot.n_segments, "ok", dtype="<U24"))
        w.thetas[f] = x
        frame_priors(graph, f, 0.0 if previous is None else t - previous, x, self.theta0, w,
                     self.bending, self.options, self.settings.loose_sigma)
        self._add_frame(graph, values, stamps, f, t, x, base)
        self._points.observe(graph, stamps, f, t, rows, verdicts)
        self._points.make(graph, values, stamps, t, self._tips, set())  # with frame f's rows
        self._previous_rows = rows
        try:
            w.smoother.update(graph, values, stamps)
        except (RuntimeError, IndexError) as error:
            warn_restart(f, t, error)
            self._restart(f, t, x, base)
        self._read()
        w.count += 1
        return self._frame_estimate(f)

    def _guess(self, f: int, rows: Rows, base: FloatArray) -> FloatArray:
        """Frame f's vector to start from: the motion's prediction, moved by the two-frame
        front end where the previous frame's cameras share tracks with this one's
        (:func:`~apcc_graph.estimation.front_end.front_end_guess`)."""
        previous = self._window.latest(f - 1)
        if previous is None:
            return self.theta0.copy()
        prediction = predict(previous, self._window.latest(f - 2), self.bending)
        if not (rows and self._previous_rows):
            return prediction
        guess, _ = front_end_guess(previous, prediction, self.robot, self.bending,
                                   self._bases.get(f - 1), base, self._previous_rows, rows,
                                   self.options.threshold_px, self._rng)
        return guess

    def _add_frame(self, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values,
                   stamps: dict[int, float], f: int, t: float, x: FloatArray, base: FloatArray
                   ) -> None:
        """Frame f's vector and tip poses (module docstring: their start), and the ties."""
        model = forward_tips(self.bending, x[None], base[None])[0]
        tips = model.copy()
        if f - 1 in self._tips:  # the previous frame's departure from the model
            tips = model @ np.linalg.inv(self._models[f - 1]) @ self._tips[f - 1]
        self._tips[f], self._models[f], self._bases[f] = tips, model, base
        values.insert(frame_key(f), x)
        stamps[frame_key(f)] = t
        for j in range(self.robot.n_segments):
            values.insert(tip_key(f, j), gtsam.Pose3(tips[j]))
            stamps[tip_key(f, j)] = t
            graph.add(segment_tie_factor(frame_key(f), tip_key(f, j),
                                         base if j == 0 else tip_key(f, j - 1), self.bending,
                                         j, self._tie_noise))

    def _restart(self, f: int, t: float, x: FloatArray, base: FloatArray) -> None:
        """A new window holding frame f alone, at ``x`` with a prior of at least 1 deg."""
        w = self._window
        w.recoveries += 1
        w.renew()
        w.leave_all_but(f, x)
        self._points.reset()
        for held in (self._tips, self._models, self._bases):
            held.clear()
        graph, values, stamps = gtsam.NonlinearFactorGraph(), gtsam.Values(), {}
        sigma = max(self.options.theta0_sigma, math.radians(1.0))
        graph.add(gtsam.PriorFactorVector(frame_key(f), x,
                                          gtsam.noiseModel.Isotropic.Sigma(len(x), sigma)))
        self._add_frame(graph, values, stamps, f, t, x, base)
        w.status[f] = np.full(self.robot.n_segments, "recovered", dtype="<U24")
        w.smoother.update(graph, values, stamps)

    def _read(self) -> None:
        """The latest estimates of the frames in the window: vectors and tips."""
        estimate = self._window.smoother.calculateEstimate()
        S = self.robot.n_segments
        for g in self._window.stamps:
            if not estimate.exists(frame_key(g)):
                continue
            x = estimate.atVector(frame_key(g))
            self._window.thetas[g] = x
            self._tips[g] = np.array([estimate.atPose3(tip_key(g, j)).matrix()
                                      for j in range(S)])
            self._models[g] = forward_tips(self.bending, x[None], self._bases[g][None])[0]

    def _sigmas(self, g: int) -> FloatArray:
        """Frame g's marginal covariance blocks, flattened (see the window)."""
        if not self.settings.uncertainty:
            return np.full(self._window.n_segments, np.nan)
        try:
            cov = self._window.smoother.marginalCovariance(frame_key(g))
        except (RuntimeError, IndexError, ValueError):
            return np.full(self._window.n_segments, np.nan)
        return self.bending.blocks(cov).ravel()

    def _frame_estimate(self, f: int) -> SmootherFrame:
        w = self._window
        return w.present(SmootherFrame(f, w.times[f], w.thetas[f].copy(), self._sigmas(f),
                                       w.status[f].copy()))

    def pop_final(self) -> list[SmootherFrame]:
        """The frames that left the window since the last call, in order, and forget them."""
        return self._window.pop_final()

    def finish(self) -> list[SmootherFrame]:
        """Make the points of every held track, then return every frame's final estimate in
        order (frames still in the window: their current smoothed estimate), except frames
        already taken by :meth:`pop_final`."""
        graph, values, stamps = gtsam.NonlinearFactorGraph(), gtsam.Values(), {}
        self._points.make(graph, values, stamps, self._window.last_time or 0.0, self._tips,
                          set(), force=True)
        if self._window.stamps:
            try:
                self._window.smoother.update(graph, values, stamps)
                for _ in range(FINAL_STEPS):
                    self._window.smoother.update()
                self._read()
            except (RuntimeError, IndexError):
                self._window.recoveries += 1
        return self._window.frames(self._sigmas)
