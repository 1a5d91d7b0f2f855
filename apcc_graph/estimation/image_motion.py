"""How much the images moved: the coherent flow of tracks between two frames, and a clock that
ticks with it.

For the ``n`` tracks a camera sees in two frames, the whitened displacements
``d = W (x_b - x_a)`` (``W`` the whitening of one observation). Motion of the camera moves its
points together, noise does not: the coordinates' medians ``m`` over the tracks, against their
spread ``s`` (1.4826 times the median absolute deviation, robust to outliers), give
``n |m / s|^2 / (pi / 2)``, about chi-square with 2 degrees of freedom when nothing moved (the
median of ``n`` normal samples has variance ``(pi / 2) s^2 / n``); the median ``|d|^2`` over
that of noise alone (about 1 then) catches a roll about the optical axis, which moves the points
without a common shift (:func:`flow_statistics`).

:func:`motion_clock` turns that into a per-frame clock for cutting tracks into pieces
(:func:`apcc_graph.factors.track_points.cut_tracks`): a frame in which some camera's images
moved since the last frame that moved ticks 1, a still frame ticks :data:`STILL_TICK`. A track
is cut for the cost of its factor (whose dense block grows with the square of the frames it
spans), but a piece that spans only still frames sees no parallax and tells its frames nothing;
on the clock, a piece born while the robot stands still lasts until the robot has moved.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np
from numpy.typing import NDArray

from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.sequence import Sequence

FrameRows = Mapping[int, tuple[NDArray[np.int64], FloatArray, FloatArray]]
"""camera -> (track ids, normalised image points ``(n, 2)``, whitening ``(n, 2, 2)``) of one
frame."""

STILL_TICK = 0.25
"""What a still frame adds to :func:`motion_clock` (a moving frame adds 1): a piece of track spans
at most four times its frames while the robot stands still."""

CHI2 = 18.4
"""A camera is still while its coherent-flow chi-square stays below this (a 1e-4 false alarm)."""

MAD_TO_SIGMA = 1.4826
"""Median absolute deviation to standard deviation, for normal samples."""

CHI2_2_MEDIAN = 2.0 * math.log(2.0)
"""Median of the chi-square distribution with 2 degrees of freedom."""

SPREAD_LIMIT = 4.0
"""A camera moved if its median squared displacement is this many times that of noise alone."""


def flow_statistics(anchor: FrameRows, rows: FrameRows, min_tracks: int = 8
                    ) -> dict[int, tuple[float, float]]:
    """Per camera with at least ``min_tracks`` tracks in both frames: the coherent-flow
    chi-square (about chi-square with 2 degrees of freedom when nothing moved) and the median
    squared displacement over that of noise alone (about 1 then); see the module docstring."""
    out = {}
    for cam, (ids, xy, whiten) in rows.items():
        if cam not in anchor:
            continue
        ids0, xy0, _ = anchor[cam]
        common, i0, i1 = np.intersect1d(ids0, ids, assume_unique=True, return_indices=True)
        n = len(common)
        if n < min_tracks:
            continue
        d = np.einsum("nij,nj->ni", whiten[i1], xy[i1] - xy0[i0])  # noise: N(0, 2 I)
        median = np.median(d, axis=0)
        scale = MAD_TO_SIGMA * np.median(np.abs(d - median), axis=0)  # per coordinate
        # the median of n normal samples has variance (pi / 2) sigma^2 / n
        coherent = float(np.sum(n * (median / np.maximum(scale, 1e-12)) ** 2) / (math.pi / 2))
        spread = float(np.median(np.sum(d * d, axis=1)) / 2.0 / CHI2_2_MEDIAN)
        out[cam] = (coherent, spread)
    return out


def sequence_rows(sequence: Sequence, noise_px: float) -> list[FrameRows]:
    """Every frame's :data:`FrameRows` of ``sequence`` (pixel noise ``noise_px``)."""
    out: list[dict[int, tuple[NDArray[np.int64], FloatArray, FloatArray]]] = [
        {} for _ in range(sequence.n_frames)]
    for cam, tracks in sequence.tracks.items():
        camera = sequence.robot.cameras[cam]
        if camera is None or len(tracks) == 0:
            continue
        bearings = sequence.bearings(cam)
        xy = bearings[:, :2] / bearings[:, 2:3]
        whiten = camera.pixel_jacobian(xy) / noise_px
        order = np.argsort(tracks.frames, kind="stable")
        frames = tracks.frames[order]
        cuts = np.searchsorted(frames, np.arange(sequence.n_frames + 1))
        for f in np.flatnonzero(np.diff(cuts)).tolist():
            rows = order[cuts[f]:cuts[f + 1]]
            out[f][cam] = (tracks.track_ids[rows], xy[rows], whiten[rows])
    return out


def motion_clock(sequence: Sequence, noise_px: float, min_tracks: int = 8,
                 still_tick: float = STILL_TICK) -> FloatArray:
    """``(F,)`` a clock that ticks 1 with each frame whose images moved and ``still_tick`` with
    each still one (module docstring), 0 at frame 0.

    A frame is still when, against the anchor (the last frame that moved), every camera with at
    least ``min_tracks`` tracks in common shows a coherent-flow chi-square below :data:`CHI2`
    and a spread below :data:`SPREAD_LIMIT`, at least one camera has that many, and the robot's
    base did not move.
    """
    rows = sequence_rows(sequence, noise_px)
    bases = sequence.world_T_base
    clock = np.zeros(sequence.n_frames)
    anchor = 0
    for f in range(1, sequence.n_frames):
        flows = flow_statistics(rows[anchor], rows[f], min_tracks).values()
        still = (bool(flows) and all(c < CHI2 and s < SPREAD_LIMIT for c, s in flows)
                 and (bases is None or np.array_equal(bases[f], bases[anchor])))
        clock[f] = clock[f - 1] + (still_tick if still else 1.0)
        anchor = anchor if still else f
    return clock
