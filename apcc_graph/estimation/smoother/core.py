"""The fixed-lag smoother: :class:`FixedLagSmoother`, behind ``estimate(..., method="smoother")``.

One smoother for both measurement models (:mod:`~apcc_graph.estimation.smoother.measurement`:
the exact model, or model error as noise, chosen by ``GraphOptions.model_sigma``). An update
is a sequence of stages, each with one owner (``docs/architecture.md``, "The smoother's
stages"):

1. **accept** the frame: its timestamp, its rows, the residual test's copy, the still-robot
   hold (:mod:`~apcc_graph.estimation.stillness`);
2. **faults**: the gap detectors (:mod:`~apcc_graph.estimation.smoother.gaps`), the model-free
   gate (:mod:`~apcc_graph.estimation.rotation_gate`), a re-acquisition that is due
   (:class:`~apcc_graph.estimation.smoother.restarts.Recovery`);
3. **make room**: the model commits what must enter before the oldest frames leave; those
   frames leave with their final estimates (and the start is checked when frame 0 leaves:
   :mod:`~apcc_graph.estimation.start_check`);
4. **associate** the frame's tracks with what the window holds (the model);
5. **predict** its vector: the motion's prediction, the two-frame front end where few points
   are known (:func:`~apcc_graph.estimation.front_end.front_end_guess`), refined against the
   known points (:mod:`~apcc_graph.estimation.initial_guess`);
6. **add** its variables, rows and priors (the model; :mod:`~apcc_graph.estimation.frame_priors`);
7. **solve**: one iSAM2 update (:class:`~apcc_graph.estimation.smoother.solver.Solver`, the only
   owner of iSAM2; a gtsam failure restarts the window at the new frame). With keyframes
   (:mod:`~apcc_graph.estimation.smoother.keyframing`) only at a keyframe: another frame keeps
   what it added for the next keyframe's update and returns its predicted estimate.

Frames leave in :meth:`FixedLagSmoother.pop_final`, where the residual test of the final frames
runs every 2 s (:mod:`~apcc_graph.estimation.fit_monitor`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import fields
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from apcc_graph.estimation.bends import parameterisation, start_vector
from apcc_graph.estimation.blackout import Reacquisition
from apcc_graph.estimation.fit_monitor import BlockFit, FitMonitor
from apcc_graph.estimation.frame_priors import frame_priors
from apcc_graph.estimation.front_end import front_end_guess
from apcc_graph.estimation.initial_guess import predict, refine, row_inliers
from apcc_graph.estimation.options import GraphOptions, Robustness
from apcc_graph.estimation.projection_tracks import Rows, frame_rows
from apcc_graph.estimation.rotation_gate import gate_weights, judge_frame
from apcc_graph.estimation.rotation_start import rotation_guess
from apcc_graph.estimation.smoother.fixed_lag import WindowSolver
from apcc_graph.estimation.smoother.keyframing import PENDING, Keyframes, with_status
from apcc_graph.estimation.smoother.measurement import WindowModel, read_estimate, window_model
from apcc_graph.estimation.smoother.restarts import Recovery
from apcc_graph.estimation.smoother.solver import Additions, Solver, new_window
from apcc_graph.estimation.smoother_options import SmootherOptions, smoother_settings
from apcc_graph.estimation.start_check import FirstFrames
from apcc_graph.estimation.stillness import StillFrames
from apcc_graph.estimation.window import (
    SmootherFrame,
    Window,
    check_timestamp,
    present_frame,
    start_angles,
    warn_restart,
)
from apcc_graph.factors.keys import frame_key
from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.robot import Robot
from apcc_graph.model.sequence import FrameObservations


class FixedLagSmoother:
    """Streaming estimator of a robot's segment angles: ``update(frame)`` once per frame.

    Args:
        robot: the robot model.
        lag: window length (seconds); default ``settings.window.lag`` (1 s).
        options: the measurement model (:class:`~apcc_graph.estimation.options.GraphOptions`;
            with ``model_sigma``, model error as noise).
        theta0: ``(S,)`` starting configuration in radians (default straight), held by a prior
            of ``options.theta0_sigma``.
        settings: the smoother's options
            (:class:`~apcc_graph.estimation.smoother_options.SmootherOptions`).
        spatial: the robot bends in 3-D: every frame's variables are its bending vectors
            (:mod:`apcc_graph.estimation.bends`), and the frames returned have ``psis`` and
            ``psi_sigmas``.
        psi0: ``(S,)`` the bending planes at the start (radians; default 0); ``spatial``
            only.
        robustness: the outlier threshold (:class:`~apcc_graph.estimation.options.Robustness`).

    The settings' records read back as attributes (``smoother.window.lag``).

    Example::

        smoother = FixedLagSmoother(robot, lag=1.0, theta0=theta0)
        for f in range(sequence.n_frames):
            now = smoother.update(sequence.frame(f))   # that frame's estimate
            done = smoother.pop_final()                # frames that left the window
        final = smoother.finish()                      # every frame, smoothed
    """

    settings: SmootherOptions

    def __init__(self, robot: Robot, lag: float | None = None,
                 options: GraphOptions | None = None, theta0: ArrayLike | None = None,
                 settings: SmootherOptions | None = None, spatial: bool = False,
                 psi0: ArrayLike | None = None, robustness: Robustness | None = None) -> None:
        name = type(self).__name__
        start_angles(name, robot, None)  # the robot first
        self.settings = s = smoother_settings(settings, lag, name)
        robustness = robustness or Robustness()
        self.inlier_sigmas = robustness.inlier_sigmas
        self.spatial = bool(spatial)
        self.bending = b = parameterisation(robot, self.spatial)  # every frame's variables
        self.theta0 = start_vector(robot, b, start_angles(name, robot, theta0), psi0)
        self.start_contradicted = False  # the first frame's images contradicted theta0
        self.robot = robot
        self.options = o = GraphOptions() if options is None else options
        self._window = Window(s.window.lag, b.width**2 * robot.n_segments,
                              lambda frame: present_frame(b, frame))
        self._model: WindowModel = window_model(robot, o, s, self._window, b,
                                                self.inlier_sigmas)
        self.gate = (self._model.default_gate if s.faults.rotation_gate is None
                     else s.faults.rotation_gate)
        groups = self._model.elimination if s.window.reproducible else None
        self._solver = Solver(lambda: new_window(s.window.lag, s.window.relinearize_threshold,
                                                 s.window.factorization, s.window.reproducible,
                                                 groups, self._model.trust_region))
        self._recovery = Recovery(robot, o, b, self.inlier_sigmas, self.gate, s.window.uncertainty,
                                  self._window, self._solver, self._model)
        self._previous: tuple[Rows, FloatArray | None] = ({}, None)  # last frame's rows, base
        self._keys = (None if s.keyframes is None else
                      Keyframes(s.keyframes, robot, b, warmup=s.window.lag))
        self._rng = np.random.default_rng(0)
        self._mounts = {c: robot.cameras[c].tip_T_cam[:3, :3]  # type: ignore[union-attr]
                        for c in robot.camera_segments}
        self._first: FirstFrames | None = FirstFrames(  # for the start search, if need be
            Reacquisition(robot, o, self.inlier_sigmas, b, self.theta0, o.theta0_sigma),
            self.spatial, robustness)
        self._still = StillFrames(
            math.inf if s.faults.still_frames is None else s.faults.still_frames,
            s.faults.still_chi2)
        alarm = robustness.misfit_alarm
        self._monitor = (None if alarm is None or s.faults.misfit_seconds is None else FitMonitor(
            robot, b, o, self.inlier_sigmas, alarm, s.faults.misfit_seconds))

    def __getattr__(self, name: str) -> Any:
        settings = self.__dict__.get("settings")
        if settings is not None and name in {f.name for f in fields(settings)}:
            return getattr(settings, name)
        raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")

    @property
    def measurement_model(self) -> str:
        """``"exact"`` or ``"model noise"``."""
        return self._model.name

    @property
    def _smoother(self) -> WindowSolver:
        """gtsam's window (tests replace it to provoke failures)."""
        return self._solver.window

    @_smoother.setter
    def _smoother(self, window: WindowSolver) -> None:
        self._solver.window = window

    @property
    def model_fits(self) -> list[BlockFit]:
        """The residual test of every block of final frames so far
        (:mod:`~apcc_graph.estimation.fit_monitor`; empty when it is off)."""
        return [] if self._monitor is None else list(self._monitor.blocks)

    @property
    def n_frames(self) -> int:
        """Frames received so far (held ones included)."""
        return self._still.count

    @property
    def recoveries(self) -> int:
        """How many times a gtsam failure was caught and recovered from."""
        return self._solver.recoveries

    @property
    def committed_observations(self) -> int:
        """Observations committed into the graph so far (each exactly once)."""
        return self._model.committed

    @property
    def outlier_observations(self) -> int:
        """Committed observations judged outliers so far."""
        return self._model.outliers

    # ------------------------------------------------------------------------- update
    def update(self, observations: FrameObservations, busy: bool = False) -> SmootherFrame:
        """Add one frame; returns that frame's estimate (filtered: only past frames seen).
        ``busy`` (with keyframes): the caller has frames waiting, so a keyframe the rule asks
        for may wait (:meth:`~apcc_graph.estimation.smoother.keyframing.Keyframes.decide`).

        Raises:
            ValueError: a timestamp not after the previous frame's, or observations of a
                segment without a camera.
        """
        window, still = self._window, self._still
        f = window.count  # the graph frame it becomes, unless the robot stands still
        # 1. accept
        t = check_timestamp(still.count, observations.timestamp, still.last_time)
        rows = frame_rows(self.robot, still.count, observations, self.options.threshold_px)
        if self._monitor is not None:  # checked: every camera it names exists
            self._monitor.observe(still.count, observations)
        base = (None if observations.world_T_base is None
                else np.asarray(observations.world_T_base, dtype=float))
        if still.hold(rows, base, f, t, window.inside(f - 1)):
            return still.held(self._frame_estimate(f - 1))
        t -= still.paused  # the graph's clock stops while the robot stands still
        # 2. faults
        rows, verdicts = self._faults(f, t, rows, observations, still.count - 1,
                                      still.last_time or 0.0)
        previous, window.last_time = window.last_time, t
        window.lag = self._recovery.lag(t, self.settings.window.lag)
        self._solver.set_lag(window.lag)
        # 3. make room (with keyframes, into the additions of the frames since the last one)
        add = self._take_pending()
        self._make_room(add, f, t, rows)
        # 4. associate, 5. predict
        marks = self._model.associate(rows)
        thetas, status, weights, accepted = self._predict(f, rows, marks, base, verdicts)
        # 6. add
        window.enter(f, t, t, status)
        window.thetas[f] = thetas
        add.variable(frame_key(f), thetas, t)
        self._model.enter(add, f, t, thetas, base)
        self._model.observe(add, f, t, rows, marks, weights, verdicts, accepted)
        self._previous = (rows, base)
        frame_priors(add.graph, f, 0.0 if previous is None else t - previous, thetas,
                     self.theta0, window, self.bending, self.options,
                     self.settings.window.loose_sigma)
        # 7. solve (with keyframes: at a keyframe only)
        if self._keys is not None and self._defer(f, t, rows, base, thetas, status, busy):
            self._keys.wait(add, self._solver.restarts)
            window.count += 1
            return still.frame_of(with_status(self._frame_estimate(f, solved=False), PENDING))
        if self._solver.update(add, self._model.replaceable(add.graph)):
            read_estimate(window, self._model, self._solver.estimate())
        else:
            warn_restart(f, t, self._solver.last_error)
            self._recovery.restart(f, t, thetas)
        window.count += 1
        return still.frame_of(self._frame_estimate(f))

    def _take_pending(self) -> Additions:
        """What the frames since the last keyframe added (with keyframes), for this update."""
        return Additions() if self._keys is None else self._keys.take(self._solver.restarts)

    def _defer(self, f: int, t: float, rows: Rows, base: FloatArray | None, x: FloatArray,
               status: NDArray[np.str_], busy: bool) -> bool:
        """With keyframes: whether graph frame ``f`` waits for the next keyframe's update
        (:mod:`~apcc_graph.estimation.smoother.keyframing`); a keyframe is recorded."""
        keys = self._keys
        assert keys is not None
        measured = f > 0 and bool(np.all(status == "ok"))
        if (f > 0 and self._recovery.reacquiring is None
                and not keys.decide(t, rows, x, base, measured, self._window.latest, busy)):
            return True
        if f == 0:
            keys.decide(t, rows, x, base, False, self._window.latest)
        keys.keyframe(f, t, rows, base)
        return False

    def _faults(self, f: int, t: float, rows: Rows, observations: FrameObservations,
                frame: int, timestamp: float) -> tuple[Rows, Mapping[int, NDArray[np.int8]]]:
        """The detectors and the gate before graph frame ``f`` enters; returns its rows (a
        re-acquired camera's held out) and the gate's verdicts on them."""
        window, recovery = self._window, self._recovery
        previous = self._previous[0] if window.inside(f - 1) else {}
        recovery.watch(f, t, rows, self._previous[0], frame, timestamp)
        rows = recovery.hold_out(rows, t)
        verdicts, agreed = judge_frame(f, rows, previous, self.gate)
        self._model.judge(f - 1, agreed)  # before frame f - 1's pieces are committed
        recovery.saw(f, t, rows)
        if self._first is not None:  # frame 0 left at a restart: no verdict on the start
            self._first = self._first.keep(f, t, observations, f == 0 or window.inside(0))
        replayed = recovery.keep(f, t, observations)
        if replayed is not None:
            self._previous = replayed
        return rows, verdicts

    def _make_room(self, add: Additions, f: int, t: float, rows: Rows) -> None:
        """Before frame f (at ``t`` seconds) enters: the model commits what must be, and the
        frames the update marginalises leave with their final estimates."""
        window = self._window
        leaving = sorted(window.leaving(t))
        first_kept = max(leaving) + 1 if leaving else min(window.stamps, default=f)
        self._model.make_room(add, f, t, rows, leaving, first_kept,
                              f % self.settings.tracks.commit_every == 0
                              if self._keys is None else self._keys.commit_now())
        first = self._first if 0 in leaving else None
        if first is not None and window.status[0][0] == "initial":  # replaced next
            self._first = None
            self.start_contradicted, replacement = first.check(
                self.theta0, self.options.theta0_sigma, window.thetas[0],
                lambda: self._recovery.covariance(0), window.last_time or 0.0)
            self._recovery.reacquiring = self._recovery.reacquiring or replacement
        for g in leaving:
            window.leave(g, window.thetas[g].copy(), self._sigmas(g))
        self._model.retire(leaving, first_kept)

    def _predict(self, f: int, rows: Rows, marks: Any, base: FloatArray | None,
                 verdicts: Mapping[int, NDArray[np.int8]]
                 ) -> tuple[FloatArray, NDArray[np.str_], dict[int, FloatArray],
                            dict[int, NDArray[np.int64]]]:
        """The new frame's vector and status, the outlier decisions of its rows of known
        points (1 elsewhere), and per camera the tracks the front end accepted (if it ran)."""
        S, bending = self.robot.n_segments, self.bending
        weights = {cam: np.ones(len(ids)) for cam, (ids, _, _) in rows.items()}
        if f == 0:
            return self.theta0.copy(), np.full(S, "initial", dtype="<U24"), weights, {}
        gates = {cam: gate_weights(v) for cam, v in verdicts.items()}
        known, masks = self._model.known_rows(rows, marks, gates)
        previous = self._window.latest(f - 1)
        prediction = predict(previous, self._older(f), bending)
        counts: dict[int, int] = {}
        for cam, mask in masks:
            counts[cam] = counts.get(cam, 0) + int(mask.sum())
        accepted: dict[int, NDArray[np.int64]] = {}
        before, before_base = self._previous
        turned = self._model.camera_rotations(f - 1)
        if turned:  # model error as noise: from the cameras' rotations, not the exact model
            prediction = rotation_guess(prediction, bending, base, before, rows, turned,
                                        self._mounts, self._rng)[0]
        elif any(counts.get(cam, 0) < self.settings.tracks.front_end_rows for cam in rows):
            prediction, accepted = front_end_guess(
                previous, prediction, self.robot, bending, before_base, base, before, rows,
                self.options.threshold_px, self._rng)
        guess = refine(prediction, self.robot, bending, base, known, self.inlier_sigmas)
        if guess.refined and any(g.min(initial=1.0) == 0.0 for g in gates.values()):
            # the rows the gate held out of the solve are judged at its answer too
            known, masks = self._model.known_rows(rows, marks)
            flags_of = row_inliers(guess.thetas, self.robot, bending, base, known,
                                   self.inlier_sigmas)
        else:
            flags_of = guess.row_inliers
        for (cam, mask), flags in zip(masks, flags_of, strict=True):
            weights[cam][mask] = flags.astype(float)
        refined = guess.refined or not self._model.refines
        status = np.full(S, "ok" if refined else "predicted", dtype="<U24")
        return guess.thetas, status, weights, accepted

    def _older(self, f: int) -> FloatArray | None:
        """Frame ``f - 2``'s estimate for the constant-velocity prediction of frame ``f``;
        ``None`` (no velocity) across a pause."""
        pause_at = self._recovery.pause_at
        if pause_at is not None and f - 2 < pause_at:
            return None
        return self._window.latest(f - 2)

    def _sigmas(self, g: int) -> FloatArray:
        """Frame g's marginal covariance blocks, flattened (see the window)."""
        return self._recovery.sigmas(g)

    def _frame_estimate(self, f: int, solved: bool = True) -> SmootherFrame:
        """Frame ``f``'s current estimate (``solved``: with its marginal sigmas, which a
        frame iSAM2 has not seen yet has not: NaN)."""
        window = self._window
        sigmas = self._sigmas(f) if solved else np.full(window.n_segments, np.nan)
        return window.present(SmootherFrame(f, window.times[f], window.thetas[f].copy(),
                                            sigmas, window.status[f].copy()))

    # ------------------------------------------------------------------------- output
    def pop_final(self) -> list[SmootherFrame]:
        """The frames that left the window since the last call (with the still frames each
        stands for), in order, and forget them."""
        frames = self._still.expand(self._window.pop_final())
        if self._monitor is not None:
            self._monitor.final(frames)
        return frames

    def finish(self) -> list[SmootherFrame]:
        """Everything the model holds enters the graph, then every frame's final estimate in
        order (frames still in the window: their current smoothed estimate), except frames
        already taken by :meth:`pop_final`. The smoother can keep receiving frames afterwards
        (tracks then start new pieces)."""
        replayed = self._recovery.settle()
        if replayed is not None:
            self._previous = replayed
        add = self._take_pending()
        self._model.finish(add, self._window.last_time or 0.0)
        if self._window.stamps and (add.graph.size() or self._model.final_steps):
            if (self._solver.update(add)
                    and self._solver.relinearise(self._model.final_steps)):
                read_estimate(self._window, self._model, self._solver.estimate())
        frames = self._still.expand(self._window.frames(self._sigmas), done=False)
        if self._monitor is not None:
            self._monitor.final(frames)
            self._monitor.flush()
        return frames
