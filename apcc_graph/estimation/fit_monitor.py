"""The residual test of a stream, block by block: does the model explain the images the
fixed-lag smoother has finished with?

:func:`apcc_graph.estimate` tests a whole recording once it is estimated
(:mod:`~apcc_graph.estimation.model_fit`). A live smoother never has the whole recording, so
:class:`FitMonitor` keeps each incoming frame's observations until the smoother hands out that
frame's final estimate (``pop_final``, ``finish``), and tests every block of
``SmootherOptions.faults.misfit_seconds`` of final frames as a short recording of its own: each
camera's observations the images alone accept, against the model's camera poses at the final
estimates (tracks are cut at the block's edges). A failing block gets a
:class:`~apcc_graph.estimation.model_fit.ModelFitWarning` naming its frames and times, once per
episode (the next failing block after a passing one warns again); every block's test stays in
:attr:`FitMonitor.blocks`.
"""

from __future__ import annotations

import warnings
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from apcc_graph.estimation.model_fit import ModelFit, ModelFitWarning, check_model_fit
from apcc_graph.estimation.options import GraphOptions
from apcc_graph.estimation.window import SmootherFrame
from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.parameterisation import Bending
from apcc_graph.model.robot import Robot
from apcc_graph.model.sequence import FrameObservations, Sequence, Tracks

MIN_BLOCK_FRAMES = 3
"""A block (the last one, at ``finish``) of fewer frames is not tested."""


@dataclass(frozen=True)
class BlockFit:
    """The residual test of one block of final frames.

    Attributes:
        first, last: the block's first and last frame (the stream's frame indices).
        start, end: their timestamps (seconds).
        fit: the test (:class:`~apcc_graph.estimation.model_fit.ModelFit`).
    """

    first: int
    last: int
    start: float
    end: float
    fit: ModelFit


class FitMonitor:
    """Block-by-block residual test of a smoother's final frames (module docstring).

    Args:
        robot: the robot.
        bending: the smoother's parameterisation (its frames' vectors).
        options: the tracks as the graph builds them (pixel noise, shortest tracks).
        inlier_sigmas: the rejection threshold (whitened pixel-noise units).
        alarm: the share of model-free inliers the model may reject.
        seconds: a block's length.
    """

    def __init__(self, robot: Robot, bending: Bending, options: GraphOptions,
                 inlier_sigmas: float, alarm: float, seconds: float) -> None:
        self.robot, self.bending, self.options = robot, bending, options
        self.inlier_sigmas, self.alarm, self.seconds = inlier_sigmas, alarm, seconds
        self.blocks: list[BlockFit] = []
        self._observations: dict[int, FrameObservations] = {}
        self._final: dict[int, tuple[float, FloatArray]] = {}
        self._failing = False

    def observe(self, frame: int, observations: FrameObservations) -> None:
        """Keep frame ``frame``'s observations until its final estimate arrives."""
        self._observations[frame] = observations

    def final(self, frames: Iterable[SmootherFrame]) -> None:
        """Final estimates (as a smoother hands them out); tests every block they complete."""
        for fr in frames:
            if fr.frame in self._observations:
                x = self.bending.vector(fr.thetas, fr.psis)
                self._final[fr.frame] = (fr.timestamp, np.asarray(x, dtype=float))
        while self._final:
            order = sorted(self._final)
            start = self._final[order[0]][0]
            block = [f for f in order if self._final[f][0] < start + self.seconds]
            if len(block) == len(order):
                return  # the block is not complete yet
            self._test(block)

    def flush(self) -> None:
        """Test what is left (the stream ended)."""
        if self._final:
            self._test(sorted(self._final))

    def _test(self, block: list[int]) -> None:
        """Test the block's frames and forget them."""
        times = [self._final[f][0] for f in block]
        x = np.array([self._final[f][1] for f in block])
        observed = [self._observations.pop(f) for f in block]
        for f in block:
            del self._final[f]
        for f in [g for g in self._observations if g < block[-1]]:
            del self._observations[f]  # frames the smoother never finalised
        if len(block) < MIN_BLOCK_FRAMES:
            return
        fit = check_model_fit(self._sequence(times, observed), x, self.bending, self.options,
                              self.inlier_sigmas, self.alarm, warn=False)
        self.blocks.append(BlockFit(block[0], block[-1], times[0], times[-1], fit))
        if not fit.explained and not self._failing:
            warnings.warn(f"frames {block[0]}-{block[-1]} ({times[0]:.2f}-{times[-1]:.2f} s): "
                          + fit.message(), ModelFitWarning, stacklevel=4)
        self._failing = not fit.explained

    def _sequence(self, times: list[float], observed: list[FrameObservations]) -> Sequence:
        """The block as a recording of its own (frames numbered from 0)."""
        tracks: dict[int, tuple[list, list, list]] = {}
        for k, obs in enumerate(observed):
            for cam, (ids, uv) in obs.tracks.items():
                entry = tracks.setdefault(cam, ([], [], []))
                entry[0].append(np.full(len(ids), k, dtype=np.int64))
                entry[1].append(np.asarray(ids, dtype=np.int64))
                entry[2].append(np.asarray(uv, dtype=float).reshape(-1, 2))
        made = {cam: Tracks(np.concatenate(f), np.concatenate(i), np.concatenate(u))
                for cam, (f, i, u) in tracks.items()}
        bases = [o.world_T_base for o in observed]
        base = None if all(b is None for b in bases) else np.array(
            [np.eye(4) if b is None else b for b in bases])
        return Sequence(self.robot, np.asarray(times), made, base)

    @property
    def latest(self) -> BlockFit | None:
        """The last block tested (``None`` before the first)."""
        return self.blocks[-1] if self.blocks else None
