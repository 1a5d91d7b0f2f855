"""Model error as noise in the smoother's window (:class:`NoisyTracks`; ``docs/estimation.md``,
"Model error as noise").

What a frame adds: besides its vector, every segment tip's pose, tied to its base (the previous
tip, or the robot's base) through the segment's APCC transform at the frame's vector with the
segment's model noise (``GraphOptions.model_sigma``, by default the robot file's)
(:func:`~apcc_graph.factors.kinematic.segment_tie_factor`). A new frame's tips start at the
model's tips moved by the previous frame's departure from the model (the model error changes
slowly). What a track's rows become: rows of projection factors over the cameras' tips, each
track's point eliminated inside its factor, live pieces replaced at every update and committed
pieces for good (:mod:`~apcc_graph.estimation.tip_tracks`); outliers are decided first without
the model (the rotation gate, :data:`GATE`), then against each piece's robust point at the
current tips. How an estimate is read back: the frames' vectors (the core), the tips and the
live pieces' points (here).
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
from apcc_graph.estimation.projection_tracks import LiveFactor, Rows
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


class NoisyTracks:
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
        self.tracks = TipTracks(robot, options, settings, window, bending, inlier_sigmas,
                                self._tips)
        self._mounts = {c: T[:3, :3] for c, T in self.tracks.mounts.items()}
        self._live: list[LiveFactor] = []
        self._full_window: int | None = None  # frames in a full window, once one left

    @property
    def committed(self) -> int:
        """Observations committed into the graph so far (each exactly once)."""
        return self.tracks.committed

    @property
    def outliers(self) -> int:
        """Committed observations judged outliers so far."""
        return self.tracks.outliers

    def known(self, cam: int, ids: NDArray[np.int64]) -> NDArray[np.bool_]:
        """Which of a camera's track ids the window knows (live tracks)."""
        return self.tracks.live.piece_ids(cam, ids) >= 0

    def judge(self, frame: int, agreed: Mapping[int, tuple[NDArray[np.int64],
                                                           NDArray[np.bool_]]]) -> None:
        """The rotation gate's judgement of frame ``frame``'s rows by the next frame."""
        for cam, (ids, agree) in agreed.items():
            self.tracks.live.judge(frame, cam, ids, agree)

    def make_room(self, add: Additions, f: int, t: float, rows: Rows, leaving: list[int],
                  first_kept: int, commit: bool) -> None:
        """Before frame ``f`` enters: the pieces that are due are committed (before their
        first frames leave; ``commit``: those whose tracks ended too)."""
        seen = {c: ids for c, (ids, _, _) in rows.items()}
        if leaving:  # the window is full: its length in frames, for the staggered cuts
            self._full_window = f - first_kept
        for cam, obs in self.tracks.live.take_due(f, seen, first_kept, commit,
                                                  window=self._full_window).items():
            self.tracks.commit(add.graph, cam, obs)

    def retire(self, leaving: list[int], first_kept: int) -> None:
        """Frames ``leaving`` left the window."""
        for g in leaving:
            for held in (self._tips, self._models, self._bases, self._x):
                held.pop(g, None)
        self.tracks.live.drop_frames_before(first_kept)

    def associate(self, rows: Rows) -> None:
        """Rows are associated with their pieces as they are observed."""
        return None

    def known_rows(self, rows: Rows, marks: None, gates: Mapping[int, FloatArray] | None = None
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

    def observe(self, add: Additions, f: int, t: float, rows: Rows, marks: None,
                weights: Mapping[int, FloatArray], verdicts: Mapping[int, NDArray[np.int8]],
                accepted: Mapping[int, NDArray[np.int64]]) -> None:
        """Frame ``f``'s rows into their live pieces, with the gate's verdicts (which the next
        frame may still change); ``weights`` and ``accepted`` are the exact model's."""
        for cam, (ids, xy, whiten) in rows.items():
            self.tracks.live.add(f, cam, ids, xy, whiten, None, verdicts[cam])

    def replay(self, add: Additions, h: int, t: float, rows: Rows,
               verdicts: Mapping[int, NDArray[np.int8]], base: FloatArray | None) -> None:
        """A kept frame's rows after a restart (its tips entered by :meth:`enter`)."""
        self.observe(add, h, t, rows, None, {}, verdicts, {})

    def replaceable(self, graph: gtsam.NonlinearFactorGraph) -> list[int]:
        """The live projection factors, added to ``graph``; their positions there (the
        solver replaces them at the next update)."""
        self._live = self.tracks.live_factors(graph)
        return [pos for pos, *_ in self._live]

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
        self.tracks.keep_points(self._live)

    def reset(self, keep: int | None = None, base: FloatArray | None = None) -> None:
        """Forget every piece and tip (a new window); the rows of frame ``keep`` (the one it
        holds) start new pieces."""
        self.tracks.reset(keep=keep)
        self.tracks.bases = {}
        for held in (self._tips, self._models, self._bases, self._x):
            held.clear()
        self._live = []

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
        """Commit every live piece (the end of the stream)."""
        for cam, obs in self.tracks.live.take_all().items():
            self.tracks.commit(add.graph, cam, obs)
        self._live = []
