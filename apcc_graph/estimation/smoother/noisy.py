"""Model error as noise in the smoother's window (:class:`NoisyTracks`; ``docs/estimation.md``,
"Model error as noise").

What a frame adds: besides its vector, every segment tip's pose, tied to its base (the previous
tip, or the robot's base) through the segment's APCC transform at the frame's vector with the
segment's model noise (``GraphOptions.model_sigma``, by default the robot file's)
(:func:`~apcc_graph.factors.kinematic.segment_tie_factor`). A new frame's tips start at the
model's tips moved by the previous frame's departure from the model (the model error changes
slowly). What a track's rows become: rows of projection factors over the cameras' tips, each
track's point eliminated inside its factor, live pieces replaced at every update and committed
pieces for good (:mod:`~apcc_graph.estimation.tip_tracks`,
:mod:`~apcc_graph.estimation.smoother.pieces`); a track that outlives the window is cut (no
landmarks: with their points as variables seen from the tips, the tips of replays of the real
robot were better on one seed and far worse on others); outliers are decided first without the model
(the rotation gate, :data:`GATE`), then against each piece's robust point at the current tips.
How an estimate is read back: the frames' vectors (the core), the tips and the live pieces'
points (here).
"""

from __future__ import annotations

from collections.abc import Mapping

import gtsam
import numpy as np
from numpy.typing import NDArray

from apcc_graph.estimation.initial_guess import FrameRows
from apcc_graph.estimation.model_noise import segment_correlations
from apcc_graph.estimation.model_ties import ModelTies
from apcc_graph.estimation.options import GraphOptions
from apcc_graph.estimation.projection_tracks import Rows
from apcc_graph.estimation.smoother.pieces import Association, PieceWindow
from apcc_graph.estimation.smoother.solver import Additions
from apcc_graph.estimation.smoother_options import SmootherOptions
from apcc_graph.estimation.terms.noisy import forward_tips
from apcc_graph.estimation.tip_tracks import TipTracks
from apcc_graph.estimation.window import Window
from apcc_graph.factors.keys import elimination_group, frame_key, tip_key
from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.parameterisation import Bending
from apcc_graph.model.robot import Robot

FINAL_STEPS = 3
"""Gauss-Newton steps of the whole window at the end of the stream (each update makes one;
the frames still inside have not converged as far as those that left)."""

GATE = 0.02
"""The model-free outlier gate's threshold (radians of bearing) when the settings name none:
the batch with model noise decides its first outliers with the same."""


class NoisyTracks(PieceWindow):
    """Model error as noise: tip poses, ties and track pieces in a smoother's window.

    Args:
        robot, options, settings, bending: the smoother's.
        window: the smoother's window.
        inlier_sigmas: the outlier threshold (whitened residual norm, pixel-noise units).
        sigmas: per segment, the ties' noise (position m, rotation rad;
            :func:`~apcc_graph.estimation.model_noise.segment_sigmas`).
    """

    name = "model noise"
    refines = False  # a new frame's guess is not refined against known points
    final_steps = FINAL_STEPS
    default_gate: float | None = GATE
    elimination = staticmethod(elimination_group)  # tips, then frame vectors
    trust_region = True
    """iSAM2's steps are dogleg steps: the cost is far from quadratic in the tips' positions
    (the batch damps its steps for the same reason), and on the struck stretches of a real
    replay full Gauss-Newton steps left the tips 10.7 / 27.3 and 18.6 / 41.4 mm off where
    dogleg steps left them 6.5 / 17.0 and 12.2 / 27.8 (the batch: 4.9 / 13.2, 11.1 / 25.1;
    docs/estimation.md, "Model error as noise")."""

    def __init__(self, robot: Robot, options: GraphOptions, settings: SmootherOptions,
                 window: Window, bending: Bending, inlier_sigmas: float,
                 sigmas: tuple[tuple[float, float], ...]) -> None:
        self._ties = ModelTies(bending, sigmas,
                               segment_correlations(options.model_correlation, robot))
        self.bending = bending
        self.n_segments = robot.n_segments
        self._tips: dict[int, FloatArray] = {}  # frame -> (S, 4, 4), frames in the window
        self._models: dict[int, FloatArray] = {}  # frame -> the model's tips at its estimate
        self._bases: dict[int, FloatArray] = {}
        self._x: dict[int, FloatArray] = {}  # frame -> its vector's estimate
        tracks = TipTracks(robot, options, settings, window, bending, inlier_sigmas, self._tips)
        super().__init__(settings, tracks, None)  # no landmarks: docs/estimation.md
        self._mounts = {c: T[:3, :3] for c, T in tracks.mounts.items()}

    def retire(self, leaving: list[int], first_kept: int) -> None:
        """Frames ``leaving`` left the window."""
        for g in leaving:
            for held in (self._tips, self._models, self._bases, self._x):
                held.pop(g, None)
        super().retire(leaving, first_kept)

    def known_rows(self, rows: Rows, marks: Association,
                   gates: Mapping[int, FloatArray] | None = None
                   ) -> tuple[list[FrameRows], list[tuple[int, NDArray[np.bool_]]]]:
        """None: a new frame starts at the motion's prediction moved by the cameras'
        rotations. (Refined against the points at the last estimate, through the model's
        camera poses, the tips of a 30-frame model-exact replay ended 4.0 / 10.9 mm off instead
        of 3.2 / 7.4: the model's poses are not the tips the points were fitted to.)"""
        return [], []

    def enter(self, add: Additions, f: int, t: float, x: FloatArray,
              base: FloatArray | None) -> None:
        """Frame ``f``'s tip poses (module docstring: their start) and their ties (each a
        transition from frame ``f - 1``, when it is in the window, where the model error
        drifts: :mod:`~apcc_graph.estimation.model_ties`)."""
        base = np.eye(4) if base is None else np.asarray(base, dtype=float)
        model = forward_tips(self.bending, x[None], base[None])[0]
        tips = model.copy()
        if f - 1 in self._tips:  # the previous frame's departure from the model
            tips = model @ np.linalg.inv(self._models[f - 1]) @ self._tips[f - 1]
        previous = (f - 1, self._x[f - 1], self._bases[f - 1]) if f - 1 in self._x else None
        self._tips[f], self._models[f], self._bases[f] = tips, model, base
        self._x[f] = np.array(x, dtype=float)
        self.tracks.bases[f] = base
        for j in range(self.n_segments):
            add.variable(tip_key(f, j), gtsam.Pose3(tips[j]), t)
        for factor in self._ties.frame(f, x, base, previous):
            add.graph.add(factor)

    def read(self, estimate: gtsam.Values) -> None:
        """After an update: the tips, the model's tips at the new vectors, and the live
        factors' points."""
        for g in self._tips:
            if not estimate.exists(frame_key(g)):
                continue
            x = self._x[g] = estimate.atVector(frame_key(g))
            self._tips[g] = np.array([estimate.atPose3(tip_key(g, j)).matrix()
                                      for j in range(self.n_segments)])
            self._models[g] = forward_tips(self.bending, x[None], self._bases[g][None])[0]
        super().read(estimate)

    def reset(self, keep: int | None = None, base: FloatArray | None = None) -> None:
        """Forget every piece and tip (a new window); the rows of frame ``keep``
        (the one it holds) start new pieces."""
        super().reset(keep, base)
        for held in (self._tips, self._models, self._bases, self._x):
            held.clear()

    def restart_frame(self, add: Additions, f: int, t: float, x: FloatArray,
                      base: FloatArray | None) -> None:
        """A restarted window's frame ``f`` at ``x``: its tips and ties."""
        self.enter(add, f, t, x, base)

    def base(self, g: int) -> FloatArray | None:
        """Frame ``g``'s base pose, for frames in the window."""
        return self._bases.get(g)

    def camera_rotations(self, g: int) -> dict[int, FloatArray]:
        """Camera -> ``world_R_cam`` of frame ``g`` from its estimated tip poses (the model's
        departure included); empty for a frame not in the window."""
        tips = self._tips.get(g)
        if tips is None:
            return {}
        return {c: tips[c][:3, :3] @ mount for c, mount in self._mounts.items()}
