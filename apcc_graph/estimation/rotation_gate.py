"""The smoother's model-free outlier gate: each observation judged against its neighbours in time.

Residual decisions (an observation's whitened residual against its track's point, at the
current estimates) are only as good as the estimates: after a pause or a blackout the smoother
restarts a few degrees off, its residual test then accepts wrong associations that happen to
agree with the wrong estimate and rejects true ones, and the estimate walks further off
(``docs/estimation.md``, "Outliers without the model"). The gate here does not look at the
estimate. Between two consecutive frames one camera's bearings of the points both frames see
are related by one rotation up to a small parallax (:func:`~apcc_graph.frontend.rotation_pairs.
relative_rotation`); an observation that agrees with the frame before or the frame after is
vouched for, one that a neighbour could judge and neither agreed with is an outlier, whatever
the residuals say. An observation no neighbour could judge (the only one of its track, or a
frame pair with too few common tracks) is left to the residual test.

Each observation's verdict is an ``int8``: ``-1`` not judged yet, ``0`` judged and disagreed,
``1`` agreed with a neighbour. A later judgement ``j`` (0 or 1) combines as ``max(verdict, j)``:
an observation that disagreed with the frame before is lifted by agreeing with the frame after,
one that agreed stays vouched for. The gate weight is ``verdict != 0``, multiplied into the
residual decisions; nothing lifts a gate of 0 except a neighbour's agreement.

The newest frame's verdicts are provisional (the frame after is not seen yet): the smoother's
live factor uses them and corrects them one frame later; a piece is committed only after its
last frame's neighbour was seen, or its track ended.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from apcc_graph.frontend.rotation_pairs import draw_pairs, relative_rotation
from apcc_graph.model.arrays import FloatArray, IntArray


class Judged(Protocol):
    """What keeps the earlier frame's rows (:class:`~apcc_graph.estimation.live_tracks.
    LiveTracks`)."""

    def judge(self, frame: int, cam: int, ids: IntArray, agree: NDArray[np.bool_]) -> None:
        """Combine a neighbour's judgement into the verdicts of ``frame``'s rows of ``ids``."""

NOT_JUDGED = -1
"""The verdict of an observation no neighbour has judged."""


def bearings(xy: FloatArray) -> FloatArray:
    """``(n, 3)`` unit bearings of ``(n, 2)`` normalised image coordinates."""
    b = np.column_stack([xy, np.ones(len(xy))])
    return b / np.linalg.norm(b, axis=1, keepdims=True)


def judge_pair(before_ids: IntArray, before_xy: FloatArray, ids: IntArray, xy: FloatArray,
               threshold: float, seed: tuple[int, ...], iterations: int = 64
               ) -> tuple[IntArray, IntArray, NDArray[np.bool_]] | None:
    """One camera's verdicts between two consecutive frames.

    Args:
        before_ids, before_xy: the earlier frame's track ids and ``(n, 2)`` normalised points.
        ids, xy: the later frame's.
        threshold: agreement with the rotation (radians of bearing).
        seed: the RANSAC's seed (the same frames give the same verdicts).
        iterations: hypotheses drawn.

    Returns:
        ``None`` when the frames share fewer than 3 tracks or no rotation is found (nothing is
        judged); otherwise the rows of the common tracks in the earlier frame, in the later
        frame, and whether each pair agrees with the rotation.
    """
    common, i_before, i_now = np.intersect1d(before_ids, ids, assume_unique=True,
                                             return_indices=True)
    if len(common) < 3:
        return None
    pick = draw_pairs(np.array([len(common)]), np.random.default_rng(seed), iterations)[0]
    R, agree = relative_rotation(bearings(before_xy[i_before]), bearings(xy[i_now]), threshold,
                                 pick=pick)
    if R is None:
        return None
    return i_before.astype(np.int64), i_now.astype(np.int64), agree


def combine(verdicts: NDArray[np.int8], judged: NDArray[np.bool_]) -> NDArray[np.int8]:
    """Verdicts after a new judgement ``judged`` (module docstring: ``max``)."""
    return np.maximum(verdicts, judged.astype(np.int8))


def gate_weights(verdicts: NDArray[np.int8]) -> FloatArray:
    """The gate's weights: 0 for an observation judged an outlier by every neighbour that could
    judge it, 1 otherwise."""
    return (np.asarray(verdicts) != 0).astype(float)


def judge_frame(f: int, rows: Mapping[int, tuple[IntArray, FloatArray, FloatArray]],
                before: Mapping[int, tuple[IntArray, FloatArray, FloatArray]],
                threshold: float | None
                ) -> tuple[dict[int, NDArray[np.int8]], dict[int, tuple[IntArray,
                                                                       NDArray[np.bool_]]]]:
    """The gate between frames ``f - 1`` and ``f`` of a streaming estimator.

    Args:
        f: the new frame.
        rows, before: camera -> (track ids, normalised points, whitening) of frame ``f`` and
            of frame ``f - 1`` (empty when there is none).
        threshold: the gate's threshold (radians of bearing); ``None``: the gate is off.

    Returns:
        camera -> the verdicts of frame ``f``'s rows (:data:`NOT_JUDGED` where no pair could
        judge them, or everywhere when the gate is off); and camera -> (track ids of frame
        ``f - 1``, whether frame ``f`` agrees with each), the judgement of the earlier frame's
        rows, for whoever holds them (:class:`Judged`).
    """
    out = {cam: np.full(len(ids), NOT_JUDGED, dtype=np.int8) for cam, (ids, _, _) in rows.items()}
    agreed: dict[int, tuple[IntArray, NDArray[np.bool_]]] = {}
    if threshold is None:
        return out, agreed
    for cam, (ids, xy, _) in rows.items():
        earlier = before.get(cam)
        found = (None if earlier is None
                 else judge_pair(earlier[0], earlier[1], ids, xy, threshold, (f, cam)))
        if found is not None:
            i_before, i_now, agree = found
            out[cam][i_now] = agree
            agreed[cam] = (earlier[0][i_before], agree)
    return out, agreed
