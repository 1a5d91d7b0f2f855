"""Model error as noise in the smoother's window (:class:`NoisyTracks`; ``docs/estimation.md``,
"Model error as noise").

What a frame adds: besides its vector, every segment tip's pose, tied to its base (the previous
tip, or the robot's base) through the segment's APCC transform at the frame's vector with the
segment's model noise (``GraphOptions.model_sigma``, by default the robot file's)
(:func:`~apcc_graph.factors.kinematic.segment_tie_factor`). A new frame's tips start at the
model's tips moved by the previous frame's departure from the model (the model error changes
slowly). What a track's rows become: a point per track and gtsam's C++ projection factors on
the tip poses (:mod:`~apcc_graph.estimation.pose_points`, which also holds the model-free
outlier decisions). How an estimate is read back: the frames' vectors (the core), the tips
and the points (here).
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
from apcc_graph.estimation.pose_points import PosePoints
from apcc_graph.estimation.projection_tracks import Rows
from apcc_graph.estimation.smoother.solver import Additions
from apcc_graph.estimation.smoother_options import SmootherOptions
from apcc_graph.estimation.terms.noisy import forward_tips
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
rows become factors as they arrive, so they are judged before (the batch with model noise
decides its first outliers with the same)."""


class NoisyTracks:
    """Model error as noise: tip poses, ties and points in a smoother's window.

    Args:
        robot, options, settings, bending: the smoother's.
        window: the smoother's window.
        inlier_sigmas: a row that misses its new point by more (pixel-noise units) stays out.
        sigmas: per segment, the ties' noise (position m, rotation rad;
            :func:`~apcc_graph.estimation.model_noise.segment_sigmas`).
    """

    name = "model noise"
    refines = False  # a new frame's guess is not refined against known points
    final_steps = FINAL_STEPS
    default_gate: float | None = GATE
    elimination = staticmethod(elimination_group)  # points, then tips, then frame vectors

    def __init__(self, robot: Robot, options: GraphOptions, settings: SmootherOptions,
                 window: Window, bending: Bending, inlier_sigmas: float,
                 sigmas: tuple[tuple[float, float], ...]) -> None:
        self._ties = ModelTies(bending, sigmas,
                               segment_correlations(options.model_correlation, robot))
        self.bending = bending
        self.n_segments = robot.n_segments
        self.points = PosePoints({c: robot.cameras[c].tip_T_cam  # type: ignore[union-attr]
                                  for c in robot.camera_segments}, settings.window.lag,
                                 inlier_sigmas)
        self._mounts = {c: robot.cameras[c].tip_T_cam[:3, :3]  # type: ignore[union-attr]
                        for c in robot.camera_segments}
        self._tips: dict[int, FloatArray] = {}  # frame -> (S, 4, 4), frames in the window
        self._models: dict[int, FloatArray] = {}  # frame -> the model's tips at its estimate
        self._bases: dict[int, FloatArray] = {}
        self._x: dict[int, FloatArray] = {}  # frame -> its vector's estimate

    @property
    def committed(self) -> int:
        """Observations that became factors so far."""
        return self.points.committed

    @property
    def outliers(self) -> int:
        """Observations left out so far."""
        return self.points.outliers

    def known(self, cam: int, ids: NDArray[np.int64]) -> NDArray[np.bool_]:
        """Which of a camera's track ids the window knows (a point or held rows)."""
        p = self.points
        return np.array([(cam, i) in p.points or (cam, i) in p.held for i in ids.tolist()],
                        dtype=bool)

    def judge(self, frame: int, agreed: Mapping[int, tuple[NDArray[np.int64],
                                                           NDArray[np.bool_]]]) -> None:
        """The rotation gate's judgement of frame ``frame``'s rows by the next frame."""
        for cam, (ids, agree) in agreed.items():
            self.points.judge(frame, cam, ids, agree)

    def make_room(self, add: Additions, f: int, t: float, rows: Rows, leaving: list[int],
                  first_kept: int, commit: bool) -> None:
        """Before frame ``f`` enters: the points of held tracks whose first rows leave."""
        self.points.make(add.graph, add.values, add.stamps, t, self._tips, set(leaving))

    def retire(self, leaving: list[int], first_kept: int) -> None:
        """Frames ``leaving`` left the window."""
        for g in leaving:
            for held in (self._tips, self._models, self._bases, self._x):
                held.pop(g, None)

    def associate(self, rows: Rows) -> None:
        """Rows are associated with their points as they are observed."""
        return None

    def known_rows(self, rows: Rows, marks: None, gates: Mapping[int, FloatArray] | None = None
                   ) -> tuple[list[FrameRows], list[tuple[int, NDArray[np.bool_]]]]:
        """None: a new frame starts at the motion's prediction moved by the two-frame front
        end. (Refined against the points at the last estimate, through the model's camera
        poses, the tips of a 30-frame model-exact replay ended 4.0 / 10.9 mm off instead of
        3.2 / 7.4: the model's poses are not the tips the points were fitted to.)"""
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
        for j in range(self.n_segments):
            add.variable(tip_key(f, j), gtsam.Pose3(tips[j]), t)
        for factor in self._ties.frame(f, x, base, previous):
            add.graph.add(factor)

    def observe(self, add: Additions, f: int, t: float, rows: Rows, marks: None,
                weights: Mapping[int, FloatArray], verdicts: Mapping[int, NDArray[np.int8]],
                accepted: Mapping[int, NDArray[np.int64]]) -> None:
        """Frame ``f``'s rows: a factor each for the tracks with a point, held otherwise
        (the gate's ``verdicts`` decide; ``weights`` and ``accepted`` are the exact model's),
        then the points its rows complete."""
        self.points.observe(add.graph, add.stamps, f, t, rows, verdicts)
        self.points.make(add.graph, add.values, add.stamps, t, self._tips, set())

    def replay(self, add: Additions, h: int, t: float, rows: Rows,
               verdicts: Mapping[int, NDArray[np.int8]], base: FloatArray | None) -> None:
        """A kept frame's rows after a restart (its tips entered by :meth:`enter`)."""
        self.observe(add, h, t, rows, None, {}, verdicts, {})

    def replaceable(self, graph: gtsam.NonlinearFactorGraph) -> list[int]:
        """None: every factor is added once."""
        return []

    def read(self, estimate: gtsam.Values) -> None:
        """After an update: the tips and the model's tips at the new vectors."""
        for g in self._tips:
            if not estimate.exists(frame_key(g)):
                continue
            x = self._x[g] = estimate.atVector(frame_key(g))
            self._tips[g] = np.array([estimate.atPose3(tip_key(g, j)).matrix()
                                      for j in range(self.n_segments)])
            self._models[g] = forward_tips(self.bending, x[None], self._bases[g][None])[0]

    def reset(self, keep: int | None = None, base: FloatArray | None = None) -> None:
        """Forget every point, held row and tip (a new window)."""
        self.points.reset()
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

    def finish(self, add: Additions, t: float) -> None:
        """Make the points of every held track with two kept rows (the end of the stream)."""
        self.points.make(add.graph, add.values, add.stamps, t, self._tips, set(), force=True)
