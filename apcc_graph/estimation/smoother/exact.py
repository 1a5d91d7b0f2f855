"""The exact model in the smoother's window: every observation projected through the model's
camera poses, each track's point eliminated (:class:`ExactTracks`).

What a frame adds: its vector alone (the core adds it). What a track's rows become: while its
piece is live, rows of one "live" projection factor per camera, replaced at every update;
once committed (its track ended, its first frame is about to leave the window, or it reached
``GraphOptions.max_track_frames``), one projection factor for good
(:mod:`~apcc_graph.estimation.projection_tracks`, :mod:`~apcc_graph.estimation.live_tracks`);
a track that outlives the window becomes a landmark, its point a variable
(:mod:`~apcc_graph.estimation.landmarks`). How an estimate is read back: the frames' vectors
(the core), the landmarks' points and the live pieces' points from their last linearisation
(here).
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from numpy.typing import NDArray

from apcc_graph.estimation.initial_guess import FrameRows
from apcc_graph.estimation.landmarks import Landmarks
from apcc_graph.estimation.options import GraphOptions
from apcc_graph.estimation.projection_tracks import ProjectionTracks, Rows
from apcc_graph.estimation.smoother.pieces import Association, PieceWindow
from apcc_graph.estimation.smoother.solver import Additions
from apcc_graph.estimation.smoother_options import SmootherOptions
from apcc_graph.estimation.window import Window
from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.parameterisation import Bending
from apcc_graph.model.robot import Robot


class ExactTracks(PieceWindow):
    """The exact model's tracks, pieces and landmarks in a smoother's window.

    Args:
        robot, options, settings, bending: the smoother's.
        window: the smoother's window (the estimates pieces are judged and promoted at).
        inlier_sigmas: the outlier threshold (whitened residual norm, pixel-noise units).
    """

    name = "exact"
    refines = True  # a new frame's guess is refined against the known points
    final_steps = 0  # Gauss-Newton steps of the whole window at the end
    default_gate: float | None = None  # the rotation gate's threshold when none is set
    elimination = None  # iSAM2's own elimination order
    trust_region = False  # Gauss-Newton steps: the frames' vectors alone, close to linear
    pair_weights = True  # the two-frame front end's constraint holds: its weights count

    def __init__(self, robot: Robot, options: GraphOptions, settings: SmootherOptions,
                 window: Window, bending: Bending, inlier_sigmas: float) -> None:
        tracks = ProjectionTracks(robot, options, settings, window, bending, inlier_sigmas)
        landmarks = Landmarks(robot, tracks.chain,
                              lambda g: (window.thetas[g], window.times[g]),
                              options.threshold_px, inlier_sigmas, settings.window.lag,
                              settings.landmarks.max_per_camera,
                              settings.landmarks.prior_sigma,
                              settings.landmarks.pose_sigma, tracks.dim)
        super().__init__(settings, tracks, landmarks if settings.landmarks.enabled else None)

    def known_rows(self, rows: Rows, marks: Association,
                   gates: Mapping[int, FloatArray] | None = None
                   ) -> tuple[list[FrameRows], list[tuple[int, NDArray[np.bool_]]]]:
        """The new frame's rows whose points are known, for its initial guess
        (:meth:`~apcc_graph.estimation.projection_tracks.ProjectionTracks.known_rows`)."""
        return self.tracks.known_rows(rows, marks, self.landmarks, gates)

    def enter(self, add: Additions, f: int, t: float, x: FloatArray,
              base: FloatArray | None) -> None:
        """Frame ``f``'s variables beyond its vector (none) and its base pose."""
        self.tracks.bases[f] = base

    def replay(self, add: Additions, h: int, t: float, rows: Rows,
               verdicts: Mapping[int, NDArray[np.int8]], base: FloatArray | None) -> None:
        """A kept frame's rows after a restart, on its base pose (:class:`PieceWindow`)."""
        self.tracks.bases[h] = base
        super().replay(add, h, t, rows, verdicts, base)

    def restart_frame(self, add: Additions, f: int, t: float, x: FloatArray,
                      base: FloatArray | None) -> None:
        """A restarted window's frame ``f`` at ``x``: nothing beyond its vector."""
        self.tracks.bases[f] = base

    def base(self, g: int) -> FloatArray | None:
        """Frame ``g``'s base pose (``None``: identity), for frames in the window."""
        return self.tracks.bases.get(g)

    def camera_rotations(self, g: int) -> dict[int, FloatArray]:
        """None: the exact model's two-frame front end guesses a new frame (it solves the
        generalized epipolar constraint through the model, which holds here)."""
        return {}
