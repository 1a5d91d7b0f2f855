"""The smoother's track pieces with model error as noise: the projection factors are over the
cameras' tip poses (:class:`~apcc_graph.factors.tip_projection.TipProjectionFactor`), each
track's point eliminated inside its factor, as in the batch (``docs/estimation.md``, "Model
error as noise").

Everything else is the exact model's (:class:`~apcc_graph.estimation.projection_tracks.
ProjectionTracks`): a piece is live, in one factor per camera replaced at every update, until
it is committed (its track ended, its first frame is about to leave the window, or it is
:data:`~apcc_graph.estimation.terms.noisy.TIP_TRACK_FRAMES` long); its rows are judged against
its robust point at the current tips. Only where the camera poses come from differs: the
tips' current estimates and the camera's mounting, not the model's forward kinematics.
"""

from __future__ import annotations

from collections.abc import Mapping

import gtsam
import numpy as np

from apcc_graph.estimation.live_tracks import LiveTracks
from apcc_graph.estimation.options import GraphOptions
from apcc_graph.estimation.projection_tracks import ProjectionTracks
from apcc_graph.estimation.smoother_options import SmootherOptions
from apcc_graph.estimation.terms.noisy import TIP_TRACK_FRAMES
from apcc_graph.estimation.window import Window
from apcc_graph.factors.keys import tip_key
from apcc_graph.factors.tip_projection import TipProjectionFactor
from apcc_graph.factors.track_points import TrackObservations
from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.parameterisation import Bending
from apcc_graph.model.robot import Robot


class TipTracks(ProjectionTracks):
    """The track pieces of the smoother with model error as noise (module docstring).

    Args:
        robot, options, settings, window, bending, inlier_sigmas: as for
            :class:`~apcc_graph.estimation.projection_tracks.ProjectionTracks`.
        tips: frame -> ``(S, 4, 4)`` every segment tip's current ``world_T_tip``, for the
            frames in the window (read, never changed, here).
    """

    def __init__(self, robot: Robot, options: GraphOptions, settings: SmootherOptions,
                 window: Window, bending: Bending, inlier_sigmas: float,
                 tips: Mapping[int, FloatArray]) -> None:
        self.tips = tips
        self.mounts = {c: robot.cameras[c].tip_T_cam  # type: ignore[union-attr]
                       for c in robot.camera_segments}
        super().__init__(robot, options, settings, window, bending, inlier_sigmas)

    def _new_live(self) -> LiveTracks:
        cut = self.options.max_track_frames
        return LiveTracks(self.robot.camera_segments,
                          TIP_TRACK_FRAMES if cut is None else min(cut, TIP_TRACK_FRAMES),
                          self.options.min_track_rows, stagger=self.settings.tracks.stagger_cuts)

    def _camera_tips(self, cam: int, first: int, last: int) -> FloatArray:
        return np.array([self.tips[g][cam] for g in range(first, last + 1)])

    def robust_norms(self, cam: int, obs: TrackObservations, gate: FloatArray
                     ) -> tuple[FloatArray, FloatArray]:
        """Every row's whitened residual norm against its piece's point, found robustly from
        the rows ``gate`` keeps at the current tips, and the points ``(T, 3)``."""
        factor = TipProjectionFactor(obs, self.mounts[cam], np.array(gate, dtype=float))
        norms = factor.residual_norms(self._camera_tips(cam, factor.first, factor.last),
                                      robust=True)
        assert factor.points is not None
        return norms, factor.points

    def new_factor(self, cam: int, obs: TrackObservations, weights: FloatArray,
                   points: FloatArray, point_iterations: int | None) -> TipProjectionFactor:
        """Camera ``cam``'s projection factor over its tips, over ``obs``, starting from
        ``points`` (``point_iterations``: triangulation steps per linearisation; ``None``: the
        factor's own)."""
        factor = TipProjectionFactor(obs, self.mounts[cam], weights)
        factor.points = points
        if point_iterations is not None:
            factor.point_iterations = point_iterations
        return factor

    def linear_values(self, cam: int, first: int, last: int) -> gtsam.Values:
        """The current tips of camera ``cam`` at frames ``first..last``."""
        values = gtsam.Values()
        for g in range(first, last + 1):
            values.insert(tip_key(g, cam), gtsam.Pose3(self.tips[g][cam]))
        return values
