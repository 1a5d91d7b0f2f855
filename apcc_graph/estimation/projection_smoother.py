"""The fixed-lag smoother on the projection model: ``estimate(..., method="smoother")``.

Every observation enters the graph once, in a projection factor that eliminates its track's
point or, for a track that outlives the window, as a landmark observation; ``apcc-graph bench
smoother`` measures it against the Cramer-Rao bound of the whole sequence and against the bound
of a fixed lag (:func:`apcc_graph.evaluation.sequence_bound.lag_bound`). The older epipolar smoother
(:mod:`apcc_graph.estimation.smoother`, ``vision="epipolar"``) stays for comparison.

This module manages the window and nothing else; the pieces it drives are separate:

- the graph (:mod:`apcc_graph.estimation.graph`): one ``Vector(S)`` of angles per frame, the
  start prior, a weak motion prior, soft joint limits, and projection factors in which every
  observation counts once and each track's point is eliminated (:mod:`factors.projection`);
- the live tracks (:mod:`apcc_graph.estimation.live_tracks`): a track is committed into one
  projection factor, all its observations at once, when it ends, when its first frame is about
  to leave the window, or at ``GraphOptions.max_track_frames``;
- the outlier decisions: when a piece is committed its point is triangulated robustly at the
  current estimates and each observation is judged against it (truncated quadratic,
  ``GraphOptions.inlier_sigmas``);
- the new frame's initial angles (:mod:`apcc_graph.estimation.initial_guess`): the prediction,
  started by the 1-point front end where few points are known, refined against the live tracks'
  and the landmarks' points;
- the landmarks (:mod:`factors.landmark`): tracks that outlive the window keep their point as a
  variable, with gtsam's C++ projection factors on per-frame camera poses tied to the angles.

gtsam's ``IncrementalFixedLagSmoother`` (iSAM2) holds the window; it re-linearises the
projection factors whose frames move more than ``relinearize_threshold``, and marginalises frames
older than ``lag``. A frame's final estimate (and marginal sigma) is the one of the last update
in which it was inside the window; :meth:`FixedLagSmoother.finish` commits the live tracks and
returns every frame's final estimate.

Failure modes handled: a frame without tracks (the motion prior carries it; without a motion
prior, a loose prior at the initial guess keeps the system determined, so marginalising such a
frame is safe); a robot standing still (no parallax: the points are weakly determined, and the
Schur complement leaves the angles to the priors); gtsam's indeterminate-system exception
(caught; the smoother restarts from its last estimate with the start prior at that estimate).
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Mapping
from typing import Any

import gtsam
import numpy as np
from numpy.typing import ArrayLike, NDArray
from tqdm import tqdm

from apcc_graph.estimation.graph import camera_chain, frame_key, limit_factor, values_from
from apcc_graph.estimation.initial_guess import (
    FramePairs,
    FrameRows,
    one_point_guess,
    predict,
    refine,
)
from apcc_graph.estimation.landmarks import Additions, Landmarks
from apcc_graph.estimation.live_tracks import LiveTracks
from apcc_graph.estimation.options import GraphOptions
from apcc_graph.estimation.result import Estimate
from apcc_graph.estimation.robust import gnc_tls_weights
from apcc_graph.estimation.smoother import SmootherFrame
from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.robot import Robot
from apcc_graph.model.sequence import FrameObservations, Sequence
from factors.projection import CameraChain, ProjectionFactor, robust_residual_norms
from factors.track_points import TrackObservations


class ProjectionFixedLagSmoother:
    """Streaming estimator of a robot's segment angles: ``update(frame)`` once per frame.

    Args:
        robot: the robot model.
        lag: window length (seconds); frames older than this are marginalised.
        options: graph construction (:class:`~apcc_graph.estimation.options.GraphOptions`).
        theta0: ``(S,)`` starting configuration in radians (default straight), held by a prior
            of ``options.theta0_sigma``.
        uncertainty: compute marginal sigmas of each new and each final frame.
        relinearize_threshold: iSAM2 re-linearises the factors of a frame whose angles moved
            more than this since their last linearisation (radians).
        loose_sigma: without a motion prior, each frame gets this weak prior at its initial
            guess (radians), so that a frame without observations stays determined.
        min_live_rows: a live piece joins the live factor (and its point the initial guesses)
            once it has this many observations: with two or three, a wrong association cannot
            be told from the rest, and at the start of a sequence such points misled the
            initial guess by degrees. Committed pieces keep all their observations.
        relinearize: keep committed pieces as Python factors that iSAM2 re-linearises when
            their frames move more than ``relinearize_threshold`` (default). ``False``
            linearises each piece once, when it is committed: faster, but the newest frames'
            estimates are still off by about a degree when their pieces commit, and on a
            200-frame room sequence (10% outliers) the error grew from 0.7-2.2x to 12-14x the
            Cramer-Rao bound.
        front_end_rows: a camera whose new observations include fewer than this many of
            tracks with known points (the first frames, after a blackout) has its segment's
            angle started by the 1-point front end from the previous frame
            (:func:`~apcc_graph.estimation.initial_guess.one_point_guess`) before the
            refinement.
        point_iterations: triangulation steps per linearisation of a projection factor, from
            its points of the previous one (iSAM2 compares no costs, so the joint
            Gauss-Newton system is enough: see :func:`factors.projection.reduced_system`).
        commit_every: pieces whose tracks ended are committed together every this many
            frames (they stay in the live factor until then): fewer committed Python factors
            for iSAM2 to re-linearise.
        landmarks: a track that outlives the window becomes a landmark, its point a
            variable (:mod:`factors.landmark`), instead of being cut into pieces with points of
            their own (which loses what the old observations said about the point: 1.4-2.3x on
            the bound of a 1 s lag, and drift).
        landmark_sigma: a landmark's weak prior at its first triangulation (metres), so that
            one seen without parallax stays determined.
        max_landmarks: most landmarks per camera at a time (each update re-eliminates every
            landmark seen in the new frame, so the cost grows with them); the other tracks
            that outlive the window are cut.
        pose_sigma: stiffness of the tie between a frame's angles and its camera-pose
            variables (radians and metres), which the landmarks' observations attach to.

    Example::

        smoother = ProjectionFixedLagSmoother(robot, lag=1.0, theta0=theta0)
        for f in range(sequence.n_frames):
            now = smoother.update(sequence.frame(f))   # that frame's estimate
            done = smoother.pop_final()                # frames that left the window
        final = smoother.finish()                      # every frame, smoothed
    """

    def __init__(
        self,
        robot: Robot,
        lag: float = 1.0,
        options: GraphOptions | None = None,
        theta0: ArrayLike | None = None,
        uncertainty: bool = True,
        relinearize_threshold: float = 3e-4,
        loose_sigma: float = math.radians(30.0),
        relinearize: bool = True,
        min_live_rows: int = 4,
        front_end_rows: int = 20,
        point_iterations: int = 1,
        commit_every: int = 1,
        landmarks: bool = True,
        landmark_sigma: float = 10.0,
        pose_sigma: float = 1e-4,
        max_landmarks: int = 10,
    ) -> None:
        if not isinstance(robot, Robot):
            raise ValueError(f"ProjectionFixedLagSmoother.robot: expected a Robot, got "
                             f"{type(robot).__name__}")
        if not (math.isfinite(lag) and lag > 0.0):
            raise ValueError(f"ProjectionFixedLagSmoother.lag = {lag!r}: expected a positive "
                             "number of seconds")
        S = robot.n_segments
        theta0 = np.zeros(S) if theta0 is None else np.asarray(theta0, dtype=float)
        if theta0.shape != (S,) or not np.all(np.isfinite(theta0)):
            raise ValueError(f"ProjectionFixedLagSmoother.theta0 has shape {theta0.shape}: "
                             f"expected ({S},) finite angles in radians")
        self.robot = robot
        self.lag = float(lag)
        self.options = GraphOptions() if options is None else options
        if self.options.vision != "projection":
            raise ValueError("ProjectionFixedLagSmoother runs the projection model; use "
                             "apcc_graph.estimation.smoother for vision='epipolar'")
        self.theta0 = theta0
        self.uncertainty = uncertainty
        self.relinearize_threshold = float(relinearize_threshold)
        self.loose_sigma = float(loose_sigma)
        self.relinearize = bool(relinearize)
        if int(min_live_rows) < 2:
            raise ValueError(f"ProjectionFixedLagSmoother.min_live_rows = {min_live_rows!r}: "
                             "expected at least 2")
        self.min_live_rows = int(min_live_rows)
        self.front_end_rows = int(front_end_rows)
        self.point_iterations = int(point_iterations)
        if int(commit_every) < 1:
            raise ValueError(f"ProjectionFixedLagSmoother.commit_every = {commit_every!r}: "
                             "expected at least 1")
        self.commit_every = int(commit_every)
        self.landmarks = bool(landmarks)
        self._landmarks = Landmarks(robot, self._chain, self._frame_state,
                                    self.options.threshold_px, self.options.inlier_sigmas,
                                    self.lag, max_landmarks, landmark_sigma, pose_sigma)
        self._previous_rows: dict[int, tuple] = {}
        self._rng = np.random.default_rng(0)
        max_frames = self.options.max_track_frames or 10**9
        self._tracks = LiveTracks(robot.camera_segments, max_frames,
                                  self.options.min_track_rows)
        self._chains = {c: camera_chain(robot, c) for c in robot.camera_segments}
        self._smoother = self._new_smoother()
        self._times: dict[int, float] = {}  # frames inside the window
        self._bases: dict[int, FloatArray | None] = {}
        self._thetas: dict[int, FloatArray] = {}
        self._status: dict[int, NDArray[np.str_]] = {}
        self._final: dict[int, SmootherFrame] = {}
        self._count = 0
        self._recoveries = 0
        self._committed = 0
        self._outliers = 0
        self._live_indices: list[int] = []

    def _new_smoother(self) -> gtsam.IncrementalFixedLagSmoother:
        params = gtsam.ISAM2Params()
        params.setRelinearizeThreshold(self.relinearize_threshold)
        params.relinearizeSkip = 1
        params.findUnusedFactorSlots = False
        return gtsam.IncrementalFixedLagSmoother(self.lag, params)

    @property
    def n_frames(self) -> int:
        """Frames received so far."""
        return self._count

    @property
    def recoveries(self) -> int:
        """How many times a gtsam failure was caught and recovered from."""
        return self._recoveries

    @property
    def committed_observations(self) -> int:
        """Observations committed into the graph so far (each exactly once)."""
        return self._committed

    @property
    def outlier_observations(self) -> int:
        """Committed observations judged outliers so far."""
        return self._outliers

    # ------------------------------------------------------------------------- update
    def update(self, observations: FrameObservations) -> SmootherFrame:
        """Add one frame; returns that frame's estimate (filtered: only past frames seen).

        Raises:
            ValueError: a timestamp not after the previous frame's, or observations of a
                segment without a camera.
        """
        f = self._count
        t = float(observations.timestamp)
        last = self._times.get(f - 1)
        if not math.isfinite(t) or (last is not None and t <= last):
            raise ValueError(f"frame {f}: timestamp {t!r} s is not after the previous frame's "
                             f"{last!r} s")
        rows = self._ingest(f, observations)
        base = (None if observations.world_T_base is None
                else np.asarray(observations.world_T_base, dtype=float))
        leaving = [g for g, tg in self._times.items() if tg < t - self.lag]
        first_kept = max(leaving) + 1 if leaving else min(self._times, default=f)
        add = Additions()
        graph = add.graph
        seen = {c: ids for c, (ids, _, _) in rows.items()}
        self._landmarks.forget(seen, t)
        if self.landmarks:
            promoted = self._tracks.take_continuing(seen, first_kept, self._landmarks.room())
            for cam, (obs, tracks) in promoted.items():
                first, last = int(obs.frames.min()), int(obs.frames.max())
                taken, outliers = self._landmarks.promote(
                    add, cam, obs, tracks, self._span_thetas(first, last), t)
                self._committed += taken
                self._outliers += outliers
        due = self._tracks.take_due(f, seen, first_kept, f % self.commit_every == 0)
        for cam, obs in due.items():
            self._commit(graph, cam, obs)  # before their first frames leave the window
        self._retire(leaving)
        self._tracks.drop_frames_before(first_kept)
        S = self.robot.n_segments
        weights = {cam: np.ones(len(ids)) for cam, (ids, _, _) in rows.items()}
        marks = {cam: self._landmarks.of(cam, ids) for cam, (ids, _, _) in rows.items()}
        if f == 0:
            guess_thetas, status = self.theta0.copy(), np.full(S, "initial", dtype="<U24")
        else:
            known, masks = self._known_rows(rows, marks)
            prediction = predict(self._thetas[f - 1], self._thetas.get(f - 2), self.robot)
            counts: dict[int, int] = {}
            for cam, mask in masks:
                counts[cam] = counts.get(cam, 0) + int(mask.sum())
            if any(counts.get(cam, 0) < self.front_end_rows for cam in rows):
                prediction, _ = one_point_guess(
                    self._thetas[f - 1], prediction, self.robot, self._bases.get(f - 1), base,
                    self._pairs(rows), self.options.threshold_px, self._rng)
            guess = refine(prediction, self.robot, base, known, self.options.inlier_sigmas)
            for (cam, mask), flags in zip(masks, guess.row_inliers, strict=True):
                weights[cam][mask] = flags.astype(float)
            guess_thetas = guess.thetas
            status = np.full(S, "ok" if guess.refined else "predicted", dtype="<U24")
        self._times[f], self._bases[f], self._status[f] = t, base, status
        self._thetas[f] = guess_thetas
        for cam, (ids, xy, whiten) in rows.items():
            lm = marks[cam] >= 0
            live = ~lm
            if live.any():
                self._tracks.add(f, cam, ids[live], xy[live], whiten[live], weights[cam][live])
            if lm.any():
                self._landmarks.observe(add, f, t, cam, marks[cam][lm], xy[lm],
                                        weights[cam][lm])
                self._committed += int(lm.sum())
                self._outliers += int(np.sum(weights[cam][lm] == 0.0))
        self._previous_rows = rows
        self._add_frame(graph, f, t, guess_thetas)
        live_factors = self._live_factors(graph)
        self._solve(graph, f, t, guess_thetas, live_factors, add.values, add.stamps)
        self._count += 1
        return self._frame_estimate(f)

    def _ingest(self, f: int, obs: FrameObservations
                ) -> dict[int, tuple[NDArray[np.int64], FloatArray, FloatArray]]:
        """camera -> (track ids, normalised points, whitening) of the new frame."""
        out = {}
        for cam, (track_ids, uv) in obs.tracks.items():
            camera = self.robot.cameras[cam] if 0 <= cam < self.robot.n_segments else None
            if camera is None:
                raise ValueError(f"frame {f}: observations of camera {cam}, but segment {cam} "
                                 f"has no camera (cameras ride on {self.robot.camera_segments})")
            ids = np.asarray(track_ids, dtype=np.int64)
            if len(ids) == 0:
                continue
            given = None if obs.bearings is None else obs.bearings.get(cam)
            if given is None:
                xy = camera.normalized(np.asarray(uv, dtype=float))
            else:
                b = np.asarray(given, dtype=float)
                xy = b[:, :2] / b[:, 2:3]
            out[cam] = (ids, xy, camera.pixel_jacobian(xy) / self.options.threshold_px)
        return out

    def _pairs(self, rows: Mapping[int, tuple]) -> list[FramePairs]:
        """Each camera's correspondences between the previous frame and the new one."""
        out = []
        for cam, (ids, xy, _) in rows.items():
            before = self._previous_rows.get(cam)
            if before is None:
                continue
            common, now, then = np.intersect1d(ids, before[0], return_indices=True)
            if len(common) == 0:
                continue

            def unit(p: FloatArray) -> FloatArray:
                b = np.column_stack([p, np.ones(len(p))])
                return b / np.linalg.norm(b, axis=1, keepdims=True)

            out.append(FramePairs(cam, unit(before[1][then]), unit(xy[now]), now))
        return out

    def _chain(self, cam: int, first: int, last: int) -> CameraChain:
        """Camera ``cam``'s chain with the base poses of frames ``first..last``."""
        chain = self._chains[cam]
        bases = [self._bases.get(g) for g in range(first, last + 1)]
        if all(b is None for b in bases):
            return chain
        stack = np.stack([np.eye(4) if b is None else b for b in bases])
        return CameraChain(chain.segments, chain.tip_T_cam, stack, None, first)

    def _frame_state(self, g: int) -> tuple[FloatArray, float]:
        return self._thetas[g], self._times[g]

    def _span_thetas(self, first: int, last: int) -> FloatArray:
        return np.array([self._thetas[g] for g in range(first, last + 1)])

    def _commit(self, graph: gtsam.NonlinearFactorGraph, cam: int,
                obs: TrackObservations) -> None:
        """One projection factor for camera ``cam``'s committed pieces, with the outlier
        decisions taken against each piece's robust point at the current estimates."""
        first, last = int(obs.frames.min()), int(obs.frames.max())
        factor = ProjectionFactor(obs, self._chain(cam, first, last), self.robot.n_segments)
        norms = factor.residual_norms(self._span_thetas(first, last), robust=True)
        factor.weights[:] = gnc_tls_weights(norms, self.options.inlier_sigmas, math.inf)
        self._committed += len(obs)
        self._outliers += int(np.sum(factor.weights == 0.0))
        if not factor.weights.any():
            return
        if self.relinearize:
            factor.point_iterations = self.point_iterations
            graph.add(factor.factor())
            return
        # Linearised once, here, at estimates the window has refined for as long as the piece
        # was live: a C++ factor iSAM2 never calls back into Python for.
        values = values_from(self._span_thetas(first, last), range(first, last + 1))
        graph.add(gtsam.LinearContainerFactor(factor.factor().linearize(values), values))

    def _known_rows(self, rows: Mapping[int, tuple], marks: Mapping[int, NDArray[np.int64]]
                    ) -> tuple[list[FrameRows], list[tuple[int, NDArray[np.bool_]]]]:
        """The new frame's observations of live tracks whose points are known and of
        landmarks, and per entry the camera and the mask of those rows."""
        out, masks = [], []
        for cam, (ids, xy, whiten) in rows.items():
            found = self._landmarks.known_rows(cam, marks[cam], xy, whiten)
            if found is not None:
                out.append(found[0])
                masks.append((cam, found[1]))
            pieces = self._tracks.piece_ids(cam, ids)
            points = self._tracks.points(cam)
            known = np.array([p in points for p in pieces.tolist()], dtype=bool)
            if known.any():
                pts = np.array([points[p] for p in pieces[known].tolist()])
                out.append(FrameRows(cam, pts, xy[known], whiten[known]))
                masks.append((cam, known))
        return out, masks

    def _live_factors(self, graph: gtsam.NonlinearFactorGraph
                      ) -> list[tuple[int, int, ProjectionFactor]]:
        """One projection factor per camera over its live (uncommitted) pieces, added to
        ``graph``; it replaces the previous update's, so every observation is in exactly one
        factor at a time. A piece seen for the first time here gets its outlier decisions from
        a robust triangulation; later observations were judged by the initial guess against
        its point. Returns (position in graph, camera, factor)."""
        out = []
        for cam in self.robot.camera_segments:
            found = self._tracks.live_rows(cam, self.min_live_rows)
            if found is None:
                continue
            obs, weights, index = found
            first, last = int(obs.frames.min()), int(obs.frames.max())
            chain = self._chain(cam, first, last)
            points = self._tracks.points(cam)
            new = np.array([int(p) not in points for p in obs.ids], dtype=bool)
            if new.any():
                part = obs.select(np.flatnonzero(new))
                rows = np.concatenate([np.arange(obs.starts[t], obs.starts[t + 1])
                                       for t in np.flatnonzero(new)])
                norms, found_points = robust_residual_norms(
                    part, chain, self._span_thetas(first, last), first, np.ones(len(part)))
                decided = gnc_tls_weights(norms, self.options.inlier_sigmas, math.inf)
                weights[rows] = decided
                self._tracks.set_weights(cam, index[rows], decided)
                for piece, point in zip(part.ids.tolist(), found_points, strict=True):
                    points[piece] = point
            if not weights.any():
                continue
            factor = ProjectionFactor(obs, chain, self.robot.n_segments, weights)
            factor.points = np.array([points[int(p)] for p in obs.ids])
            factor.point_iterations = self.point_iterations
            out.append((graph.size(), cam, factor))
            graph.add(factor.factor())
        return out

    def _add_frame(self, graph: gtsam.NonlinearFactorGraph, f: int, t: float,
                   thetas: FloatArray) -> None:
        """Priors of the new frame: start prior (frame 0), motion prior, limits near them."""
        S = self.robot.n_segments
        key = frame_key(f)
        o = self.options
        if f == 0:
            graph.add(gtsam.PriorFactorVector(key, self.theta0,
                                              gtsam.noiseModel.Isotropic.Sigma(S,
                                                                               o.theta0_sigma)))
        elif o.motion_sigma is not None:
            dt = max(t - self._times[f - 1], 1e-9)
            graph.add(gtsam.BetweenFactorVector(
                frame_key(f - 1), key, np.zeros(S),
                gtsam.noiseModel.Isotropic.Sigma(S, o.motion_sigma * math.sqrt(dt))))
        if f > 0 and o.motion_sigma is None:
            graph.add(gtsam.PriorFactorVector(key, thetas,
                                              gtsam.noiseModel.Isotropic.Sigma(S,
                                                                               self.loose_sigma)))
        theta_max = np.array([s.theta_max for s in self.robot.segments])
        if np.any(np.abs(thetas) > theta_max - math.radians(10.0)):
            graph.add(limit_factor(key, theta_max, o.limit_sigma))

    def _solve(self, graph: gtsam.NonlinearFactorGraph, f: int, t: float,
               thetas: FloatArray, live: list[tuple[int, int, ProjectionFactor]],
               new_values: gtsam.Values | None = None,
               new_stamps: Mapping[int, float] | None = None) -> None:
        values = gtsam.Values() if new_values is None else new_values
        values.insert(frame_key(f), thetas)
        stamps = gtsam.FixedLagSmootherKeyTimestampMap()
        stamps.insert((frame_key(f), t))
        for key, stamp in (new_stamps or {}).items():
            stamps.insert((key, stamp))
        try:
            self._smoother.update(graph, values, stamps, self._live_indices)
        except (RuntimeError, IndexError):
            self._restart(f, t, thetas)
            return
        indices = self._smoother.getISAM2Result().getNewFactorsIndices()
        self._live_indices = [int(indices[pos]) for pos, *_ in live]
        for _, cam, factor in live:
            # The points of the linearisation start the next frame's initial guess.
            points = self._tracks.points(cam)
            if factor.points is not None:
                for piece, point in zip(factor.obs.ids.tolist(), factor.points, strict=True):
                    points[piece] = point
        estimate = self._smoother.calculateEstimate()
        for g in self._times:
            key = frame_key(g)
            if estimate.exists(key):
                self._thetas[g] = estimate.atVector(key)
        self._landmarks.update_points(estimate)

    def _restart(self, f: int, t: float, thetas: FloatArray) -> None:
        """After a gtsam failure: a new smoother holding only frame f, at its guess, with a
        prior of ``options.theta0_sigma`` (frames in the window keep their last estimates)."""
        self._recoveries += 1
        self._smoother = self._new_smoother()
        graph = gtsam.NonlinearFactorGraph()
        S = self.robot.n_segments
        graph.add(gtsam.PriorFactorVector(frame_key(f), thetas, gtsam.noiseModel.Isotropic.Sigma(
            S, max(self.options.theta0_sigma, math.radians(1.0)))))
        values = gtsam.Values()
        values.insert(frame_key(f), thetas)
        stamps = gtsam.FixedLagSmootherKeyTimestampMap()
        stamps.insert((frame_key(f), t))
        self._smoother.update(graph, values, stamps)
        for g in [g for g in self._times if g != f]:
            self._final[g] = SmootherFrame(g, self._times.pop(g), self._thetas.pop(g).copy(),
                                           np.full(S, np.nan), self._status.pop(g))
            self._bases.pop(g, None)
        self._status[f] = np.full(S, "recovered", dtype="<U24")
        self._tracks = LiveTracks(self.robot.camera_segments, self._tracks.max_frames,
                                  self._tracks.min_rows)
        self._live_indices = []
        self._landmarks.reset()

    def _retire(self, leaving: list[int]) -> None:
        """Record the final estimate of frames that the coming update marginalises."""
        self._landmarks.retire(leaving)
        for g in sorted(leaving):
            sigmas = self._sigmas(g)
            self._final[g] = SmootherFrame(g, self._times.pop(g), self._thetas.pop(g).copy(),
                                           sigmas, self._status.pop(g))
            self._bases.pop(g, None)

    def _sigmas(self, g: int) -> FloatArray:
        S = self.robot.n_segments
        if not self.uncertainty:
            return np.full(S, np.nan)
        try:
            cov = self._smoother.marginalCovariance(frame_key(g))
            return np.sqrt(np.maximum(np.diag(cov), 0.0))
        except (RuntimeError, IndexError, ValueError):
            return np.full(S, np.nan)  # not in gtsam's Bayes tree

    def _frame_estimate(self, f: int) -> SmootherFrame:
        return SmootherFrame(f, self._times[f], self._thetas[f].copy(), self._sigmas(f),
                             self._status[f].copy())

    # ------------------------------------------------------------------------- output
    def pop_final(self) -> list[SmootherFrame]:
        """The frames that left the window since the last call, in order, and forget them.

        For long or endless streams: memory then stays bounded by the window.
        """
        out = [self._final[g] for g in sorted(self._final)]
        self._final.clear()
        return out

    def finish(self) -> list[SmootherFrame]:
        """Commit every live track, then return every frame's final estimate in order (frames
        still in the window: their current smoothed estimate), except frames already taken by
        :meth:`pop_final`. The smoother can keep receiving frames afterwards (tracks then
        start new pieces)."""
        graph = gtsam.NonlinearFactorGraph()
        for cam, obs in self._tracks.take_all().items():
            self._commit(graph, cam, obs)
        if graph.size() and self._times:
            try:
                self._smoother.update(graph, gtsam.Values(),
                                      gtsam.FixedLagSmootherKeyTimestampMap(),
                                      self._live_indices)
                self._live_indices = []
                estimate = self._smoother.calculateEstimate()
                for g in self._times:
                    if estimate.exists(frame_key(g)):
                        self._thetas[g] = estimate.atVector(frame_key(g))
            except (RuntimeError, IndexError):
                self._recoveries += 1
        out = dict(self._final)
        for g in self._times:
            out[g] = SmootherFrame(g, self._times[g], self._thetas[g].copy(), self._sigmas(g),
                                   self._status[g].copy())
        return [out[g] for g in sorted(out)]

    def calibration(self) -> Mapping[int, tuple[float, float]] | None:
        """Self-calibration is not part of the projection smoother yet: ``None``."""
        return None

    def __iter__(self) -> Iterator[SmootherFrame]:
        return iter(self.finish())


def projection_smoother_estimate(
    sequence: Sequence,
    theta0: ArrayLike | None = None,
    lag: float = 1.0,
    options: GraphOptions | None = None,
    progress: bool = False,
    **smoother_options: Any,
) -> Estimate:
    """Run :class:`ProjectionFixedLagSmoother` over a recorded sequence, frame by frame.

    Each frame's angles are its final smoothed estimate (the last update in which it was inside
    the window). Ground-truth columns are never read.

    Args:
        sequence: the sequence.
        theta0: ``(S,)`` starting configuration in radians (default straight).
        lag: window length in seconds.
        options: graph construction (:class:`~apcc_graph.estimation.options.GraphOptions`).
        progress: show a progress bar.
        **smoother_options: further :class:`ProjectionFixedLagSmoother` arguments.

    Returns:
        The estimate, ``method = "smoother"``.
    """
    options = GraphOptions() if options is None else options
    smoother = ProjectionFixedLagSmoother(sequence.robot, lag=lag, options=options, theta0=theta0,
                                **smoother_options)
    for f in tqdm(range(sequence.n_frames), desc="smoother", disable=not progress):
        smoother.update(sequence.frame(f))
    frames = smoother.finish()
    S = sequence.n_segments
    return Estimate(
        method="smoother", robot=sequence.robot, timestamps=sequence.timestamps.copy(),
        thetas=np.array([fr.thetas for fr in frames]),
        sigmas=np.array([fr.sigmas for fr in frames]),
        status=np.array([fr.status for fr in frames], dtype="<U24"),
        inliers=np.zeros((sequence.n_frames, S), dtype=np.int64),
        world_T_base=sequence.world_T_base)
