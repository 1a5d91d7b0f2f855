"""What the smoother does after a gap in what it saw, and after gtsam fails: :class:`Recovery`.

It owns the state of the faults (the re-acquisition under way, the frames each camera saw, the
last pause) and carries out the plans of the pure detectors of
:mod:`~apcc_graph.estimation.smoother.gaps`, through the window
(:class:`~apcc_graph.estimation.window.Window`), the solver that owns iSAM2
(:class:`~apcc_graph.estimation.smoother.solver.Solver`) and the measurement model:

- after a blackout, the window restarts at the last blind frame under its marginal from the
  frames before (:meth:`Recovery._leave_blind`), and a re-acquisition of the frames that
  follow starts; after a pause with no track back, and after a contradicted start, a
  re-acquisition starts;
- :meth:`Recovery.reacquire` solves the kept frames in one batch (the model's own: the exact
  model's or model noise's), from the unknown-start search's answer, once the first of them
  is about to leave the window, and restarts the window holding them
  (:meth:`Recovery._restart_holding`: the batch's values and priors, their observations
  replayed into the model's tracks, so the window knows what the batch knew);
- after a lost camera's return, only its segment is re-acquired, and the window restarts at
  the newest frame under its own marginal for the other segments and the batch's for the lost
  one (:meth:`Recovery._reacquire_segment`). A segment the window has not lost is left to it:
  after the middle camera's 1 s blackout on the reliability bench, a batch over the lag after
  its return knew that segment to 0.42 deg where the window knew it to 0.15;
- after a gtsam failure the window restarts from one frame (:meth:`Recovery.restart`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import replace

import gtsam
import numpy as np

from apcc_graph.estimation.blackout import (
    MIN_SIGMA,
    Forward,
    Reacquired,
    Reacquisition,
    bridged,
    warn_blackout,
    warn_pause,
    warn_segment_lost,
)
from apcc_graph.estimation.graph import prior_factors
from apcc_graph.estimation.options import GraphOptions
from apcc_graph.estimation.projection_tracks import Rows, frame_rows
from apcc_graph.estimation.rotation_gate import judge_frame
from apcc_graph.estimation.smoother import gaps
from apcc_graph.estimation.smoother.gaps import LOOSE, Gap
from apcc_graph.estimation.smoother.measurement import WindowModel, read_estimate
from apcc_graph.estimation.smoother.solver import Additions, Solver
from apcc_graph.estimation.window import Window, component_sigmas
from apcc_graph.factors.keys import frame_key
from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.parameterisation import Bending
from apcc_graph.model.robot import Robot
from apcc_graph.model.sequence import FrameObservations

Previous = tuple[Rows, FloatArray | None]
"""The last frame's rows and base pose, as the next frame's gate and front end see them."""


class Recovery:
    """The smoother's faults and restarts (module docstring).

    Args:
        robot, options, bending, inlier_sigmas: the smoother's.
        gate: the rotation gate's threshold (radians of bearing) or ``None``.
        uncertainty: frames leave with their marginal covariances (else NaN).
        window, solver, model: the smoother's window, iSAM2 owner and measurement model.

    Attributes:
        reacquiring: the re-acquisition under way, if any.
        pause_at: the first graph frame after the last pause.
        last_seen: the last graph frame with tracks, and ``last_seen_time`` its graph time.
    """

    def __init__(self, robot: Robot, options: GraphOptions, bending: Bending,
                 inlier_sigmas: float, gate: float | None, uncertainty: bool, window: Window,
                 solver: Solver, model: WindowModel) -> None:
        self.robot, self.options, self.bending = robot, options, bending
        self.inlier_sigmas, self.gate, self.uncertainty = inlier_sigmas, gate, uncertainty
        self.window, self.solver, self.model = window, solver, model
        self.reacquiring: Reacquisition | None = None
        self.pause_at: int | None = None
        self.last_seen: int | None = None
        self.last_seen_time = 0.0
        self._seen_by: dict[int, int] = {}  # camera -> last graph frame it saw
        self._seen_at: dict[int, float] = {}  # camera -> the graph time it last saw

    def covariance(self, h: int) -> FloatArray:
        """Frame ``h``'s marginal covariance (NaN if gtsam cannot give it)."""
        return self.solver.covariance(frame_key(h), self.bending.dim)

    def blocks(self, h: int) -> FloatArray:
        """Frame ``h``'s flattened covariance blocks (NaN if gtsam cannot give them)."""
        return self.bending.blocks(self.covariance(h)).ravel()

    def sigmas(self, h: int) -> FloatArray:
        """Frame ``h``'s flattened covariance blocks as the smoother reports them (NaN
        without ``uncertainty``)."""
        if not self.uncertainty:
            return np.full(self.window.n_segments, np.nan)
        return self.blocks(h)

    # ----------------------------------------------------------------------- detection
    def watch(self, f: int, t: float, rows: Rows, previous: Rows, frame: int,
              timestamp: float) -> None:
        """Before graph frame ``f`` (graph time ``t``) enters: ask the detectors, say what
        they found and start what they plan (``frame``, ``timestamp``: as received, for the
        warnings)."""
        window, seen_before = self.window, self._seen_by
        self._seen_by = {**seen_before, **{cam: f for cam, r in rows.items() if len(r[0])}}
        if self.last_seen is None or not rows:
            return
        known = self.model.known
        plan = (gaps.blackout(f, rows, previous, window.inside(f - 1), known,
                              window.thetas[f - 1],
                              lambda: component_sigmas(self.bending, self.blocks(f - 1)),
                              t - self.last_seen_time)
                if window.inside(f - 1) else None)
        if plan is None:
            paused, plan = gaps.pause(t, window.last_time, window.lag, rows, known,
                                      window.latest(f - 1), self.options.motion_sigma)
            if paused:
                self.pause_at = f
            elif self.reacquiring is None and window.inside(f - 1):
                plan = gaps.lost_camera(rows, previous, known, seen_before, window.inside,
                                        lambda: self.covariance(f - 1), window.thetas[f - 1],
                                        self.bending.width)
        if plan is not None:
            self._start(plan, frame, timestamp)

    def _start(self, plan: Gap, frame: int, timestamp: float) -> None:
        """Say what a detector found and start its re-acquisition."""
        blind: dict[int, Forward] = {}
        if plan.kind == "blackout":
            warn_blackout(frame, timestamp, component_sigmas(
                self.bending, self.blocks(plan.restart_at or 0)))
            blind = self._leave_blind(plan.restart_at or 0)
        elif plan.kind == "pause":
            warn_pause(frame, timestamp, plan.gap, plan.sigma)
        else:
            warn_segment_lost(frame, timestamp, plan.camera or 0, plan.gap)
        self.reacquiring = Reacquisition(
            self.robot, self.options, self.inlier_sigmas, self.bending, plan.start, plan.sigma,
            then=plan.then, blind=blind, camera=plan.camera, sigmas=plan.sigmas,
            since=plan.since)

    def saw(self, f: int, t: float, rows: Rows) -> None:
        """Graph frame ``f`` (at ``t``) enters with ``rows``."""
        if rows:
            self.last_seen, self.last_seen_time = f, t
        self._seen_at.update({cam: t for cam, r in rows.items() if len(r[0])})

    def lag(self, t: float, lag: float) -> float:
        """The window's length at graph time ``t`` for the settings' ``lag``: :data:`~apcc_graph.
        estimation.smoother.gaps.LONGER` lags while a segment is seen only through the cameras
        further out (:func:`~apcc_graph.estimation.smoother.gaps.weakly_seen`)."""
        weak = gaps.weakly_seen(self._seen_at, self.robot.camera_segments, t, lag)
        return lag * gaps.LONGER if weak else lag

    def hold_out(self, rows: Rows, t: float) -> Rows:
        """The new frame's rows without those of a camera whose segment is being re-acquired
        (until the re-acquisition is due at graph time ``t``)."""
        kept = self.reacquiring
        if kept is None or kept.camera is None or kept.due(t, self.window.lag):
            return rows
        return {cam: r for cam, r in rows.items() if cam != kept.camera}

    def keep(self, f: int, t: float, observations: FrameObservations) -> Previous | None:
        """Before graph frame ``f`` (at ``t``) enters: the re-acquisition that is due is
        carried out (returning the window's new previous frame, if it restarted), and the
        frame is kept for the next."""
        previous = None
        if self.reacquiring is not None and self.reacquiring.due(t, self.window.lag):
            previous = self.reacquire(self.reacquiring)  # may leave a second round pending
        if self.reacquiring is not None and not self.reacquiring.due(t, self.window.lag):
            self.reacquiring.add(f, t, observations)  # every frame, the second round's too
        return previous

    def settle(self) -> Previous | None:
        """The recording ends (or pauses for a :meth:`~apcc_graph.estimation.smoother.core.
        FixedLagSmoother.finish`): the re-acquisition under way, if it holds two frames or
        more, is carried out now over the frames it kept rather than never (returning the
        window's new previous frame, if it restarted); a further round it plans stays pending
        for the frames that may still come."""
        kept = self.reacquiring
        if kept is None or len(kept.slots) < 2:
            return None
        return self.reacquire(kept)

    # ---------------------------------------------------------------------- restarts
    def restart(self, f: int, t: float, thetas: FloatArray,
                prior: gtsam.noiseModel.Base | None = None, status: str | None = "recovered",
                sigmas: Mapping[int, FloatArray] | None = None) -> None:
        """A new window holding only frame f, at ``thetas``, with ``prior`` (default: a sigma
        of ``options.theta0_sigma``, at least 1 deg); the other frames leave with their last
        estimates (and ``sigmas``). After a gtsam failure, after a re-acquisition, and when the
        tracks come back after a blackout."""
        add = Additions()
        sigma = max(self.options.theta0_sigma, math.radians(1.0))
        prior = prior or gtsam.noiseModel.Isotropic.Sigma(len(thetas), sigma)
        add.graph.add(gtsam.PriorFactorVector(frame_key(f), thetas, prior))
        add.variable(frame_key(f), thetas, t)
        base = self.model.base(f)
        self.model.reset(keep=f, base=base)
        self.model.restart_frame(add, f, t, thetas, base)
        self.solver.restart(add)
        self.window.leave_all_but(f, thetas, sigmas)
        if status is not None:
            self.window.status[f] = np.full(self.robot.n_segments, status, dtype="<U24")

    def _leave_blind(self, g: int) -> dict[int, Forward]:
        """Tracks came back after a blackout that ended with graph frame ``g``: the window
        restarts at ``g`` under its marginal from the frames before, so the new tracks, from a
        start that far off, cannot drag the blind frames (they leave with the motion prior's
        prediction and its sigmas); returns those frames' estimates for :func:`bridged`."""
        window, seen = self.window, self.last_seen
        covariances = {h: self.covariance(h) for h in sorted(window.stamps)}
        blind = {h: Forward(window.thetas[h].copy(), self.bending.blocks(cov).ravel(),
                            window.times[h])
                 for h, cov in covariances.items() if seen is None or h > seen}
        loose = np.diag(np.full(len(window.thetas[g]), LOOSE**2))
        cov = covariances[g]
        prior = gtsam.noiseModel.Gaussian.Covariance(cov if np.all(np.isfinite(cov)) else loose)
        self.restart(g, window.stamps[g], window.thetas[g].copy(), prior, None,
                     {h: self.sigmas(h) for h in covariances})
        return blind

    def reacquire(self, kept: Reacquisition) -> Previous | None:
        """One batch over the frames kept since a blackout or a pause (or since the start,
        replaced); they take its angles and sigmas, and the window restarts holding them
        (:meth:`_restart_holding`); returns the new previous frame (``None``: the window
        goes on as it was)."""
        self.reacquiring, window, g = None, self.window, kept.slots[-1]
        if not window.inside(g):
            return None
        if kept.camera is not None:
            kept = self._segment_start(kept)
        try:
            found = kept.solve()
        except (RuntimeError, ValueError, IndexError):
            return None  # the window goes on as it was
        if kept.camera is not None:
            self._reacquire_segment(kept, found.x, found.blocks)
            return None
        window.reacquired(kept.slots, found.x, found.blocks, self.robot.n_segments)
        motion = self.options.motion_sigma
        for h, forward in kept.blind.items() if motion is not None else ():
            window.revise(h, *bridged(forward, found.x[0], found.blocks[0], kept.first_time,
                                      motion, self.bending.width))
        previous = self._restart_holding(kept, found)
        span = gaps.next_round(kept.span, kept.then, float(np.max(found.sigmas[-1])),
                               window.lag)
        if span is not None:
            self.reacquiring = kept.longer(span)
        return previous

    def _segment_start(self, kept: Reacquisition) -> Reacquisition:
        """A one-camera re-acquisition started at its first frame's estimate and marginal
        sigmas in the window (the other cameras saw that frame; the frame before the return
        may be a few degrees behind), the lost segment's sigma at least :data:`MIN_SIGMA`."""
        h = kept.slots[0]
        if not self.window.inside(h):
            return kept
        sigmas = np.sqrt(np.maximum(np.diagonal(self.covariance(h)), 0.0))
        sigmas = np.where(np.isfinite(sigmas) & (sigmas > 0.0), sigmas, LOOSE)
        block = kept.block()
        sigmas[block] = np.maximum(sigmas[block], MIN_SIGMA)
        return replace(kept, theta0=self.window.thetas[h].copy(), sigmas=sigmas)

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
        window, block, c, g = self.window, kept.block(), kept.camera or 0, kept.slots[-1]
        w = block.stop - block.start
        cells = slice(w * w * c, w * w * (c + 1))
        sigmas = {h: self.sigmas(h) for h in window.stamps}
        for h, cov_h in zip(kept.slots, blocks, strict=True):
            if h in sigmas and np.all(np.isfinite(sigmas[h])):
                sigmas[h] = sigmas[h].copy()
                sigmas[h][cells] = cov_h[cells]
        cov = self.covariance(g)
        if not np.all(np.isfinite(cov)):
            cov = np.diag(np.full(len(cov), LOOSE**2))
        cov[block, :], cov[:, block] = 0.0, 0.0
        cov[block, block] = np.asarray(blocks[-1][cells], dtype=float).reshape(w, w)
        window.reacquired_segment(kept.slots, c, block, thetas, blocks)
        self._bridge_segment(kept, thetas[0], blocks[0])
        self.restart(g, window.stamps[g], window.thetas[g].copy(),
                     gtsam.noiseModel.Gaussian.Covariance(cov), None, sigmas)

    def _bridge_segment(self, kept: Reacquisition, after: FloatArray,
                        after_blocks: FloatArray) -> None:
        """The frames a camera did not see before its segment was re-acquired, if they left
        and were not taken yet: that segment's estimate :func:`bridged` between the frames
        before (their final estimates, the motion prior's prediction) and the first
        re-acquired frame (``after``, its flattened covariance blocks ``after_blocks``)."""
        motion, window, block = self.options.motion_sigma, self.window, kept.block()
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

    def _restart_holding(self, kept: Reacquisition, found: Reacquired) -> Previous:
        """A new window holding the re-acquired frames still in the window, at the batch's
        values, under the batch's own priors (its start prior on the first kept frame, or,
        when that frame has left, the batch's marginal there; the motion priors between
        them), their observations replayed into the model's tracks, judged by the rotation
        gate (the landmarks are forgotten): the window goes on from what the batch knew, and
        the tracks that continue keep their points. The other frames leave. (With the priors
        alone, one Gauss-Newton step pulled every frame onto the start prior, 17 to 49 degrees
        from the batch's answer on a pause, and the first frames left the window before they
        came back.)"""
        window = self.window
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
        add = Additions()
        add.graph.add(gtsam.PriorFactorVector(frame_key(h0), mean,
                                              gtsam.noiseModel.Diagonal.Sigmas(sigma)))
        for factor in prior_factors([h for _, h in inside], window.times, None, self.bending,
                                    self.options, limits=False):
            add.graph.add(factor)
        by_slot = dict(zip(kept.slots, found.blocks, strict=True))
        sigmas = {h: by_slot.get(h, self.sigmas(h)) for h in window.stamps}
        keep = {h for _, h in inside}
        for h in [h for h in window.stamps if h not in keep]:
            window.leave(h, window.thetas.get(h, found.x[0]).copy(), sigmas[h])
        self.model.reset()
        before: Rows = {}
        for k, h in inside:
            add.variable(frame_key(h), found.x[k], window.stamps[h])
            self.model.restart_frame(add, h, window.stamps[h], found.x[k], kept.base(k))
            rows = frame_rows(self.robot, h, kept.frame(k), self.options.threshold_px)
            verdicts, agreed = judge_frame(h, rows, before, self.gate)
            self.model.judge(h - 1, agreed)
            self.model.replay(add, h, window.stamps[h], rows, verdicts, kept.base(k))
            before = rows
        if self.solver.restart(add, self.model.replaceable(add.graph)):
            read_estimate(self.window, self.model, self.solver.estimate())
        return before, kept.base(inside[-1][0])
