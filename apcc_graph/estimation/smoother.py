"""The fixed-lag smoother: :class:`FixedLagSmoother`, behind ``estimate(..., method="smoother")``.

Every observation enters the graph once, in a projection factor that eliminates its track's
point or, for a track that outlives the window, as a landmark observation (``apcc-graph bench
smoother`` measures it against the Cramer-Rao bounds). It drives the window (``window``), the
graph (``graph``: angles per frame, start prior, weak motion prior, soft joint limits,
projection factors), the track pieces, committed when their track ends, when their first frame
is about to leave the window, or at ``GraphOptions.max_track_frames`` (``projection_tracks``,
``live_tracks``), the new frame's initial angles (``initial_guess``), the landmarks
(``landmarks``) and the still frames (``stillness``), all in :mod:`apcc_graph.estimation`.

gtsam's iSAM2 holds the window (:mod:`~apcc_graph.estimation.fixed_lag`: the same bytes on
every run), re-linearises the factors whose frames move more than ``relinearize_threshold`` and
marginalises frames older than ``lag``.

Failure modes handled: a frame without tracks (the motion prior carries it; without a motion
prior, a loose prior at the initial guess keeps the system determined, so marginalising such a
frame is safe); a robot standing still (after a few still frames the next ones are held out of
the graph: :mod:`apcc_graph.estimation.stillness`); gtsam's indeterminate-system exception
(caught; the smoother restarts from its last estimate with the start prior at that estimate);
tracks that return after a blackout, or none after a pause of more than half a second (both
re-acquired, a pause twice), and one camera's that return after the window lost its segment
(that segment re-acquired: :mod:`apcc_graph.estimation.smoother_restarts`); a start that
contradicts the first second's images (replaced by the unknown-start search's answer:
:mod:`apcc_graph.estimation.start_check`); a model the images contradict (every 2 s of final
frames is tested: :mod:`apcc_graph.estimation.fit_monitor`)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import fields
from typing import Any

import gtsam
import numpy as np
from numpy.typing import ArrayLike, NDArray

from apcc_graph.estimation.bends import parameterisation, start_vector
from apcc_graph.estimation.blackout import Reacquisition
from apcc_graph.estimation.fit_monitor import BlockFit, FitMonitor
from apcc_graph.estimation.fixed_lag import WindowSolver
from apcc_graph.estimation.frame_priors import frame_priors
from apcc_graph.estimation.front_end import front_end_guess
from apcc_graph.estimation.initial_guess import predict, refine, row_inliers
from apcc_graph.estimation.landmarks import Additions, Landmarks
from apcc_graph.estimation.options import GraphOptions, Robustness
from apcc_graph.estimation.projection_tracks import LiveFactor, ProjectionTracks, Rows, frame_rows
from apcc_graph.estimation.rotation_gate import gate_weights, judge_frame
from apcc_graph.estimation.smoother_options import SmootherOptions, smoother_settings
from apcc_graph.estimation.smoother_restarts import Restarts
from apcc_graph.estimation.start_check import FirstFrames
from apcc_graph.estimation.stillness import StillFrames
from apcc_graph.estimation.window import (
    SmootherFrame,
    Window,
    check_timestamp,
    key_stamps,
    new_gtsam_smoother,
    present_frame,
    start_angles,
    warn_restart,
)
from apcc_graph.factors.keys import frame_key
from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.robot import Robot
from apcc_graph.model.sequence import FrameObservations


class FixedLagSmoother(Restarts):
    """Streaming estimator of a robot's segment angles: ``update(frame)`` once per frame.

    Args:
        robot: the robot model.
        lag: window length (seconds); default ``settings.lag`` (1 s).
        options: the measurement model (:class:`~apcc_graph.estimation.options.GraphOptions`).
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

    The settings' fields read back as attributes (``smoother.lag``).

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
        self.inlier_sigmas = (robustness or Robustness()).inlier_sigmas
        self.spatial = bool(spatial)
        self.bending = b = parameterisation(robot, self.spatial)  # every frame's variables
        self.theta0 = start_vector(robot, b, start_angles(name, robot, theta0), psi0)
        self.start_contradicted = False  # the first frame's images contradicted theta0
        self.robot = robot
        self.options = o = GraphOptions() if options is None else options
        self._window = Window(s.lag, b.width**2 * robot.n_segments,
                              lambda: new_gtsam_smoother(s.lag, s.relinearize_threshold,
                                                         s.factorization, s.reproducible),
                              lambda frame: present_frame(b, frame))
        self._tracks = ProjectionTracks(robot, o, s, self._window, b, self.inlier_sigmas)
        w = self._window
        self._landmarks = Landmarks(robot, self._tracks.chain, lambda g: (w.thetas[g], w.times[g]),
                                    o.threshold_px, self.inlier_sigmas, s.lag, s.max_landmarks,
                                    s.landmark_sigma, s.pose_sigma, self._tracks.dim)
        self._previous_rows: Rows = {}
        self._previous_base: FloatArray | None = None
        self._rng = np.random.default_rng(0)
        self._live_indices: list[int] = []
        self._full_window: int | None = None  # frames in a full window, once one left
        self._last_seen: int | None = None  # the last graph frame with tracks
        self._reacquiring: Reacquisition | None = None
        self._first: FirstFrames | None = FirstFrames(  # for the start search, if need be
            Reacquisition(robot, o, self.inlier_sigmas, b, self.theta0, o.theta0_sigma),
            self.spatial, robustness or Robustness())
        self._still = StillFrames(math.inf if s.still_frames is None else s.still_frames,
                                  s.still_chi2)
        alarm = (robustness or Robustness()).misfit_alarm
        self._monitor = (None if alarm is None or s.misfit_seconds is None else FitMonitor(
            robot, b, o, self.inlier_sigmas, alarm, s.misfit_seconds))

    def __getattr__(self, name: str) -> Any:
        settings = self.__dict__.get("settings")
        if settings is not None and name in {f.name for f in fields(settings)}:
            return getattr(settings, name)
        raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")

    @property
    def _smoother(self) -> WindowSolver:
        """The iSAM2 smoother holding the window (tests replace it to provoke failures)."""
        return self._window.smoother

    @_smoother.setter
    def _smoother(self, smoother: WindowSolver) -> None:
        self._window.smoother = smoother

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
        return self._window.recoveries

    @property
    def committed_observations(self) -> int:
        """Observations committed into the graph so far (each exactly once)."""
        return self._tracks.committed

    @property
    def outlier_observations(self) -> int:
        """Committed observations judged outliers so far."""
        return self._tracks.outliers

    # ------------------------------------------------------------------------- update
    def update(self, observations: FrameObservations) -> SmootherFrame:
        """Add one frame; returns that frame's estimate (filtered: only past frames seen).

        Raises:
            ValueError: a timestamp not after the previous frame's, or observations of a
                segment without a camera.
        """
        window, still = self._window, self._still
        f = window.count  # the graph frame it becomes, unless the robot stands still
        t = check_timestamp(still.count, observations.timestamp, still.last_time)
        rows = frame_rows(self.robot, still.count, observations, self.options.threshold_px)
        if self._monitor is not None:  # checked: every camera it names exists
            self._monitor.observe(still.count, observations)
        base = (None if observations.world_T_base is None
                else np.asarray(observations.world_T_base, dtype=float))
        if still.hold(rows, base, f, t, window.inside(f - 1)):
            return still.held(self._frame_estimate(f - 1))
        t -= still.paused  # the graph's clock stops while the robot stands still
        self._watch_gaps(f, t, rows, still.count - 1, still.last_time or 0.0)
        rows = self._hold_out(rows, t)  # a camera whose lost segment is being re-acquired
        verdicts = judge_frame(  # and frame f - 1's, before its pieces are committed
            f, rows, self._previous_rows if window.inside(f - 1) else {}, self._tracks.live,
            self.settings.rotation_gate)
        self._last_seen = f if rows else self._last_seen
        if self._first is not None:  # frame 0 left at a restart: no verdict on the start
            self._first = self._first.keep(f, t, observations, f == 0 or window.inside(0))
        if self._reacquiring is not None and self._reacquiring.due(t, window.lag):
            self._reacquire(self._reacquiring)  # may leave a second round pending
        if self._reacquiring is not None and not self._reacquiring.due(t, window.lag):
            self._reacquiring.add(f, t, observations)  # every frame, the second round's too
        previous, window.last_time = window.last_time, t
        add = Additions()
        self._make_room(add, f, t, rows)
        weights = {cam: np.ones(len(ids)) for cam, (ids, _, _) in rows.items()}
        marks = {cam: self._landmarks.of(cam, ids) for cam, (ids, _, _) in rows.items()}
        gates = {cam: gate_weights(v) for cam, v in verdicts.items()}
        thetas, status, accepted = self._initial_guess(f, rows, marks, base, weights, gates)
        window.enter(f, t, t, status)
        window.thetas[f] = thetas
        self._tracks.bases[f] = base
        self._observe(add, f, t, rows, marks, weights, verdicts)
        self._tracks.live.vouch(f, accepted)
        self._previous_rows, self._previous_base = rows, base
        frame_priors(add.graph, f, 0.0 if previous is None else t - previous, thetas,
                     self.theta0, window, self.bending, self.options, self.settings.loose_sigma)
        live = self._tracks.live_factors(add.graph)
        self._solve(add.graph, f, t, thetas, live, add.values, add.stamps)
        window.count += 1
        return still.frame_of(self._frame_estimate(f))

    def _make_room(self, add: Additions, f: int, t: float, rows: Rows) -> None:
        """Before frame f (at ``t`` seconds) enters: tracks that outlive the window become
        landmarks, pieces that are due are committed (before their first frames leave the
        window), and the frames the update marginalises leave with their final estimates."""
        window = self._window
        leaving = window.leaving(t)
        first_kept = max(leaving) + 1 if leaving else min(window.stamps, default=f)
        seen = {c: ids for c, (ids, _, _) in rows.items()}
        self._landmarks.forget(seen, t)
        tracks = self._tracks
        if self.settings.landmarks:
            promoted = tracks.live.take_continuing(seen, first_kept, self._landmarks.room())
            for cam, (obs, ids) in promoted.items():
                first, last = int(obs.frames.min()), int(obs.frames.max())
                tracks.count(*self._landmarks.promote(add, cam, obs, ids,
                                                      tracks.span(first, last), t,
                                                      tracks.live.gates(obs)))
        if leaving:  # the window is full: its length in frames, for the staggered cuts
            self._full_window = f - first_kept
        due = tracks.live.take_due(f, seen, first_kept, f % self.settings.commit_every == 0,
                                   window=self._full_window)
        for cam, obs in due.items():
            tracks.commit(add.graph, cam, obs)
        self._retire(leaving)
        tracks.live.drop_frames_before(first_kept)

    def _initial_guess(self, f: int, rows: Rows, marks: Mapping[int, NDArray[np.int64]],
                       base: FloatArray | None, weights: dict[int, FloatArray],
                       gates: Mapping[int, FloatArray]
                       ) -> tuple[FloatArray, NDArray[np.str_], dict[int, NDArray[np.int64]]]:
        """The new frame's angles and status, and per camera the tracks the front end accepted
        (if it ran); ``weights`` get the outlier decisions of its observations of known
        points (those the gate, ``gates``, did not already reject)."""
        S, bending, accepted = self.robot.n_segments, self.bending, {}
        if f == 0:
            return self.theta0.copy(), np.full(S, "initial", dtype="<U24"), accepted
        known, masks = self._tracks.known_rows(rows, marks, self._landmarks, gates)
        previous = self._window.latest(f - 1)
        prediction = predict(previous, self._older(f), bending)
        counts: dict[int, int] = {}
        for cam, mask in masks:
            counts[cam] = counts.get(cam, 0) + int(mask.sum())
        if any(counts.get(cam, 0) < self.settings.front_end_rows for cam in rows):
            prediction, accepted = front_end_guess(
                previous, prediction, self.robot, bending, self._previous_base, base,
                self._previous_rows, rows, self.options.threshold_px, self._rng)
        guess = refine(prediction, self.robot, bending, base, known, self.inlier_sigmas)
        if guess.refined and any(g.min(initial=1.0) == 0.0 for g in gates.values()):
            # the rows the gate held out of the solve are judged at its answer too
            known, masks = self._tracks.known_rows(rows, marks, self._landmarks)
            flags_of = row_inliers(guess.thetas, self.robot, bending, base, known,
                                   self.inlier_sigmas)
        else:
            flags_of = guess.row_inliers
        for (cam, mask), flags in zip(masks, flags_of, strict=True):
            weights[cam][mask] = flags.astype(float)
        status = np.full(S, "ok" if guess.refined else "predicted", dtype="<U24")
        return guess.thetas, status, accepted

    def _observe(self, add: Additions, f: int, t: float, rows: Rows,
                 marks: Mapping[int, NDArray[np.int64]], weights: Mapping[int, FloatArray],
                 verdicts: Mapping[int, NDArray[np.int8]]) -> None:
        """The new observations: of landmarks into the graph (with the gate's verdict so far:
        a landmark observation is final), of other tracks into their live pieces (with the
        gate's verdicts, which the next frame may still change)."""
        for cam, (ids, xy, whiten) in rows.items():
            lm = marks[cam] >= 0
            live = ~lm
            if live.any():
                self._tracks.live.add(f, cam, ids[live], xy[live], whiten[live],
                                      weights[cam][live], verdicts[cam][live])
            if lm.any():
                w = weights[cam][lm] * gate_weights(verdicts[cam][lm])
                self._landmarks.observe(add, f, t, cam, marks[cam][lm], xy[lm], w)
                self._tracks.count(int(lm.sum()), int(np.sum(w == 0.0)))

    # -------------------------------------------------------------------------- solve
    def _solve(self, graph: gtsam.NonlinearFactorGraph, f: int, t: float,
               thetas: FloatArray, live: list[LiveFactor], values: gtsam.Values,
               new_stamps: Mapping[int, float]) -> None:
        """``smoother.update`` with the new frame at ``thetas`` (a restart on failure)."""
        values.insert(frame_key(f), thetas)
        stamps = key_stamps([(frame_key(f), t), *new_stamps.items()])
        try:
            self._smoother.update(graph, values, stamps, self._live_indices)
        except (RuntimeError, IndexError) as error:
            warn_restart(f, t, error)
            self._window.recoveries += 1
            self._restart(f, t, thetas)
            return
        indices = self._smoother.getISAM2Result().getNewFactorsIndices()
        self._live_indices = [int(indices[pos]) for pos, *_ in live]
        self._tracks.keep_points(live)
        self._read_window()

    def _read_window(self) -> None:
        """The latest estimates of the frames and landmarks in the window."""
        estimate = self._smoother.calculateEstimate()
        for g in self._window.stamps:
            key = frame_key(g)
            if estimate.exists(key):
                self._window.thetas[g] = estimate.atVector(key)
        self._landmarks.update_points(estimate)

    def _known(self, cam: int, ids: NDArray[np.int64]) -> NDArray[np.bool_]:
        """Which of a camera's track ids are landmarks or live tracks."""
        return (self._landmarks.of(cam, ids) >= 0) | (self._tracks.live.piece_ids(cam, ids) >= 0)

    def _retire(self, leaving: list[int]) -> None:
        """Record the final estimate of frames that the coming update marginalises."""
        self._landmarks.retire(leaving)
        first = self._first if 0 in leaving else None
        if first is not None and self._window.status[0][0] == "initial":  # replaced next
            self._first, self.start_contradicted = None, first.check(
                self.theta0, self.options.theta0_sigma, self._window.thetas[0],
                lambda: self._smoother.marginalCovariance(frame_key(0)),
                self._window.last_time or 0.0)
            self._reacquiring = self._reacquiring or first.replacement
        for g in sorted(leaving):
            self._window.leave(g, self._window.thetas[g].copy(), self._sigmas(g))
            self._tracks.bases.pop(g, None)

    def _sigmas(self, g: int) -> FloatArray:
        """Frame g's marginal covariance blocks, flattened (see the window)."""
        nan = np.full(self._window.n_segments, np.nan)
        if not self.settings.uncertainty:
            return nan
        try:
            cov = self._smoother.marginalCovariance(frame_key(g))
        except (RuntimeError, IndexError, ValueError):
            return nan  # not in gtsam's Bayes tree
        return self.bending.blocks(cov).ravel()

    def _frame_estimate(self, f: int) -> SmootherFrame:
        window = self._window
        return window.present(SmootherFrame(f, window.times[f], window.thetas[f].copy(),
                                            self._sigmas(f), window.status[f].copy()))

    # ------------------------------------------------------------------------- output
    def pop_final(self) -> list[SmootherFrame]:
        """The frames that left the window since the last call (with the still frames each
        stands for), in order, and forget them."""
        frames = self._still.expand(self._window.pop_final())
        if self._monitor is not None:
            self._monitor.final(frames)
        return frames

    def finish(self) -> list[SmootherFrame]:
        """Commit every live track, then return every frame's final estimate in order (frames
        still in the window: their current smoothed estimate), except frames already taken by
        :meth:`pop_final`. The smoother can keep receiving frames afterwards (tracks then
        start new pieces)."""
        graph = gtsam.NonlinearFactorGraph()
        for cam, obs in self._tracks.live.take_all().items():
            self._tracks.commit(graph, cam, obs)
        if graph.size() and self._window.stamps:
            try:
                self._smoother.update(graph, gtsam.Values(), key_stamps(), self._live_indices)
                self._live_indices = []
                self._read_window()
            except (RuntimeError, IndexError):
                self._window.recoveries += 1
        frames = self._still.expand(self._window.frames(self._sigmas), done=False)
        if self._monitor is not None:
            self._monitor.final(frames)
            self._monitor.flush()
        return frames
