"""The smoother's track factors: live pieces, committed pieces, outlier decisions.

Every observation enters the smoother's graph exactly once. While its track piece is live
(:mod:`apcc_graph.estimation.live_tracks`) it sits in one "live" projection factor per camera,
replaced at every update (:meth:`ProjectionTracks.live_factors`); when the piece is committed
(its track ended, its first frame is about to leave the window, or it is ``max_track_frames``
long) all its observations enter one projection factor for good (:meth:`ProjectionTracks.commit`).

Outlier decisions: a piece seen for the first time in the live factor, and a piece being
committed, have their point triangulated robustly at the current estimates and each observation
is judged against it (truncated quadratic, ``Robustness.inlier_sigmas``); the observations of
a new frame were judged by its initial guess. With ``SmootherOptions.faults.rotation_gate`` the
model-free gate's weights (:mod:`apcc_graph.estimation.rotation_gate`) multiply those decisions,
and a new piece waits for :data:`DECIDE_OPEN` rows the gate leaves open. A piece with fewer
than two weighted rows is left out of its factor (:func:`~apcc_graph.estimation.robust.
enough_rows`). Each live piece's point, from the last
linearisation, starts the next frame's initial guess (:meth:`ProjectionTracks.known_rows`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Protocol

import gtsam
import numpy as np
from numpy.typing import NDArray

from apcc_graph.estimation.graph import camera_chain, values_from
from apcc_graph.estimation.initial_guess import FrameRows
from apcc_graph.estimation.landmarks import Landmarks
from apcc_graph.estimation.live_tracks import LiveTracks
from apcc_graph.estimation.options import GraphOptions
from apcc_graph.estimation.robust import enough_rows, gnc_tls_weights
from apcc_graph.estimation.smoother_options import SmootherOptions
from apcc_graph.estimation.window import Window, observed_camera
from apcc_graph.factors.camera_chain import CameraChain
from apcc_graph.factors.projection import ProjectionFactor
from apcc_graph.factors.reduced_system import robust_residual_norms
from apcc_graph.factors.track_points import TrackObservations
from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.parameterisation import Bending
from apcc_graph.model.robot import Robot
from apcc_graph.model.sequence import FrameObservations

DECIDE_OPEN = 3
"""Rows the model-free gate must leave open before a live piece's point is triangulated and its
rows judged against it (two rays fit any point; a wrong point then judges every later row)."""

Rows = Mapping[int, tuple[NDArray[np.int64], FloatArray, FloatArray]]
"""camera -> (track ids, normalised points, whitening) of a new frame."""


class TrackFactor(Protocol):
    """What the smoother needs of a projection factor (over frame vectors, or over tips)."""

    obs: TrackObservations
    points: FloatArray | None

    def factor(self) -> gtsam.CustomFactor:
        """The gtsam factor."""


LiveFactor = tuple[int, int, TrackFactor]
"""A live factor: its position in the update's graph, its camera, the factor."""


class ProjectionTracks:
    """The track pieces of the smoother and their factors.

    Args:
        robot: the robot.
        options: graph construction (noise, outlier threshold, track lengths).
        settings: the smoother's options (``min_live_rows``, ``relinearize``,
            ``point_iterations``).
        window: the smoother's window (the estimates the pieces are judged at).
        bending: the parameterisation of the frames' vectors.
        inlier_sigmas: the outlier threshold (whitened residual norm, pixel-noise units).

    Attributes:
        live: the live pieces.
        bases: frame -> base pose (``None``: identity), for frames inside the window.
        committed: observations committed so far (each exactly once).
        outliers: committed observations judged outliers so far.
    """

    def __init__(self, robot: Robot, options: GraphOptions,
                 settings: SmootherOptions, window: Window, bending: Bending,
                 inlier_sigmas: float) -> None:
        self.robot = robot
        self.inlier_sigmas = inlier_sigmas
        self.dim = bending.dim  # a frame's vector
        self.options = options
        self.settings = settings
        self.window = window
        self.live = self._new_live()
        self.bases: dict[int, FloatArray | None] = {}
        self.committed = 0
        self.outliers = 0
        self._chains = {c: camera_chain(robot, c, bending)
                        for c in robot.camera_segments}

    def _new_live(self) -> LiveTracks:
        max_frames = self.options.max_track_frames or 10**9
        return LiveTracks(self.robot.camera_segments, max_frames, self.options.min_track_rows,
                          stagger=self.settings.tracks.stagger_cuts)

    def reset(self, keep: int | None = None) -> None:
        """Forget every live piece (after the smoother restarted); the observations of frame
        ``keep`` (the frame the new window holds) start new pieces."""
        old, self.live = self.live, self._new_live()
        if keep is not None:
            for cam, (ids, xy, whiten, weights, verdicts) in old.frame_rows(keep).items():
                self.live.add(keep, cam, ids, xy, whiten, weights, verdicts)

    def chain(self, cam: int, first: int, last: int) -> CameraChain:
        """Camera ``cam``'s chain with the base poses of frames ``first..last``."""
        chain = self._chains[cam]
        bases = [self.bases.get(g) for g in range(first, last + 1)]
        if all(b is None for b in bases):
            return chain
        stack = np.stack([np.eye(4) if b is None else b for b in bases])
        return CameraChain(chain.bending, chain.tip_T_cam, stack, first)

    def span(self, first: int, last: int) -> FloatArray:
        """``(last - first + 1, P)`` the current estimates of frames ``first..last`` (``P``:
        :attr:`dim`)."""
        return np.array([self.window.thetas[g] for g in range(first, last + 1)])

    def count(self, observations: int, outliers: int) -> None:
        """Count observations committed elsewhere (as landmark observations)."""
        self.committed += observations
        self.outliers += outliers

    def commit(self, graph: gtsam.NonlinearFactorGraph, cam: int,
               obs: TrackObservations) -> None:
        """One projection factor for camera ``cam``'s committed pieces, with the outlier
        decisions taken against each piece's robust point at the current estimates, times
        the model-free gate's (call before the live tracks drop the pieces' frames)."""
        gate = self.live.gates(obs)
        gate *= enough_rows(gate, obs.tracks, obs.starts, 2)
        norms, points = self.robust_norms(cam, obs, gate)
        weights = gnc_tls_weights(norms, self.inlier_sigmas, math.inf) * gate
        # A piece left with one row says nothing about the angles, but its point, fixed off
        # that row's ray between linearisations, makes a large spurious cost.
        weights *= enough_rows(weights, obs.tracks, obs.starts, 2)
        self.count(len(obs), int(np.sum(weights == 0.0)))
        if not weights.any():
            return
        relinearize = self.settings.window.relinearize
        factor = self.new_factor(cam, obs, weights, points,
                                 self.settings.tracks.point_iterations if relinearize else None)
        if relinearize:
            graph.add(factor.factor())
            return
        # Linearised once, here, at estimates the window has refined for as long as the piece
        # was live: a C++ factor iSAM2 never calls back into Python for.
        values = self.linear_values(cam, int(obs.frames.min()), int(obs.frames.max()))
        graph.add(gtsam.LinearContainerFactor(factor.factor().linearize(values), values))

    def robust_norms(self, cam: int, obs: TrackObservations, gate: FloatArray
                     ) -> tuple[FloatArray, FloatArray]:
        """Every row's whitened residual norm against its piece's point, found robustly from
        the rows ``gate`` keeps at the current estimates, and the points ``(T, 3)``."""
        first, last = int(obs.frames.min()), int(obs.frames.max())
        return robust_residual_norms(obs, self.chain(cam, first, last), self.span(first, last),
                                     first, gate)

    def new_factor(self, cam: int, obs: TrackObservations, weights: FloatArray,
                   points: FloatArray, point_iterations: int | None) -> TrackFactor:
        """Camera ``cam``'s projection factor over ``obs`` starting from ``points``
        (``point_iterations``: triangulation steps per linearisation; ``None``: the
        factor's own)."""
        first, last = int(obs.frames.min()), int(obs.frames.max())
        factor = ProjectionFactor(obs, self.chain(cam, first, last), self.dim, weights)
        factor.points = points
        if point_iterations is not None:
            factor.point_iterations = point_iterations
        return factor

    def linear_values(self, cam: int, first: int, last: int) -> gtsam.Values:
        """The current estimates of the variables camera ``cam``'s factors over frames
        ``first..last`` depend on (where a committed factor is linearised once)."""
        return values_from(self.span(first, last), range(first, last + 1))

    def known_rows(self, rows: Rows, marks: Mapping[int, NDArray[np.int64]],
                   landmarks: Landmarks | None,
                   gates: Mapping[int, FloatArray] | None = None
                   ) -> tuple[list[FrameRows], list[tuple[int, NDArray[np.bool_]]]]:
        """The new frame's observations of landmarks and of live tracks whose points are known
        from at least ``settings.tracks.min_live_rows`` observations (a vouched piece's point from
        two close frames is too loose to check a new observation against), and per entry the camera
        and the mask of those rows; rows with a gate weight of 0 in ``gates`` (camera -> per
        row) are left out; ``landmarks``: ``None`` where there are none)."""
        out, masks = [], []
        for cam, (ids, xy, whiten) in rows.items():
            open_ = np.ones(len(ids), dtype=bool) if gates is None else gates[cam] > 0.0
            found = (None if landmarks is None else
                     landmarks.known_rows(cam, np.where(open_, marks[cam], -1), xy, whiten))
            if found is not None:
                out.append(found[0])
                masks.append((cam, found[1]))
            pieces = self.live.piece_ids(cam, ids)
            points = self.live.points(cam)
            known = np.array([p in points for p in pieces.tolist()], dtype=bool)
            known &= (self.live.lengths(cam, pieces) >= self.settings.tracks.min_live_rows) & open_
            if known.any():
                pts = np.array([points[p] for p in pieces[known].tolist()])
                out.append(FrameRows(cam, pts, xy[known], whiten[known]))
                masks.append((cam, known))
        return out, masks

    def live_factors(self, graph: gtsam.NonlinearFactorGraph) -> list[LiveFactor]:
        """One projection factor per camera over its live (uncommitted) pieces, added to
        ``graph``; it replaces the previous update's, so every observation is in exactly one
        factor at a time. A piece seen for the first time here gets its outlier decisions from
        a robust triangulation. Returns (position in graph, camera, factor)."""
        out = []
        for cam in self.robot.camera_segments:
            found = self.live.live_rows(cam, self.settings.tracks.min_live_rows)
            if found is None:
                continue
            obs, weights, index = found
            points = self.live.points(cam)
            new = np.array([int(p) not in points for p in obs.ids], dtype=bool)
            if new.any():
                self._decide(cam, obs, weights, index, new)
                known = np.array([int(p) in points for p in obs.ids], dtype=bool)
                if not known.all():  # pieces the gate left too few rows to decide yet
                    weights = weights[known[obs.tracks]]
                    obs = obs.select(np.flatnonzero(known))
                    if len(obs) == 0:
                        continue
            weights = weights * enough_rows(weights, obs.tracks, obs.starts, 2)
            if not weights.any():
                continue
            factor = self.new_factor(cam, obs, weights,
                                     np.array([points[int(p)] for p in obs.ids]),
                                     self.settings.tracks.point_iterations)
            out.append((graph.size(), cam, factor))
            graph.add(factor.factor())
        return out

    def _decide(self, cam: int, obs: TrackObservations, weights: FloatArray,
                index: NDArray[np.int64], new: NDArray[np.bool_]) -> None:
        """Outlier decisions and points of the pieces ``new`` (a mask over ``obs``' pieces)
        from a robust triangulation at the current estimates. A piece with fewer than
        :data:`DECIDE_OPEN` rows the model-free gate leaves open is not decided yet: its rows
        stay out of this update, and it is decided again at the next."""
        points = self.live.points(cam)
        part = obs.select(np.flatnonzero(new))
        rows = np.concatenate([np.arange(obs.starts[t], obs.starts[t + 1])
                               for t in np.flatnonzero(new)])
        gate = self.live.gates(part)
        ready = enough_rows(gate, part.tracks, part.starts, DECIDE_OPEN)
        norms, found_points = self.robust_norms(cam, part, gate * ready)
        decided = gnc_tls_weights(norms, self.inlier_sigmas, math.inf)
        weights[rows] = decided * gate * ready
        self.live.set_weights(cam, index[rows[ready]], decided[ready])
        done = np.unique(part.tracks[ready])
        for piece, point in zip(part.ids[done].tolist(), found_points[done], strict=True):
            points[piece] = point

    def keep_points(self, live: list[LiveFactor]) -> None:
        """The live factors' points at their last linearisation start the next frame's
        initial guess."""
        for _, cam, factor in live:
            points = self.live.points(cam)
            if factor.points is not None:
                for piece, point in zip(factor.obs.ids.tolist(), factor.points, strict=True):
                    points[piece] = point


def frame_rows(robot: Robot, frame: int, obs: FrameObservations, threshold_px: float) -> Rows:
    """A frame's observations as camera -> (track ids, normalised points, whitening
    ``(N, 2, 2)``: the pixel Jacobian over ``threshold_px``); cameras without tracks left out.

    Raises:
        ValueError: observations of a segment without a camera (naming ``frame``).
    """
    out = {}
    for cam, (track_ids, uv) in obs.tracks.items():
        camera = observed_camera(robot, frame, cam)
        ids = np.asarray(track_ids, dtype=np.int64)
        if len(ids) == 0:
            continue
        given = None if obs.bearings is None else obs.bearings.get(cam)
        if given is None:
            xy = camera.normalized(np.asarray(uv, dtype=float))
        else:
            b = np.asarray(given, dtype=float)
            xy = b[:, :2] / b[:, 2:3]
        out[cam] = (ids, xy, camera.pixel_jacobian(xy) / threshold_px)
    return out
