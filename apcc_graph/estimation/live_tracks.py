"""The tracks a streaming estimator is still watching, until each one is committed once.

Every observation enters the smoother's graph exactly once, inside the projection factor of its
track (:mod:`apcc_graph.factors.projection`). A track is therefore held here while it is being
observed and committed, all its observations at once, when one of these happens:

- it ends: the camera no longer sees it in the new frame (a frame in which the camera sees
  nothing at all ends no track);
- its first frame is about to leave the smoother's window (a piece of a track that outlives the
  window: the rest of the track starts a new piece with its own point, or, with
  :meth:`LiveTracks.take_continuing`, the estimator keeps the track as a landmark);
- it reached ``max_frames`` frames;
- with ``stagger``, it belongs to a cohort (a quarter or more of its camera's live pieces born
  in the same frame: the camera's first frame, a new scene) and is longer than the window less
  its own share of half a window: otherwise a cohort is cut together, every window, and the
  frame after each cut has no known point but the landmarks (on a real robot's replayed motion
  the smoother's window was dragged 20 degrees off after such a cut).

An ended piece may be held back (still live) until the estimator commits a batch of them
(``commit_ended=False`` in :meth:`LiveTracks.take_due`): fewer, larger committed factors, each
re-linearised at once. Its first frame leaving the window still commits it.

Pieces of fewer than ``min_rows`` observations are dropped when committed (one observation of an
unknown point carries no information). A piece joins the estimator's live factor once it is long
enough to tell a wrong association (:meth:`LiveTracks.live_rows`), or earlier if the front end
vouched for every pair of its consecutive observations (:meth:`LiveTracks.vouch`): in the first
frames, when no piece is long yet, that is the only vision the estimator has. Observations are
kept per frame and dropped with their frame when it leaves the window, by then always committed.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from apcc_graph.estimation.rotation_gate import NOT_JUDGED, combine, gate_weights
from apcc_graph.factors.track_points import TrackObservations
from apcc_graph.model.arrays import FloatArray, IntArray

COHORT = 0.25
"""With ``stagger``, live pieces sharing a first frame with at least this share of their
camera's live pieces are cut early, each by its own share of half a window."""


@dataclass
class _FrameRows:
    """One frame's observations of one camera."""

    frame: int
    pieces: IntArray  # piece id per row
    ids: IntArray  # track id per row
    xy: FloatArray  # (n, 2) normalised coordinates
    whiten: FloatArray  # (n, 2, 2)
    weights: FloatArray  # (n,) robust decisions (1 inlier, 0 outlier)
    verdicts: NDArray[np.int8]  # (n,) the model-free gate's (estimation/rotation_gate.py)


@dataclass
class _Camera:
    rows: list[_FrameRows] = field(default_factory=list)
    piece_of: dict[int, int] = field(default_factory=dict)  # track id -> its live piece
    first: dict[int, int] = field(default_factory=dict)  # live piece -> first frame
    last: dict[int, int] = field(default_factory=dict)  # live piece -> last frame seen
    points: dict[int, FloatArray] = field(default_factory=dict)  # piece -> world point
    ended: set[int] = field(default_factory=set)  # pieces whose track ended, not committed
    vouched: set[int] = field(default_factory=set)  # every pair of rows accepted by a front end


class LiveTracks:
    """Live track pieces of every camera (see the module docstring).

    Args:
        cameras: the cameras (segment indices).
        max_frames: longest piece, in frames.
        min_rows: shortest piece worth committing.
    """

    def __init__(self, cameras: tuple[int, ...], max_frames: int, min_rows: int = 2,
                 stagger: bool = False) -> None:
        self._cams = {c: _Camera() for c in cameras}
        self.max_frames = int(max_frames)
        self.min_rows = int(min_rows)
        self.stagger = bool(stagger)
        self._next_piece = 0

    def _early(self, piece: int, window: int) -> int:
        """How many frames before its first frame leaves a window of ``window`` frames a
        piece of a cohort is cut (with ``stagger``): a fixed share of up to half the window
        per piece, so that pieces born together are not all cut together again."""
        share = ((piece * 2654435761) % 2**32) / 2**32  # Knuth's multiplicative hash
        return int(share * (window // 2))

    @staticmethod
    def _cohorts(state: _Camera) -> set[int]:
        """The first frames shared by at least :data:`COHORT` of a camera's live pieces:
        pieces born together (a camera's first frame, a new scene after a blackout or a gap)
        that would otherwise be cut together, every window, leaving the frame after each cut
        with no known point."""
        firsts, counts = np.unique(np.fromiter(state.first.values(), dtype=np.int64,
                                               count=len(state.first)), return_counts=True)
        return set(firsts[counts >= max(COHORT * len(state.first), 2.0)].tolist())

    def add(self, frame: int, cam: int, ids: IntArray, xy: FloatArray, whiten: FloatArray,
            weights: FloatArray | None = None,
            verdicts: NDArray[np.int8] | None = None) -> None:
        """Record camera ``cam``'s observations of frame ``frame`` (after :meth:`take_due`),
        with their first robust decisions (default: all inliers) and the model-free gate's
        verdicts (default: not judged; :meth:`judge` updates them)."""
        state = self._cams[cam]
        pieces = np.empty(len(ids), dtype=np.int64)
        for k, tid in enumerate(ids.tolist()):
            piece = state.piece_of.get(tid)
            if piece is None:
                piece = self._next_piece
                self._next_piece += 1
                state.piece_of[tid] = piece
                state.first[piece] = frame
            state.last[piece] = frame
            pieces[k] = piece
        w = np.ones(len(ids)) if weights is None else np.asarray(weights, dtype=float)
        v = (np.full(len(ids), NOT_JUDGED, dtype=np.int8) if verdicts is None
             else np.asarray(verdicts, dtype=np.int8).copy())
        state.rows.append(_FrameRows(frame, pieces, ids, xy, whiten, w, v))

    def frame_rows(self, frame: int) -> dict[int, tuple[IntArray, FloatArray, FloatArray,
                                                        FloatArray, NDArray[np.int8]]]:
        """Camera -> the track ids, normalised coordinates, whitening, weights and gate
        verdicts of its observations in ``frame`` (cameras that saw it while it is still
        held)."""
        out = {}
        for cam, state in self._cams.items():
            for r in state.rows:
                if r.frame == frame and len(r.ids):
                    out[cam] = (r.ids.copy(), r.xy.copy(), r.whiten.copy(), r.weights.copy(),
                                r.verdicts.copy())
        return out

    def judge(self, frame: int, cam: int, ids: IntArray, agree: NDArray[np.bool_]) -> None:
        """A neighbouring frame's judgement of camera ``cam``'s observations of tracks ``ids``
        in ``frame`` (those still held; :func:`~apcc_graph.estimation.rotation_gate.combine`).
        """
        agree = np.asarray(agree, dtype=bool)
        for r in self._cams[cam].rows:
            if r.frame == frame:
                _, mine, theirs = np.intersect1d(r.ids, np.asarray(ids), assume_unique=True,
                                                 return_indices=True)
                r.verdicts[mine] = combine(r.verdicts[mine], agree[theirs])

    def gates(self, obs: TrackObservations) -> FloatArray:
        """The gate weights of the rows of ``obs`` (ids are piece ids, as :meth:`take_due`
        and :meth:`live_rows` return them), looked up by (piece, frame) among the rows still
        held (call before :meth:`drop_frames_before`); 1 for a row not found."""
        state = self._cams[obs.camera]
        if not any(np.any(r.verdicts == 0) for r in state.rows):  # the gate closed nothing
            return np.ones(len(obs))
        keys = np.concatenate([(r.pieces << 32) | r.frame for r in state.rows])
        verdicts = np.concatenate([r.verdicts for r in state.rows])
        order = np.argsort(keys, kind="stable")
        keys, verdicts = keys[order], verdicts[order]
        want = (obs.ids[obs.tracks].astype(np.int64) << 32) | obs.frames.astype(np.int64)
        at = np.minimum(np.searchsorted(keys, want), len(keys) - 1)
        found = keys[at] == want
        return np.where(found, gate_weights(verdicts[at]), 1.0)

    def take_due(self, frame: int, seen: dict[int, IntArray], leaving_before: int,
                 commit_ended: bool = True, window: int | None = None
                 ) -> dict[int, TrackObservations]:
        """Commit the pieces that are due before frame ``frame``'s observations are added.

        Args:
            frame: the new frame.
            seen: camera -> track ids seen in the new frame.
            leaving_before: frames before this one leave the window in this update.
            commit_ended: commit the pieces whose tracks ended (now or held back since);
                ``False`` holds them, live, for a later call.
            window: the window's length in frames once full (``None`` before it is known):
                with ``stagger``, a piece of a cohort (:meth:`_cohorts`) is cut once it is
                longer than the window less its own share of half of it.

        Returns:
            camera -> the committed observations (pieces with at least ``min_rows`` rows;
            track ids are piece ids), for cameras that have any.
        """
        out: dict[int, TrackObservations] = {}
        for cam, state in self._cams.items():
            blind = cam not in seen or len(seen[cam]) == 0
            now = set() if blind else set(seen[cam].tolist())
            due = set()
            cohorts = self._cohorts(state) if self.stagger and window else set()
            for tid, piece in list(state.piece_of.items()):
                length = frame - state.first[piece]
                # A camera that saw nothing at all (a dropped frame) ends no track: its
                # tracks may go on in the next frame.
                ended = not blind and tid not in now
                if ended:
                    state.ended.add(piece)
                    del state.piece_of[tid]
                elif (state.first[piece] < leaving_before or length >= self.max_frames
                      or (state.first[piece] in cohorts and window is not None
                          and length > window - self._early(piece, window))):
                    due.add(piece)
                    del state.piece_of[tid]
            for piece in list(state.ended):
                if commit_ended or state.first[piece] < leaving_before:
                    due.add(piece)
                    state.ended.discard(piece)
            obs = self._take(state, due)
            if obs is not None:
                out[cam] = obs
        return out

    def take_continuing(self, seen: dict[int, IntArray], leaving_before: int,
                        limit: dict[int, int] | None = None
                        ) -> dict[int, tuple[TrackObservations, dict[int, int]]]:
        """Take out the pieces whose first frame leaves the window while their track goes on
        (the new frame sees it): an estimator keeps their points as variables (landmarks)
        instead of cutting the tracks. Call before :meth:`take_due`.

        Args:
            seen: camera -> track ids seen in the new frame.
            leaving_before: frames before this one leave the window in this update.
            limit: camera -> most pieces to take (the oldest first); the others stay, and
                :meth:`take_due` cuts them.

        Returns:
            camera -> (the pieces' observations, ids are piece ids; track id -> piece), for
            pieces with at least ``min_rows`` rows.
        """
        out: dict[int, tuple[TrackObservations, dict[int, int]]] = {}
        for cam, state in self._cams.items():
            if cam not in seen or len(seen[cam]) == 0:
                continue
            now = set(seen[cam].tolist())
            going = {tid: piece for tid, piece in state.piece_of.items()
                     if state.first[piece] < leaving_before and tid in now}
            room = None if limit is None else max(int(limit.get(cam, 0)), 0)
            if room is not None and len(going) > room:
                oldest = sorted(going.items(), key=lambda item: (state.first[item[1]], item[1]))
                going = dict(oldest[:room])
            for tid in going:
                del state.piece_of[tid]
            obs = self._take(state, set(going.values()))
            if obs is not None:
                out[cam] = (obs, going)
        return out

    def take_all(self) -> dict[int, TrackObservations]:
        """Commit every live piece (end of a stream)."""
        out: dict[int, TrackObservations] = {}
        for cam, state in self._cams.items():
            state.piece_of.clear()
            state.ended.clear()
            obs = self._take(state, set(state.first))
            if obs is not None:
                out[cam] = obs
        return out

    def _take(self, state: _Camera, due: set[int]) -> TrackObservations | None:
        """The observations of pieces ``due`` (those long enough), and forget the pieces."""
        obs = self._collect(state, due) if due else None
        for piece in due:
            state.vouched.discard(piece)
            state.first.pop(piece)
            state.last.pop(piece)
            state.points.pop(piece, None)
        return obs

    def _collect(self, state: _Camera, due: set[int]) -> TrackObservations | None:
        found = self._gather(state, due)
        return None if found is None else found[0]

    def _gather(self, state: _Camera, due: set[int]
                ) -> tuple[TrackObservations, FloatArray, IntArray] | None:
        """The rows of pieces ``due`` with at least ``min_rows`` rows: observations (ids are
        piece ids), their weights (robust decisions times the gate's), and each row's
        position in the concatenated buffer."""
        if not state.rows or not due:
            return None
        pieces = np.concatenate([r.pieces for r in state.rows])
        keep = np.isin(pieces, np.fromiter(due, dtype=np.int64, count=len(due)))
        _, inverse, counts = np.unique(pieces[keep], return_inverse=True, return_counts=True)
        keep[keep] = counts[inverse] >= self.min_rows
        if not keep.any():
            return None
        index = np.flatnonzero(keep)
        frames = np.concatenate([np.full(len(r.pieces), r.frame) for r in state.rows])[index]
        order = np.lexsort((frames, pieces[index]))
        index = index[order]
        xy = np.concatenate([r.xy for r in state.rows])[index]
        whiten = np.concatenate([r.whiten for r in state.rows])[index]
        weights = np.concatenate([r.weights for r in state.rows])[index]
        if any(np.any(r.verdicts == 0) for r in state.rows):  # the gate closed some
            weights *= gate_weights(np.concatenate([r.verdicts for r in state.rows])[index])
        cam = next(c for c, s in self._cams.items() if s is state)
        obs = TrackObservations.build(cam, frames[order], pieces[index], xy, whiten)
        return obs, weights, index

    def live_rows(self, cam: int, min_rows: int | None = None
                  ) -> tuple[TrackObservations, FloatArray, IntArray] | None:
        """Camera ``cam``'s live pieces seen in at least ``min_rows`` frames (default the
        store's ``min_rows``), and the vouched ones (:meth:`vouch`): observations (ids are
        piece ids), weights, and row positions for :meth:`set_weights`."""
        state = self._cams[cam]
        need = self.min_rows if min_rows is None else int(min_rows)
        pieces = {p for p, f in state.first.items() if state.last[p] - f + 1 >= need}
        return self._gather(state, pieces | state.vouched)

    def vouch(self, frame: int, accepted: Mapping[int, IntArray]) -> None:
        """Record which observations of frame ``frame`` (after :meth:`add`) a front end
        accepted, with the same track's observation in frame ``frame - 1``, as inliers of its
        consensus: ``accepted`` maps a camera to those track ids (call every frame; a camera
        left out, or an empty mapping when no front end ran, accepted none). A piece stays
        vouched while every new observation of it is accepted; a piece that loses it also
        loses its point, so that its rows are decided again, all at once, when it is long
        enough (:meth:`live_rows`)."""
        for cam, state in self._cams.items():
            ids = np.asarray(accepted.get(cam, ()), dtype=np.int64).tolist()
            now = {state.piece_of[t] for t in ids if t in state.piece_of}
            for piece in now:
                if state.first[piece] == frame - 1:
                    state.vouched.add(piece)
            lost = {p for p in state.vouched if state.last[p] == frame and p not in now}
            for piece in lost:
                state.vouched.discard(piece)
                state.points.pop(piece, None)

    def lengths(self, cam: int, pieces: IntArray) -> IntArray:
        """Observations so far of each live piece (0 for -1 or a piece no longer live)."""
        state = self._cams[cam]
        return np.array([state.last[p] - state.first[p] + 1 if p in state.first else 0
                         for p in np.asarray(pieces).tolist()], dtype=np.int64)

    def set_weights(self, cam: int, index: IntArray, weights: FloatArray) -> None:
        """Store robust decisions for rows at buffer positions ``index`` (from
        :meth:`live_rows`, before any other change); the gate's verdicts stay apart."""
        state = self._cams[cam]
        sizes = np.array([len(r.pieces) for r in state.rows])
        starts = np.concatenate([[0], np.cumsum(sizes)])
        chunk = np.searchsorted(starts, index, side="right") - 1
        for c in np.unique(chunk):
            sel = chunk == c
            state.rows[c].weights[index[sel] - starts[c]] = weights[sel]

    def drop_frames_before(self, frame: int) -> None:
        """Forget observations of frames before ``frame`` (they have left the window)."""
        for state in self._cams.values():
            state.rows = [r for r in state.rows if r.frame >= frame]

    def points(self, cam: int) -> dict[int, FloatArray]:
        """Cached world points of live pieces (piece id -> ``(3,)``)."""
        return self._cams[cam].points

    def piece_ids(self, cam: int, track_ids: IntArray) -> IntArray:
        """Live piece of each track id (-1 where the track has none)."""
        state = self._cams[cam]
        return np.array([state.piece_of.get(t, -1) for t in track_ids.tolist()], dtype=np.int64)
