"""The epipolar smoother's first-estimate factors: which are in gtsam, and swapping them.

With ``linearization="first-estimate"`` each epipolar factor enters gtsam linearised, as a C++
``LinearContainerFactor``, at the angles it was built at; gtsam never calls back into Python.
Two refinements swap such a factor for one re-gated and re-linearised at a newer estimate
(iSAM2 backend only, by its factor index):

- the iterated update (``iterations``): while an update moves the new frame's angles by more
  than ``iterate_threshold``, its factors are rebuilt at the new estimate;
- rebuilding (``rebuilds_per_frame``): factors whose variables have since moved more than
  ``rebuild_threshold`` are rebuilt at the current estimate, largest move first.

:class:`FirstEstimateFactors` keeps the bookkeeping this needs (where gtsam put each factor and
where it was linearised); the smoother runs the updates.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import gtsam
import numpy as np
from numpy.typing import NDArray

from apcc_graph.estimation.epipolar_front_end import (
    EpipolarFrontEnd,
    FramePair,
    Measured,
    StoredFrame,
)
from apcc_graph.estimation.smoother_options import EpipolarSmootherOptions
from apcc_graph.estimation.window import Window
from apcc_graph.model.arrays import FloatArray


@dataclass
class ActiveFactor:
    """A first-estimate epipolar factor in gtsam, kept so it can be rebuilt where it was built.

    Attributes:
        frame: its newest frame b.
        camera: its camera.
        newest: frame b's observations.
        pairs: its pairs, before gating.
        frames: ``(P + 1,)`` frames a_0 .. a_P-1, b.
        point: ``(P + 1, camera + 1)`` the angles it was linearised at.
        index: gtsam's factor index.
    """

    frame: int
    camera: int
    newest: StoredFrame
    pairs: list[FramePair]
    frames: NDArray[np.int64]
    point: FloatArray
    index: int = -1


class Fresh(NamedTuple):
    """A new frame's first-estimate factor: its position in the update's graph."""

    position: int
    camera: int
    pairs: list[FramePair]


class Live(NamedTuple):
    """A new frame's factor during the iterated update: gtsam's index, its pairs, and the new
    frame's angles it was linearised at."""

    index: int
    pairs: list[FramePair]
    at: FloatArray


class FirstEstimateFactors:
    """Where the epipolar smoother's first-estimate factors are, and their rebuilt versions.

    Args:
        settings: the smoother's options (linearisation, iterations, rebuilding).
        front: the front end that builds and linearises factors.
        window: the smoother's window (estimates, stamps, gtsam's smoother).
    """

    def __init__(self, settings: EpipolarSmootherOptions, front: EpipolarFrontEnd,
                 window: Window) -> None:
        self.settings = settings
        self.front = front
        self.window = window
        self.active: dict[tuple[int, int], ActiveFactor] = {}
        self.pending: list[tuple[int, ActiveFactor]] = []  # (position in the new graph, entry)
        self.fresh: list[Fresh] = []
        self.rebuilds = 0

    @property
    def incremental(self) -> bool:
        """Whether gtsam's smoother is iSAM2 (factor indices to swap by)."""
        return self.settings.backend == "incremental"

    def add(self, graph: gtsam.NonlinearFactorGraph, measured: list[Measured],
            frame: StoredFrame, thetas: FloatArray) -> None:
        """Add the new frame's factors to ``graph``, linearised at ``thetas`` (first-estimate)
        or as Python factors (``linearization="relinearize"``)."""
        s = self.settings
        f = frame.index
        for i, pairs, factor in measured:
            if s.linearization != "first-estimate":
                graph.add(factor.factor)
                continue
            self.fresh.append(Fresh(graph.size(), i, pairs))
            if s.rebuilds_per_frame > 0:
                self.pending.append((graph.size(), ActiveFactor(
                    f, i, frame, pairs, np.array([p.earlier.index for p in pairs] + [f]),
                    np.array([self.window.thetas[p.earlier.index][: i + 1] for p in pairs]
                             + [thetas[: i + 1]]))))
            graph.add(factor.linear_factor(self.front.linearization_point(factor, f, thetas)))

    def take_fresh(self) -> list[Fresh]:
        """The new frame's factors, and forget them."""
        fresh, self.fresh = self.fresh, []
        return fresh

    def take_pending(self) -> list[tuple[int, ActiveFactor]]:
        """The factors of the coming update to register, and forget them."""
        pending, self.pending = self.pending, []
        return pending

    def register(self, pending: list[tuple[int, ActiveFactor]]) -> None:
        """Remember where gtsam put the new first-estimate factors (iSAM2 backend only)."""
        if not self.incremental or not pending:
            return
        indices = self.window.smoother.getISAM2Result().getNewFactorsIndices()
        for position, entry in pending:
            entry.index = int(indices[position])
            self.active[(entry.frame, entry.camera)] = entry

    def forget(self, gone: set[int]) -> None:
        """Factors on frames absorbed into the marginal can no longer be swapped."""
        for key in [k for k, e in self.active.items() if gone.intersection(e.frames.tolist())]:
            del self.active[key]

    # -------------------------------------------------------------------------- rebuild
    def rebuilding(self) -> bool:
        """Whether this update rebuilds moved factors."""
        s = self.settings
        return (s.linearization == "first-estimate" and self.incremental
                and s.rebuilds_per_frame > 0 and bool(self.active))

    def rebuild_moved(self, graph: gtsam.NonlinearFactorGraph, stamp: float) -> list[int]:
        """Rebuild the factors whose variables moved most since they were linearised (the
        window's estimates must be fresh).

        Only factors whose frames all stay in the window through this update qualify. The
        rebuilt factors are added to ``graph``; returns the gtsam indices to remove.
        """
        s = self.settings
        window = self.window
        moved = []
        for key, entry in list(self.active.items()):
            if any(g not in window.stamps or window.stamps[g] < stamp - s.lag
                   for g in entry.frames):
                del self.active[key]  # about to be (or already) marginalised
                continue
            now = np.array([window.thetas[g][: entry.camera + 1] for g in entry.frames])
            change = float(np.max(np.abs(now - entry.point)))
            if change > s.rebuild_threshold:
                moved.append((change, key))
        remove = []
        for _, key in sorted(moved, reverse=True)[: s.rebuilds_per_frame]:
            entry = self.active.pop(key)
            b = entry.frame
            thetas = window.thetas[b].copy()
            factor = self.front.factor(entry.camera, entry.newest, entry.pairs, thetas)
            if factor is None or not factor.mask.any():
                continue
            remove.append(entry.index)
            self.pending.append((graph.size(), ActiveFactor(
                b, entry.camera, entry.newest, entry.pairs, entry.frames,
                np.array([window.thetas[g][: entry.camera + 1] for g in entry.frames]))))
            graph.add(factor.linear_factor(self.front.linearization_point(factor, b, thetas)))
            self.rebuilds += 1
        return remove

    # ------------------------------------------------------------------ iterated update
    def live(self, fresh: list[Fresh], point: FloatArray) -> dict[int, Live]:
        """camera -> the new frame's factor as gtsam holds it after the update."""
        indices = self.window.smoother.getISAM2Result().getNewFactorsIndices()
        return {i: Live(int(indices[pos]), pairs, point.copy()) for pos, i, pairs in fresh}

    @staticmethod
    def needed(f: int, live: dict[int, Live]) -> set[int]:
        """The frames whose estimates re-linearising the live factors reads."""
        return {f} | {p.earlier.index for entry in live.values() for p in entry.pairs}

    def relinearized(self, frame: StoredFrame, live: dict[int, Live], now: FloatArray
                     ) -> tuple[gtsam.NonlinearFactorGraph, list[int], list[tuple[int, int]]]:
        """The live factors re-linearised at ``now``, the new frame's angles: the graph, the
        gtsam indices they replace, and ``(position, camera)`` of each.

        Camera i's factor depends on the angles of segments 0..i, so it is rebuilt only when
        those moved more than ``iterate_threshold`` since it was linearised."""
        f = frame.index
        graph = gtsam.NonlinearFactorGraph()
        remove, positions = [], []
        for i, (index, pairs, at) in live.items():
            change = float(np.max(np.abs(now[: i + 1] - at[: i + 1])))
            if change <= self.settings.iterate_threshold:
                continue
            factor = self.front.factor(i, frame, pairs, now)
            if factor is None or not factor.mask.any():
                continue  # keep the factor linearised where it was
            remove.append(index)
            positions.append((graph.size(), i))
            graph.add(factor.linear_factor(self.front.linearization_point(factor, f, now)))
        return graph, remove, positions

    def swapped(self, f: int, live: dict[int, Live], positions: list[tuple[int, int]],
                now: FloatArray) -> None:
        """Record where gtsam put the re-linearised factors; the rebuild bookkeeping follows."""
        new_indices = self.window.smoother.getISAM2Result().getNewFactorsIndices()
        thetas = self.window.thetas
        for position, i in positions:
            live[i] = Live(int(new_indices[position]), live[i].pairs, now)
            entry = self.active.get((f, i))
            if entry is not None:
                entry.index = live[i].index
                entry.point = np.array([thetas[g][: i + 1] for g in entry.frames[:-1]]
                                       + [now[: i + 1]])
