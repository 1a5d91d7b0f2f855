"""The exact model in the smoother's window: every observation projected through the model's
camera poses, each track's point eliminated (:class:`ExactTracks`).

What a frame adds: its vector alone (the core adds it). What a track's rows become: while its
piece is live, rows of one "live" projection factor per camera, replaced at every update;
once committed (its track ended, its first frame is about to leave the window, or it reached
``GraphOptions.max_track_frames``), one projection factor for good
(:mod:`~apcc_graph.estimation.projection_tracks`, :mod:`~apcc_graph.estimation.live_tracks`);
a track that outlives the window becomes a landmark, its point a variable
(:mod:`~apcc_graph.estimation.landmarks`). How an estimate is read back: the frames' vectors
(the core), the landmarks' points and the live pieces' points from their last linearisation
(here).
"""

from __future__ import annotations

from collections.abc import Mapping

import gtsam
import numpy as np
from numpy.typing import NDArray

from apcc_graph.estimation.initial_guess import FrameRows
from apcc_graph.estimation.landmarks import Landmarks
from apcc_graph.estimation.options import GraphOptions
from apcc_graph.estimation.projection_tracks import LiveFactor, ProjectionTracks, Rows
from apcc_graph.estimation.rotation_gate import gate_weights
from apcc_graph.estimation.smoother.solver import Additions
from apcc_graph.estimation.smoother_options import SmootherOptions
from apcc_graph.estimation.window import Window
from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.parameterisation import Bending
from apcc_graph.model.robot import Robot

Association = Mapping[int, NDArray[np.int64]]
"""camera -> the landmark of each of a frame's rows (-1: a live track's row)."""


class ExactTracks:
    """The exact model's tracks, pieces and landmarks in a smoother's window.

    Args:
        robot, options, settings, bending: the smoother's.
        window: the smoother's window (the estimates pieces are judged and promoted at).
        inlier_sigmas: the outlier threshold (whitened residual norm, pixel-noise units).
    """

    name = "exact"
    refines = True  # a new frame's guess is refined against the known points
    final_steps = 0  # Gauss-Newton steps of the whole window at the end
    default_gate: float | None = None  # the rotation gate's threshold when none is set
    elimination = None  # iSAM2's own elimination order
    trust_region = False  # Gauss-Newton steps: the frames' vectors alone, close to linear

    def __init__(self, robot: Robot, options: GraphOptions, settings: SmootherOptions,
                 window: Window, bending: Bending, inlier_sigmas: float) -> None:
        self.settings = settings
        self.tracks = ProjectionTracks(robot, options, settings, window, bending, inlier_sigmas)
        self.landmarks = Landmarks(robot, self.tracks.chain,
                                   lambda g: (window.thetas[g], window.times[g]),
                                   options.threshold_px, inlier_sigmas, settings.window.lag,
                                   settings.landmarks.max_per_camera,
                                   settings.landmarks.prior_sigma,
                                   settings.landmarks.pose_sigma, self.tracks.dim)
        self._full_window: int | None = None  # frames in a full window, once one left
        self._live: list[LiveFactor] = []

    @property
    def committed(self) -> int:
        """Observations committed into the graph so far (each exactly once)."""
        return self.tracks.committed

    @property
    def outliers(self) -> int:
        """Committed observations judged outliers so far."""
        return self.tracks.outliers

    def known(self, cam: int, ids: NDArray[np.int64]) -> NDArray[np.bool_]:
        """Which of a camera's track ids the window knows (landmarks or live tracks)."""
        return (self.landmarks.of(cam, ids) >= 0) | (self.tracks.live.piece_ids(cam, ids) >= 0)

    def judge(self, frame: int, agreed: Mapping[int, tuple[NDArray[np.int64],
                                                           NDArray[np.bool_]]]) -> None:
        """The rotation gate's judgement of frame ``frame``'s rows by the next frame."""
        for cam, (ids, agree) in agreed.items():
            self.tracks.live.judge(frame, cam, ids, agree)

    def make_room(self, add: Additions, f: int, t: float, rows: Rows, leaving: list[int],
                  first_kept: int, commit: bool) -> None:
        """Before frame ``f`` (at ``t`` seconds) enters: tracks that outlive the window become
        landmarks, and the pieces that are due are committed (before their first frames
        leave; ``commit``: those whose tracks ended too)."""
        seen = {c: ids for c, (ids, _, _) in rows.items()}
        self.landmarks.forget(seen, t)
        tracks = self.tracks
        if self.settings.landmarks.enabled:
            promoted = tracks.live.take_continuing(seen, first_kept, self.landmarks.room())
            for cam, (obs, ids) in promoted.items():
                first, last = int(obs.frames.min()), int(obs.frames.max())
                tracks.count(*self.landmarks.promote(add, cam, obs, ids, tracks.span(first, last),
                                                     t, tracks.live.gates(obs)))
        if leaving:  # the window is full: its length in frames, for the staggered cuts
            self._full_window = f - first_kept
        due = tracks.live.take_due(f, seen, first_kept, commit, window=self._full_window)
        for cam, obs in due.items():
            tracks.commit(add.graph, cam, obs)

    def retire(self, leaving: list[int], first_kept: int) -> None:
        """Frames ``leaving`` left the window (``first_kept`` is the oldest left)."""
        self.landmarks.retire(leaving)
        for g in leaving:
            self.tracks.bases.pop(g, None)
        self.tracks.live.drop_frames_before(first_kept)

    def associate(self, rows: Rows) -> Association:
        """The landmark each of the new frame's rows observes (-1: none)."""
        return {cam: self.landmarks.of(cam, ids) for cam, (ids, _, _) in rows.items()}

    def known_rows(self, rows: Rows, marks: Association,
                   gates: Mapping[int, FloatArray] | None = None
                   ) -> tuple[list[FrameRows], list[tuple[int, NDArray[np.bool_]]]]:
        """The new frame's rows whose points are known, for its initial guess
        (:meth:`~apcc_graph.estimation.projection_tracks.ProjectionTracks.known_rows`)."""
        return self.tracks.known_rows(rows, marks, self.landmarks, gates)

    def enter(self, add: Additions, f: int, t: float, x: FloatArray,
              base: FloatArray | None) -> None:
        """Frame ``f``'s variables beyond its vector (none) and its base pose."""
        self.tracks.bases[f] = base

    def observe(self, add: Additions, f: int, t: float, rows: Rows, marks: Association,
                weights: Mapping[int, FloatArray], verdicts: Mapping[int, NDArray[np.int8]],
                accepted: Mapping[int, NDArray[np.int64]]) -> None:
        """The new observations: of landmarks into the graph (with the gate's verdict so far:
        a landmark observation is final), of other tracks into their live pieces (with the
        gate's verdicts, which the next frame may still change); ``accepted``: the tracks the
        two-frame front end accepted, per camera."""
        for cam, (ids, xy, whiten) in rows.items():
            lm = marks[cam] >= 0
            live = ~lm
            if live.any():
                self.tracks.live.add(f, cam, ids[live], xy[live], whiten[live],
                                     weights[cam][live], verdicts[cam][live])
            if lm.any():
                w = weights[cam][lm] * gate_weights(verdicts[cam][lm])
                self.landmarks.observe(add, f, t, cam, marks[cam][lm], xy[lm], w)
                self.tracks.count(int(lm.sum()), int(np.sum(w == 0.0)))
        self.tracks.live.vouch(f, accepted)

    def replay(self, add: Additions, h: int, t: float, rows: Rows,
               verdicts: Mapping[int, NDArray[np.int8]], base: FloatArray | None) -> None:
        """A kept frame's rows after a restart become live tracks' rows (their outlier
        decisions come from the robust triangulation when their factor is first built)."""
        self.tracks.bases[h] = base
        for cam, (ids, xy, whiten) in rows.items():
            self.tracks.live.add(h, cam, ids, xy, whiten, None, verdicts[cam])

    def replaceable(self, graph: gtsam.NonlinearFactorGraph) -> list[int]:
        """The live projection factors, added to ``graph``; their positions there (the
        solver replaces them at the next update)."""
        self._live = self.tracks.live_factors(graph)
        return [pos for pos, *_ in self._live]

    def read(self, estimate: gtsam.Values) -> None:
        """After an update: the live factors' points start the next frame's guess; the
        landmarks' points are read back."""
        self.tracks.keep_points(self._live)
        self.landmarks.update_points(estimate)

    def reset(self, keep: int | None = None, base: FloatArray | None = None) -> None:
        """Forget every track, piece and landmark (a new window); the rows of frame ``keep``
        (the one it holds) start new pieces."""
        self.tracks.reset(keep=keep)
        self.tracks.bases = {} if keep is None else {keep: base}
        self.landmarks.reset()
        self._live = []

    def restart_frame(self, add: Additions, f: int, t: float, x: FloatArray,
                      base: FloatArray | None) -> None:
        """A restarted window's frame ``f`` at ``x``: nothing beyond its vector."""
        self.tracks.bases[f] = base

    def finish(self, add: Additions, t: float) -> None:
        """Commit every live piece (the end of the stream)."""
        for cam, obs in self.tracks.live.take_all().items():
            self.tracks.commit(add.graph, cam, obs)
        self._live = []

    def base(self, g: int) -> FloatArray | None:
        """Frame ``g``'s base pose (``None``: identity), for frames in the window."""
        return self.tracks.bases.get(g)

    def camera_rotations(self, g: int) -> dict[int, FloatArray]:
        """None: the exact model's two-frame front end guesses a new frame (it solves the
        generalized epipolar constraint through the model, which holds here)."""
        return {}
