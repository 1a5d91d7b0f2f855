"""The epipolar smoother's window in gtsam: one ``Vector1`` per frame and segment.

:class:`EpipolarWindow` is the shared :class:`~apcc_graph.estimation.window.Window` plus what its
variables' layout needs: angle ``theta[f, i]`` has key ``f * S + i``
(:func:`~apcc_graph.estimation.epipolar_graph.angle_key`), so a frame's estimate, its marginal
sigmas and its final record are read segment by segment.
"""

from __future__ import annotations

import math
from collections.abc import Iterable

import numpy as np

from apcc_graph.estimation.epipolar_graph import angle_key
from apcc_graph.estimation.smoother_options import EpipolarSmootherOptions
from apcc_graph.estimation.window import Window, new_gtsam_smoother
from apcc_graph.model.arrays import FloatArray


class EpipolarWindow(Window):
    """The epipolar smoother's window (see the module docstring).

    Args:
        settings: the smoother's options (lag, backend, iSAM2's re-linearisation,
            ``uncertainty``).
        n_segments: angles per frame.
    """

    def __init__(self, settings: EpipolarSmootherOptions, n_segments: int) -> None:
        s = settings
        super().__init__(s.lag, n_segments, lambda: new_gtsam_smoother(
            s.lag, s.relinearize_threshold, s.relinearize_skip, s.backend))
        self.settings = settings

    def keys(self, frame: int) -> list[int]:
        """The keys of a frame's angles."""
        return [angle_key(frame, i, self.n_segments) for i in range(self.n_segments)]

    def read(self, wanted: Iterable[int]) -> list[int]:
        """Refresh the latest estimates of the ``wanted`` frames that are inside the window
        (or are the frame being added); the frames read, in order."""
        f = self.count
        done = []
        for g in sorted(wanted):
            if g < 0 or (g not in self.stamps and g != f):
                continue
            try:
                self.thetas[g] = np.array([self.smoother.calculateEstimateVector(key)[0]
                                           for key in self.keys(g)])
            except (RuntimeError, IndexError, KeyError):
                continue  # already marginalised
            done.append(g)
        return done

    def sigmas(self, g: int) -> FloatArray:
        """Frame g's marginal standard deviations (NaN without uncertainty, with the batch
        backend, or where gtsam cannot say)."""
        out = np.full(self.n_segments, np.nan)
        if not self.settings.uncertainty or self.settings.backend == "batch":
            return out  # BatchFixedLagSmoother has no marginalCovariance
        for i, key in enumerate(self.keys(g)):
            try:
                cov = self.smoother.marginalCovariance(key)
                out[i] = math.sqrt(max(float(cov[0, 0]), 0.0))
            except (RuntimeError, IndexError, ValueError):
                pass  # not in gtsam's Bayes tree (an unconstrained variable): unknown, NaN
        return out

    def retire(self, stamp: float) -> list[int]:
        """Frames that the coming update (at gtsam timestamp ``stamp``) marginalises leave
        with their current estimate and sigmas; returns them."""
        leaving = self.leaving(stamp)
        if not leaving:
            return []
        estimate = self.smoother.calculateEstimate()
        for g in leaving:
            thetas = np.array([estimate.atVector(key)[0] for key in self.keys(g)])
            self.leave(g, thetas, self.sigmas(g))
        return leaving
