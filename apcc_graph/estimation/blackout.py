"""Tracks that come back after a blackout: every camera saw nothing, and none of the tracks
that return is one the smoother knows.

Nothing then ties the new frames to the frames before the blackout but the motion prior across
it, loose by then (``motion_sigma`` times the square root of its length: about 29 degrees after
a second at the default). The new tracks give the motion back at once, but the absolute angles
only as far as the cameras' parallax and the kinematic chain tell them, and the smoother's
Gauss-Newton steps from a start that far off end in another minimum (60 degrees off on the
reliability bench, where the robot moved 60 degrees in the dark).

So the smoother says so (:class:`BlackoutWarning`, with the sigma the motion prior had left)
and *re-acquires* the angles (:class:`Reacquisition`): it keeps the observations of the frames
after the blackout until the first of them is about to leave the window, then solves those
frames in one batch (:func:`~apcc_graph.estimation.batch_solve.projection_solve`, from the
unknown-start search's answer over them when it determines one, else from the smoother's
estimate with a start prior of the motion prior's sigma; the paper's chain carries that start
through the frames). Graduated non-convexity and Levenberg-Marquardt over a second of new
tracks find the basin that Gauss-Newton steps frame by frame miss: on the 210-frame test
recording, batches over 20 and 40 frames from 60 degrees off came within 12 and 3 degrees of
segment 1 (honest sigmas of 6 and 1.3), segments 2 and 3 within 2 and 0.4. The batch's angles
become those frames' final estimates (status ``"reacquired"``; :class:`Reacquired` holds what
it found), and the window restarts holding them, under the batch's own priors, their
observations replayed into its tracks (:mod:`apcc_graph.estimation.smoother.restarts`). The
blind frames themselves are kept out of the new tracks' first, wrong minimum (the window
restarts at the last of them when the tracks come back) and, once the batch has solved,
:func:`bridged` between the frames before the blackout and the first re-acquired frame. Further
rounds over ever more of the frames follow while the batch is unsure
(:func:`~apcc_graph.estimation.smoother.gaps.next_round`).
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray

from apcc_graph.estimation.batch_solve import projection_solve
from apcc_graph.estimation.chain import chain_vectors
from apcc_graph.estimation.options import GraphOptions, Robustness
from apcc_graph.estimation.projection_tracks import Rows
from apcc_graph.estimation.start_search import find_start
from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.parameterisation import Bending
from apcc_graph.model.robot import Robot
from apcc_graph.model.sequence import FrameObservations, Sequence, Tracks

MIN_SIGMA = math.radians(1.0)
"""Smallest start prior of a re-acquisition (radians)."""


class BlackoutWarning(UserWarning):
    """Every camera lost its tracks and only new ones came back: the absolute angles after the
    blackout may be far off (see :mod:`apcc_graph.estimation.blackout`)."""


def tracks_returned(rows: Rows, previous: Rows,
                    known: Callable[[int, NDArray[np.int64]], NDArray[np.bool_]]) -> bool:
    """Whether the new frame has tracks, the previous frame had none, and no new track is
    known (``known(camera, ids)``: which ids are landmarks or live tracks)."""
    if not rows or previous:
        return False
    return not any(np.any(known(cam, ids)) for cam, (ids, _, _) in rows.items())


def warn_blackout(frame: int, timestamp: float, sigmas: FloatArray) -> None:
    """Say that tracks came back after a blackout at ``frame`` (``sigmas``: the smoother's
    marginal sigmas of the last blind frame, radians; NaN if unknown)."""
    shown = ", ".join("?" if not math.isfinite(s) else f"{math.degrees(s):.2g}" for s in sigmas)
    warnings.warn(f"frame {frame} ({timestamp:.3f} s): every camera had lost its tracks and "
                  "only new ones came back; the angles across the blackout rest on the motion "
                  f"prior (sigma {shown} deg). The smoother re-acquires them from the new "
                  "tracks once they span its lag; until then, and as far as their parallax "
                  "allows after, the absolute angles may be off",
                  BlackoutWarning, stacklevel=4)


def warn_pause(frame: int, timestamp: float, gap: float, sigma: float) -> None:
    """Say that ``frame`` (at ``timestamp`` seconds) came ``gap`` seconds after the previous
    one, with none of the tracks seen before it (``sigma``: the start prior of the
    re-acquisition, radians)."""
    warnings.warn(f"frame {frame} ({timestamp:.3f} s): the recording had paused for {gap:.2f} s, "
                  "and none of the tracks seen before came back; the robot may have moved "
                  "anywhere meanwhile. The smoother re-acquires the angles from the tracks "
                  "after the pause once they span its lag (from the unknown-start search, else "
                  f"from the last estimate with a sigma of {math.degrees(sigma):.2g} deg); until "
                  "then they may be off",
                  BlackoutWarning, stacklevel=4)


def warn_segment_lost(frame: int, timestamp: float, camera: int, sigma: float) -> None:
    """Say that the tracks of the camera on segment ``camera`` (0-based) came back all new at
    ``frame`` (``timestamp`` seconds) after the smoother lost its segment (``sigma``: that
    segment's marginal sigma the frame before, radians; NaN if unknown)."""
    shown = "?" if not math.isfinite(sigma) else f"{math.degrees(sigma):.2g}"
    n = camera + 1
    warnings.warn(f"frame {frame} ({timestamp:.3f} s): camera cam_{n}'s tracks came back all "
                  f"new after the smoother had lost segment {n} (sigma {shown} deg: no other "
                  "camera sees it). The smoother re-acquires that segment from the frames that "
                  "follow once they span its lag (holding that camera's tracks until then); "
                  "until then its angle rests on the motion prior and may be off",
                  BlackoutWarning, stacklevel=5)


@dataclass(frozen=True)
class Forward:
    """A blind frame's estimate from the frames before the blackout alone: its frame vector,
    flattened per-segment covariance blocks (as the window keeps them) and graph time."""

    thetas: FloatArray
    blocks: FloatArray
    time: float


def bridged(forward: Forward, after: FloatArray, after_blocks: FloatArray, time: float,
            motion_sigma: float, width: int) -> tuple[FloatArray, FloatArray]:
    """A blind frame's estimate given every frame: ``forward`` (from the frames before the
    blackout) fused with what the first frame after it (``after``, its flattened covariance
    blocks ``after_blocks``, at graph time ``time``) says of it through the random-walk
    motion prior (``motion_sigma`` rad/sqrt(s)) over the time between them.

    No frame between the two saw anything, so the two are independent given the blind frame
    (the two-filter smoother; exact for the random walk, per segment block of ``width``
    components). Returns its frame vector and flattened covariance blocks; where either side
    has no covariance, ``forward`` unchanged.
    """
    P = np.asarray(forward.blocks, dtype=float).reshape(-1, width, width)
    drift = motion_sigma**2 * max(time - forward.time, 0.0) * np.eye(width)
    B = np.asarray(after_blocks, dtype=float).reshape(-1, width, width) + drift
    if not (np.all(np.isfinite(P)) and np.all(np.isfinite(B))):
        return forward.thetas, forward.blocks
    m = np.asarray(forward.thetas, dtype=float).reshape(-1, width, 1)
    b = np.asarray(after, dtype=float).reshape(-1, width, 1)
    P_inv, B_inv = np.linalg.inv(P), np.linalg.inv(B)
    C = np.linalg.inv(P_inv + B_inv)
    x = C @ (P_inv @ m + B_inv @ b)
    return x.ravel(), C.ravel()


@dataclass(frozen=True)
class Reacquired:
    """What one re-acquisition's batch found over the ``K`` kept frames.

    Attributes:
        x: ``(K, dim)`` frame vectors (radians).
        blocks: ``(K, S w w)`` flattened marginal covariance blocks (radians squared).
        sigmas: ``(K, dim)`` marginal standard deviations (radians).
        start: ``(dim,)`` the mean of the start prior it used on the first kept frame.
        start_sigmas: ``(dim,)`` that prior's standard deviations (radians).
    """

    x: FloatArray
    blocks: FloatArray
    sigmas: FloatArray
    start: FloatArray
    start_sigmas: FloatArray


@dataclass
class Reacquisition:
    """The frames after a blackout, kept until one batch re-acquires their angles.

    Args:
        robot: the robot.
        options: the smoother's graph options (the start prior is replaced).
        inlier_sigmas: the smoother's outlier threshold.
        bending: the smoother's parameterisation.
        theta0: the smoother's estimate of the first kept frame (its frame vector, radians).
        sigma: the start prior of the batch (radians; at least :data:`MIN_SIGMA`).
        search: first run the unknown-start search over the kept frames; when it determines
            their start, its answer and sigma replace ``theta0`` and ``sigma``.
        blind: after a blackout, the blind frames' estimates from the frames before it
            (:class:`Forward`), for :func:`bridged` once the batch has solved.
        then: after this re-acquisition, keep the frames until they span this many seconds
            and re-acquire them once more (:meth:`longer`), and then in further rounds while
            the batch is unsure (:func:`~apcc_graph.estimation.smoother.gaps.next_round`);
            ``None`` and no ``span``: once.
        span: keep the frames until they span this many seconds rather than the lag.
        camera: one camera's tracks came back (its segment lost, the others not): only that
            segment is re-acquired (the search's answer replaces it alone); ``None``: every
            segment.
        sigmas: ``(dim,)`` the start prior's sigma per component (radians), replacing
            ``sigma`` (a segment the search determines takes the search's).
        since: with ``camera``, the first graph frame that camera did not see (its blind
            frames are bridged once the segment is re-acquired).
    """

    robot: Robot
    options: GraphOptions
    inlier_sigmas: float
    bending: Bending
    theta0: FloatArray
    sigma: float
    search: bool = True
    then: float | None = None
    span: float | None = None
    blind: dict[int, Forward] = field(default_factory=dict)
    camera: int | None = None
    sigmas: FloatArray | None = None
    since: int | None = None
    slots: list[int] = field(default_factory=list)
    _times: list[float] = field(default_factory=list)
    _frames: list[FrameObservations] = field(default_factory=list)

    def add(self, slot: int, t: float, observations: FrameObservations) -> None:
        """Keep graph frame ``slot`` (at graph time ``t``) and its observations."""
        self.slots.append(slot)
        self._times.append(t)
        self._frames.append(observations)

    def frame(self, k: int) -> FrameObservations:
        """The ``k``-th kept frame's observations."""
        return self._frames[k]

    def base(self, k: int) -> FloatArray | None:
        """The ``k``-th kept frame's base pose, if it has one."""
        base = self._frames[k].world_T_base
        return None if base is None else np.asarray(base, dtype=float)

    @property
    def times(self) -> list[float]:
        """The kept frames' graph times (seconds)."""
        return list(self._times)

    @property
    def first_time(self) -> float:
        """The graph time of the first kept frame."""
        return self._times[0]

    def due(self, t: float, lag: float) -> bool:
        """Whether the first kept frame leaves a window of ``lag`` seconds at graph time
        ``t`` (or has left it, after a restart); with ``span``, once the kept frames span
        that many seconds (at least ``lag``)."""
        wait = lag if self.span is None else max(self.span, lag)
        return bool(self._times) and self._times[0] < t - wait

    def longer(self, span: float) -> Reacquisition:
        """The same re-acquisition, its frames kept until they span ``span`` seconds (a second
        round over more of the frames after the blackout)."""
        return replace(self, then=None, span=span, slots=list(self.slots),
                       _times=list(self._times), _frames=list(self._frames))

    def sequence(self) -> Sequence:
        """The kept frames as a recording (their frame ``k`` is the ``k``-th kept)."""
        tracks = stacked_tracks(self.robot.camera_segments, [obs.tracks for obs in self._frames])
        bases = [obs.world_T_base for obs in self._frames]
        return Sequence(self.robot, self._times, tracks,
                        None if any(b is None for b in bases) else np.array(bases))

    def solve(self) -> Reacquired:
        """One batch over the kept frames (:class:`Reacquired`), in the model ``options`` pick."""
        sequence = self.sequence()
        theta0, sigma, spreads = (self._searched(sequence) if self.search
                                  else (self.theta0, self.sigma, None))
        options = replace(self.options, theta0_sigma=max(sigma, MIN_SIGMA))
        sigmas = None
        if self.camera is not None:  # the search answers for the lost segment only
            theta0, sigmas = self._one_segment(theta0, spreads)
        # From the chain whatever the model: with a model noise of 5 mm / 2 deg, a 20-frame
        # re-acquisition from the cameras' rotations ended 8.9 / 6.8 / 2.6 deg off with
        # singular marginals, from the chain 4.5 / 1.0 / 0.7 deg off.
        start, _, _ = chain_vectors(sequence, self.bending, theta0, options.threshold_px)
        found = projection_solve(sequence, start, theta0, options,
                                 Robustness(self.inlier_sigmas), bending=self.bending,
                                 start_sigmas=sigmas)
        prior = (np.full(len(theta0), options.theta0_sigma) if sigmas is None
                 else np.asarray(sigmas, dtype=float))
        return Reacquired(found.x, found.blocks.reshape(len(found.x), -1), found.sigmas,
                          np.array(theta0, dtype=float), prior)

    def block(self) -> slice:
        """The components of the re-acquired camera's segment in a frame vector."""
        w, c = self.bending.width, self.camera
        if c is None:
            raise ValueError("Reacquisition.block: every segment is re-acquired")
        return slice(w * c, w * (c + 1))

    def _one_segment(self, searched: FloatArray, spreads: FloatArray | None
                     ) -> tuple[FloatArray, FloatArray]:
        """The start of a one-camera re-acquisition: the smoother's frame vector and sigmas,
        the lost segment's block from ``searched`` when the search determined it (``spreads``:
        its ``(S,)`` sigmas, else ``None``)."""
        theta0 = np.array(self.theta0, dtype=float)
        sigmas = (np.full(len(theta0), self.sigma) if self.sigmas is None
                  else np.array(self.sigmas, dtype=float))
        block = self.block()
        if spreads is not None:
            theta0[block], sigmas[block] = searched[block], spreads[self.camera]
        sigmas[block] = np.maximum(sigmas[block], MIN_SIGMA)
        return theta0, np.maximum(sigmas, 1e-6)

    def _searched(self, sequence: Sequence) -> tuple[FloatArray, float, FloatArray | None]:
        """The kept frames' start, its sigma and the search's ``(S,)`` sigmas: the
        unknown-start search's when it determines them, else ``theta0``, ``sigma`` and
        ``None``."""
        span = float(sequence.timestamps[-1] - sequence.timestamps[0])
        try:
            found = find_start(sequence, span + 1.0, self.options, spatial=self.bending.is_free,
                               robustness=Robustness(self.inlier_sigmas))
        except (RuntimeError, ValueError, IndexError):
            return self.theta0, self.sigma, None
        if not found.determined:
            return self.theta0, self.sigma, None
        spreads = np.asarray(found.sigma0, dtype=float)
        return found.x0.copy(), float(np.nanmax(spreads, initial=MIN_SIGMA)), spreads


def stacked_tracks(cameras: Iterable[int],
                   frames: list[Mapping[int, tuple[NDArray[np.int64], FloatArray]]]
                   ) -> dict[int, Tracks]:
    """Each camera's tracks over ``frames`` (each a mapping camera -> ``(ids, uv)``), the
    ``k``-th frame as frame ``k``; a camera seen in none of them has no entry."""
    tracks = {}
    for cam in cameras:
        rows = [(k, *seen[cam]) for k, seen in enumerate(frames)
                if cam in seen and len(seen[cam][0])]
        if rows:
            tracks[cam] = Tracks(np.concatenate([np.full(len(ids), k) for k, ids, _ in rows]),
                                 np.concatenate([ids for _, ids, _ in rows]),
                                 np.concatenate([uv for _, _, uv in rows]))
    return tracks
