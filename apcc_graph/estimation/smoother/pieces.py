"""What the smoother's two measurement models share (:class:`PieceWindow`): a track's rows go
to a live piece, replaced at every update, until the piece is committed for good or (where
the model has landmarks) its track, outliving the window, becomes a landmark.

The models differ in what the pieces are projected through (the exact model's camera poses,
:mod:`~apcc_graph.estimation.smoother.exact`; the tips, with model error as noise,
:mod:`~apcc_graph.estimation.smoother.noisy`), in whether there are landmarks (the exact
model's; with model error as noise a track that outlives the window is cut), and in what a
frame adds; the order of the stages, which decides that every observation enters the graph
exactly once, is here.
"""

from __future__ import annotations

from collections.abc import Mapping

import gtsam
import numpy as np
from numpy.typing import NDArray

from apcc_graph.estimation.landmarks import Landmarks
from apcc_graph.estimation.projection_tracks import LiveFactor, ProjectionTracks, Rows
from apcc_graph.estimation.rotation_gate import gate_weights
from apcc_graph.estimation.smoother.solver import Additions
from apcc_graph.estimation.smoother_options import SmootherOptions
from apcc_graph.model.arrays import FloatArray

Association = Mapping[int, NDArray[np.int64]]
"""camera -> the landmark of each of a frame's rows (-1: a live track's row)."""


class PieceWindow:
    """Live pieces, committed pieces and landmarks of a smoother's window.

    Args:
        settings: the smoother's.
        tracks: the pieces (and how they are projected).
        landmarks: the landmarks (and how their observations attach); ``None``: a track that
            outlives the window is cut into pieces.
    """

    pair_weights = False
    """The two-frame front end's weights join the rotation gate's (the exact model, where the
    front end's constraint holds)."""

    def __init__(self, settings: SmootherOptions, tracks: ProjectionTracks,
                 landmarks: Landmarks | None) -> None:
        self.settings, self.tracks, self.landmarks = settings, tracks, landmarks
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
        live = self.tracks.live.piece_ids(cam, ids) >= 0
        return live if self.landmarks is None else (self.landmarks.of(cam, ids) >= 0) | live

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
        tracks, landmarks = self.tracks, self.landmarks
        if landmarks is not None:
            landmarks.forget(seen, t)
            promoted = tracks.live.take_continuing(seen, first_kept, landmarks.room())
            for cam, (obs, ids) in promoted.items():
                tracks.count(*landmarks.promote(add, cam, obs, ids, tracks.robust_norms, t,
                                                tracks.live.gates(obs)))
        if leaving:  # the window is full: its length in frames, for the staggered cuts
            self._full_window = f - first_kept
        due = tracks.live.take_due(f, seen, first_kept, commit, window=self._full_window)
        for cam, obs in due.items():
            tracks.commit(add.graph, cam, obs)

    def retire(self, leaving: list[int], first_kept: int) -> None:
        """Frames ``leaving`` left the window (``first_kept`` is the oldest left)."""
        if self.landmarks is not None:
            self.landmarks.retire(leaving)
        for g in leaving:
            self.tracks.bases.pop(g, None)
        self.tracks.live.drop_frames_before(first_kept)

    def associate(self, rows: Rows) -> Association:
        """The landmark each of the new frame's rows observes (-1: none)."""
        if self.landmarks is None:
            return {cam: np.full(len(ids), -1, dtype=np.int64) for cam, (ids, _, _) in rows.items()}
        return {cam: self.landmarks.of(cam, ids) for cam, (ids, _, _) in rows.items()}

    def observe(self, add: Additions, f: int, t: float, rows: Rows, marks: Association,
                weights: Mapping[int, FloatArray], verdicts: Mapping[int, NDArray[np.int8]],
                accepted: Mapping[int, NDArray[np.int64]]) -> None:
        """The new observations: of landmarks into the graph (with the gate's verdict so far:
        a landmark observation is final), of other tracks into their live pieces (with the
        gate's verdicts, which the next frame may still change). ``weights`` and
        ``accepted`` (the tracks the two-frame front end accepted, per camera) count only
        with :attr:`pair_weights`."""
        for cam, (ids, xy, whiten) in rows.items():
            lm = marks[cam] >= 0
            live = ~lm
            pair = weights[cam] if self.pair_weights else None
            if live.any():
                self.tracks.live.add(f, cam, ids[live], xy[live], whiten[live],
                                     None if pair is None else pair[live], verdicts[cam][live])
            if lm.any() and self.landmarks is not None:
                w = gate_weights(verdicts[cam][lm])
                w = w if pair is None else pair[lm] * w
                left_out = self.landmarks.observe(add, f, t, cam, marks[cam][lm], xy[lm], w)
                self.tracks.count(int(lm.sum()), left_out)
        if self.pair_weights:
            self.tracks.live.vouch(f, accepted)

    def replay(self, add: Additions, h: int, t: float, rows: Rows,
               verdicts: Mapping[int, NDArray[np.int8]], base: FloatArray | None) -> None:
        """A kept frame's rows after a restart become live tracks' rows (their outlier
        decisions come from the robust triangulation when their factor is first built)."""
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
        if self.landmarks is not None:
            self.landmarks.update_points(estimate)

    def reset(self, keep: int | None = None, base: FloatArray | None = None) -> None:
        """Forget every track, piece and landmark (a new window); the rows of frame ``keep``
        (the one it holds, on ``base``) start new pieces."""
        self.tracks.reset(keep=keep)
        self.tracks.bases = {} if keep is None else {keep: base}
        if self.landmarks is not None:
            self.landmarks.reset()
        self._live = []

    def finish(self, add: Additions, t: float) -> None:
        """Commit every live piece (the end of the stream)."""
        for cam, obs in self.tracks.live.take_all().items():
            self.tracks.commit(add.graph, cam, obs)
        self._live = []
