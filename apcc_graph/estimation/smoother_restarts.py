"""What the fixed-lag smoother does after a gap in what it saw: :class:`Restarts`.

A mixin of :class:`~apcc_graph.estimation.smoother.FixedLagSmoother` (it reads the smoother's
window, tracks and landmarks):

- :meth:`Restarts._watch_gaps` notices the two gaps after which the window's last estimate
  no longer says where the robot is: tracks that return after every camera was blind
  (:func:`~apcc_graph.estimation.blackout.tracks_returned`), and a pause in the recording longer
  than the lag, during which the robot may have moved anywhere, when no track seen before it
  comes back (with some, their points tie the new frame to the old ones). Either is said
  (:class:`~apcc_graph.estimation.blackout.BlackoutWarning`) and starts a
  :class:`~apcc_graph.estimation.blackout.Reacquisition` of the frames that follow;
- :meth:`Restarts._reacquire` solves those frames in one batch, from the unknown-start
  search's answer, once the first of them is about to leave the window, and restarts the
  window holding them (:meth:`Restarts._restart_holding`: the batch's values and priors, their
  observations replayed into the live tracks, so the window knows what the batch knew);
  after a gtsam failure the window restarts from one frame (:meth:`Restarts._restart`);
- :meth:`Restarts._watch_camera` notices one camera whose tracks come back all new while the
  others kept seeing, after the window lost that camera's segment (its marginal sigma above
  :data:`LOST`: the last camera's segment, seen by no other camera, drifts on the motion prior
  alone). That camera's rows stay out of the window (:meth:`Restarts._hold_out`) while the
  frames that follow are kept; one batch over them, started at the window's estimate and
  sigmas of their first frame (the other segments) and at the unknown-start search's answer
  for the lost one, re-acquires that segment, and the window restarts at the newest frame
  under its own marginal for the other segments and the batch's for the lost one
  (:meth:`Restarts._reacquire_segment`). A segment the window has not lost is left to it:
  after the middle camera's 1 s blackout on the reliability bench, a batch over the lag
  after its return knew that segment to 0.42 deg where the window knew it to 0.15.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import replace
from types import MappingProxyType

import gtsam
import numpy as np
from numpy.typing import NDArray

from apcc_graph.estimation.blackout import (
    MIN_SIGMA,
    Forward,
    Reacquired,
    Reacquisition,
    bridged,
    tracks_returned,
    warn_blackout,
    warn_pause,
    warn_segment_lost,
)
from apcc_graph.estimation.fixed_lag import WindowSolver
from apcc_graph.estimation.graph import prior_factors
from apcc_graph.estimation.landmarks import Landmarks
from apcc_graph.estimation.options import GraphOptions
from apcc_graph.estimation.projection_tracks import ProjectionTracks, Rows, frame_rows
from apcc_graph.estimation.rotation_gate import judge_frame
from apcc_graph.estimation.smoother_options import SmootherOptions
from apcc_graph.estimation.window import Window, component_sigmas, key_stamps
from apcc_graph.factors.keys import frame_key
from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.parameterisation import Bending
from apcc_graph.model.robot import Robot

PAUSE = 0.5
"""Seconds: a gap in the recording after which, when none of the tracks seen before comes back,
the robot may have moved anywhere (the motion prior over it is 20 degrees at the default
``motion_sigma``), so the frames after it are re-acquired, whatever the lag (with a 2 s lag a
1.5 s pause, handled as one long frame interval, put the robot 80 degrees off)."""
SECOND_ROUND: float | None = 2.0
"""Seconds: after the first re-acquisition of the frames after a pause (over one lag of them),
they are kept until they span this long and re-acquired once more, and the window restarts from
that batch (``None``: one round). After a pause of 1.5 s it took segment 1 from 4-6 degrees RMS
to 0.9 when the window restarted from one frame; restarted holding the batch's frames, from 1.03
to 0.75 (the bound of a 1 s lag there: 0.85). Not after a contradicted start (segment 1 0.82
to 1.02 degree on the reliability bench), nor yet after a blackout, whose bench row varies
from run to run as much as a second round changed it (docs/estimation.md, "What the smoother
says when the data go wrong")."""
LOOSE = math.pi / 6
"""Radians: the start prior of a re-acquisition when nothing says how far the robot went."""
LOST = math.radians(2.0)
"""Radians: a camera whose tracks come back all new has its segment re-acquired when the
window's marginal sigma of that segment (the frame before) exceeds this."""


class Restarts:
    """Blackouts, pauses and restarts of the fixed-lag smoother (module docstring)."""

    # What it reads of the smoother that mixes it in.
    robot: Robot
    options: GraphOptions
    bending: Bending
    inlier_sigmas: float
    settings: SmootherOptions
    _window: Window
    _tracks: ProjectionTracks
    _landmarks: Landmarks
    _last_seen: int | None
    _previous_rows: Rows
    _previous_base: FloatArray | None
    _reacquiring: Reacquisition | None
    _live_indices: list[int]
    _known: Callable[[int, NDArray[np.int64]], NDArray[np.bool_]]
    _sigmas: Callable[[int], FloatArray]
    _smoother: WindowSolver
    _read_window: Callable[[], None]
    _pause_at: int | None = None  # the first graph frame after the last pause
    _seen_by: Mapping[int, int] = MappingProxyType({})  # camera -> last graph frame it saw

    def _watch_gaps(self, f: int, t: float, rows: Rows, frame: int,
                    timestamp: float) -> None:
        """Before graph frame ``f`` (graph time ``t``) enters: start a re-acquisition if the
        tracks come back after a blackout, or if the recording paused longer than
        :data:`PAUSE` (or the lag)
        (``frame``, ``timestamp``: as received, for the warnings)."""
        window, seen_before = self._window, self._seen_by
        self._seen_by = {**seen_before, **{cam: f for cam, r in rows.items() if len(r[0])}}
        if self._last_seen is None or not rows:
            return
        blind: dict[int, Forward] = {}
        if window.inside(f - 1) and tracks_returned(rows, self._previous_rows, self._known):
            sigmas = component_sigmas(self.bending, self._sigmas(f - 1))
            warn_blackout(frame, timestamp, sigmas)
            start, sigma = window.thetas[f - 1].copy(), float(np.nanmax(sigmas, initial=LOOSE))
            then, blind = None, self._leave_blind(f - 1)
        elif (window.last_time is not None and t - window.last_time > min(window.lag, PAUSE)
              and window.latest(f - 1) is not None):
            gap, self._pause_at = t - window.last_time, f
            if any(np.any(self._known(cam, ids)) for cam, (ids, _, _) in rows.items()):
                return  # tracks seen before the pause tie the new frame to the old ones
            motion = self.options.motion_sigma
            sigma = LOOSE if motion is None else min(LOOSE, motion * math.sqrt(gap))
            warn_pause(frame, timestamp, gap, sigma)
            start, then = window.latest(f - 1), SECOND_ROUND
        else:
            self._watch_camera(f, rows, frame, timestamp, seen_before)
            return
        self._reacquiring = Reacquisition(self.robot, self.options, self.inlier_sigmas,
                                          self.bending, start, sigma, then=then, blind=blind)

    def _watch_camera(self, f: int, rows: Rows, frame: int, timestamp: float,
                      seen_before: Mapping[int, int]) -> None:
        """Before graph frame ``f`` enters: a camera whose tracks come back all new while
        others saw the frame before, its segment lost by the window, starts a re-acquisition
        of that segment (module docstring; ``seen_before``: camera -> the last graph frame it
        saw before ``f``)."""
        window, w = self._window, self.bending.width
        if self._reacquiring is not None or not self._previous_rows or not window.inside(f - 1):
            return
        for cam, (ids, _, _) in sorted(rows.items()):
            before, last = self._previous_rows.get(cam), seen_before.get(cam)
            if (before is not None and len(before[0])) or np.any(self._known(cam, ids)):
                continue
            if last is not None and window.inside(last):
                continue  # the window still holds a frame it saw: it follows the return
            cov = self._covariance(f - 1)
            sigmas = np.sqrt(np.maximum(np.diagonal(cov), 0.0))
            lost = float(np.max(sigmas[w * cam:w * (cam + 1)]))
            if lost <= LOST:  # also False for NaN: then it is lost too
                continue
            warn_segment_lost(frame, timestamp, cam, lost)
            self._reacquiring = Reacquisition(
                self.robot, self.options, self.inlier_sigmas, self.bending,
                window.thetas[f - 1].copy(), LOOSE, camera=cam,
                sigmas=np.where(np.isfinite(sigmas) & (sigmas > 0.0), sigmas, LOOSE),
                since=0 if last is None else last + 1)
            return

    def _hold_out(self, rows: Rows, t: float) -> Rows:
        """The new frame's rows without those of a camera whose segment is being re-acquired
        (until the re-acquisition is due at graph time ``t``)."""
        kept = self._reacquiring
        if kept is None or kept.camera is None or kept.due(t, self._window.lag):
            return rows
        return {cam: r for cam, r in rows.items() if cam != kept.camera}

    def _segment_start(self, kept: Reacquisition) -> Reacquisition:
        """A one-camera re-acquisition started at its first frame's estimate and marginal
        sigmas in the window (the other cameras saw that frame; the frame before the return
        may be a few degrees behind), the lost segment's sigma at least :data:`MIN_SIGMA`."""
        h = kept.slots[0]
        if not self._window.inside(h):
            return kept
        sigmas = np.sqrt(np.maximum(np.diagonal(self._covariance(h)), 0.0))
        sigmas = np.where(np.isfinite(sigmas) & (sigmas > 0.0), sigmas, LOOSE)
        block = kept.block()
        sigmas[block] = np.maximum(sigmas[block], MIN_SIGMA)
        return replace(kept, theta0=self._window.thetas[h].copy(), sigmas=sigmas)

    def _reacquire_segment(self, kept: Reacquisition, thetas: FloatArray, blocks: FloatArray
                           ) -> None:
        """A one-camera re-acquisition solved (``thetas``, flattened covariance ``blocks``):
        its frames take the batch's angles of that segment (status ``"reacquired"`` there),
        and the window restarts at the newest under a prior that keeps what it knew of the
        other segments (its marginal covariance of that frame) and takes the batch's answer
        for the lost one. Keeping the window instead, with the batch's answers as priors on
        the kept frames, left the segment 0.4-2 deg off with sigmas of 0.05 (probably the held
        camera's rows, linearised degrees away, going into the marginals of the frames that
        left); without those priors it drifted 18 deg (docs/estimation.md)."""
        window, block, c, g = self._window, kept.block(), kept.camera or 0, kept.slots[-1]
        w = block.stop - block.start
        cells = slice(w * w * c, w * w * (c + 1))
        sigmas = {h: self._sigmas(h) for h in window.stamps}
        for h, cov_h in zip(kept.slots, blocks, strict=True):
            if h in sigmas and np.all(np.isfinite(sigmas[h])):
                sigmas[h] = sigmas[h].copy()
                sigmas[h][cells] = cov_h[cells]
        cov = self._covariance(g)
        if not np.all(np.isfinite(cov)):
            cov = np.diag(np.full(len(cov), LOOSE**2))
        cov[block, :], cov[:, block] = 0.0, 0.0
        cov[block, block] = np.asarray(blocks[-1][cells], dtype=float).reshape(w, w)
        window.reacquired_segment(kept.slots, c, block, thetas, blocks)
        self._bridge_segment(kept, thetas[0], blocks[0])
        self._restart(g, window.stamps[g], window.thetas[g].copy(),
                      gtsam.noiseModel.Gaussian.Covariance(cov), None, sigmas)

    def _bridge_segment(self, kept: Reacquisition, after: FloatArray,
                        after_blocks: FloatArray) -> None:
        """The frames a camera did not see before its segment was re-acquired, if they left
        and were not taken yet: that segment's estimate :func:`bridged` between the frames
        before (their final estimates, the motion prior's prediction) and the first
        re-acquired frame (``after``, its flattened covariance blocks ``after_blocks``)."""
        motion, window, block = self.options.motion_sigma, self._window, kept.block()
        if motion is None or kept.since is None:
            return
        w = block.stop - block.start
        cells = slice(w * w * (kept.camera or 0), w * w * ((kept.camera or 0) + 1))
        for h in range(kept.since, kept.slots[0]):
            old = window.final.get(h)
            if old is None:
                continue
            x, cov = bridged(Forward(old.thetas, old.sigmas, old.timestamp), after,
                             after_blocks, kept.first_time, motion, w)
            thetas, sigmas = old.thetas.copy(), old.sigmas.copy()
            thetas[block], sigmas[cells] = x[block], cov[cells]
            window.revise(h, thetas, sigmas)

    def _leave_blind(self, g: int) -> dict[int, Forward]:
        """Tracks came back after a blackout that ended with graph frame ``g``: the window
        restarts at ``g`` under its marginal from the frames before, so the new tracks, from a
        start that far off, cannot drag the blind frames (they leave with the motion prior's
        prediction and its sigmas); returns those frames' estimates for :func:`bridged`."""
        window, seen = self._window, self._last_seen
        covariances = {h: self._covariance(h) for h in sorted(window.stamps)}
        blind = {h: Forward(window.thetas[h].copy(), self.bending.blocks(cov).ravel(),
                            window.times[h])
                 for h, cov in covariances.items() if seen is None or h > seen}
        loose = np.diag(np.full(len(window.thetas[g]), LOOSE**2))
        cov = covariances[g]
        prior = gtsam.noiseModel.Gaussian.Covariance(cov if np.all(np.isfinite(cov)) else loose)
        self._restart(g, window.stamps[g], window.thetas[g].copy(), prior, None,
                      {h: self._sigmas(h) for h in covariances})
        return blind

    def _covariance(self, h: int) -> FloatArray:
        """Frame ``h``'s marginal covariance (its frame vector's), whether or not the smoother
        reports sigmas; NaN if gtsam cannot give it."""
        try:
            return np.asarray(self._smoother.marginalCovariance(frame_key(h)), dtype=float)
        except (RuntimeError, IndexError, ValueError):
            n = len(self._window.thetas[h])
            return np.full((n, n), np.nan)

    def _older(self, f: int) -> FloatArray | None:
        """Frame ``f - 2``'s estimate for the constant-velocity prediction of frame ``f``;
        ``None`` (no velocity) across a pause."""
        if self._pause_at is not None and f - 2 < self._pause_at:
            return None
        return self._window.latest(f - 2)

    def _reacquire(self, kept: Reacquisition) -> None:
        """One batch over the frames kept since a blackout or a pause (or since the start,
        replaced); they take its angles and sigmas, and the window restarts holding them
        (:meth:`_restart_holding`; :mod:`apcc_graph.estimation.blackout`)."""
        self._reacquiring, window, g = None, self._window, kept.slots[-1]
        if not window.inside(g):
            return
        if kept.camera is not None:
            kept = self._segment_start(kept)
        try:
            found = kept.solve()
        except (RuntimeError, ValueError, IndexError):
            return  # the window goes on as it was
        if kept.camera is not None:
            self._reacquire_segment(kept, found.x, found.blocks)
            return
        window.reacquired(kept.slots, found.x, found.blocks, self.robot.n_segments)
        motion = self.options.motion_sigma
        for h, forward in kept.blind.items() if motion is not None else ():
            window.revise(h, *bridged(forward, found.x[0], found.blocks[0], kept.first_time,
                                      motion, self.bending.width))
        self._restart_holding(kept, found)
        if kept.then is not None and kept.then > window.lag:
            self._reacquiring = kept.longer(kept.then)

    def _restart_holding(self, kept: Reacquisition, found: Reacquired) -> None:
        """A new window holding the re-acquired frames still in the window, at the batch's
        values, under the batch's own priors (its start prior on the first kept frame, or,
        when that frame has left, the batch's marginal there; the motion priors between
        them), their observations replayed into the live tracks (:meth:`_replay`): the
        window goes on from what the batch knew, and the tracks that continue keep their
        points. The other frames leave."""
        window = self._window
        for k, h in enumerate(kept.slots):  # frames a gtsam failure pushed out come back
            if not window.inside(h) and kept.times[k] >= kept.times[-1] - window.lag:
                window.reenter(h, found.x[k])
        inside = [(k, h) for k, h in enumerate(kept.slots) if window.inside(h)]
        k0, h0 = inside[0]
        if k0 == 0:
            mean, sigma = found.start, found.start_sigmas
        else:  # also summarises the rows replayed below: slightly overconfident
            mean, sigma = found.x[k0], found.sigmas[k0]
        sigma = np.where(np.isfinite(sigma), np.maximum(sigma, 1e-6), LOOSE)
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        graph.add(gtsam.PriorFactorVector(frame_key(h0), mean,
                                          gtsam.noiseModel.Diagonal.Sigmas(sigma)))
        for factor in prior_factors([h for _, h in inside], window.times, None, self.bending,
                                    self.options, limits=False):
            graph.add(factor)
        for k, h in inside:
            values.insert(frame_key(h), found.x[k])
        by_slot = dict(zip(kept.slots, found.blocks, strict=True))
        sigmas = {h: by_slot.get(h, self._sigmas(h)) for h in window.stamps}
        keep = {h for _, h in inside}
        for h in [h for h in window.stamps if h not in keep]:
            window.leave(h, window.thetas.get(h, found.x[0]).copy(), sigmas[h])
        window.renew()
        self._replay(kept, inside)
        self._settle(graph, values, key_stamps([(frame_key(h), window.stamps[h])
                                                for _, h in inside]))

    def _replay(self, kept: Reacquisition, inside: list[tuple[int, int]]) -> None:
        """The kept frames ``inside`` (kept index, graph frame) become the live tracks' only
        frames, judged by the rotation gate (each piece's outlier decisions come from its
        robust triangulation at the batch's values when its factor is first built); the
        landmarks are forgotten."""
        tracks = self._tracks
        tracks.reset()
        tracks.bases = {h: kept.base(k) for k, h in inside}
        self._landmarks.reset()
        self._live_indices = []
        before: Rows = {}
        for k, h in inside:
            rows = frame_rows(self.robot, h, kept.frame(k), self.options.threshold_px)
            verdicts = judge_frame(h, rows, before, tracks.live, self.settings.rotation_gate)
            for cam, (ids, xy, whiten) in rows.items():
                tracks.live.add(h, cam, ids, xy, whiten, None, verdicts[cam])
            before = rows
        self._previous_rows, self._previous_base = before, kept.base(inside[-1][0])

    def _settle(self, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values,
                stamps: Mapping[int, float]) -> None:
        """The restarted window's first update: ``graph``, its new ``values`` and their
        ``stamps``, with the live tracks' factors. (With the priors alone, one Gauss-Newton
        step pulled every frame onto the start prior, 17 to 49 degrees from the batch's
        answer on a pause, and the first frames left the window before they came back.)"""
        live = self._tracks.live_factors(graph)
        self._smoother.update(graph, values, stamps, self._live_indices)
        indices = self._smoother.getISAM2Result().getNewFactorsIndices()
        self._live_indices = [int(indices[pos]) for pos, *_ in live]
        self._tracks.keep_points(live)
        self._read_window()

    def _restart(self, f: int, t: float, thetas: FloatArray,
                 prior: gtsam.noiseModel.Base | None = None, status: str | None = "recovered",
                 sigmas: Mapping[int, FloatArray] | None = None) -> None:
        """A new smoother holding only frame f, at ``thetas``, with ``prior`` (default: a sigma
        of ``options.theta0_sigma``, at least 1 deg); the other frames leave with their last
        estimates (and ``sigmas``). After a gtsam failure, after a re-acquisition, and when the
        tracks come back after a blackout."""
        self._window.renew()
        graph = gtsam.NonlinearFactorGraph()
        sigma = max(self.options.theta0_sigma, math.radians(1.0))
        prior = prior or gtsam.noiseModel.Isotropic.Sigma(len(thetas), sigma)
        graph.add(gtsam.PriorFactorVector(frame_key(f), thetas, prior))
        values = gtsam.Values()
        values.insert(frame_key(f), thetas)
        self._smoother.update(graph, values, key_stamps([(frame_key(f), t)]))
        self._window.leave_all_but(f, thetas, sigmas)
        self._tracks.bases = {f: self._tracks.bases.get(f)}
        if status is not None:
            self._window.status[f] = np.full(self.robot.n_segments, status, dtype="<U24")
        self._tracks.reset(keep=f)
        self._live_indices = []
        self._landmarks.reset()
