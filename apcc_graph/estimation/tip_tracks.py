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

A track that outlives the window becomes a landmark (:class:`TipLandmarks`), its point a
variable whose observations hang from the tips, as the exact model's hang from camera poses.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING

import gtsam
import numpy as np
from numpy.typing import NDArray

from apcc_graph.estimation.landmarks import Landmarks
from apcc_graph.estimation.live_tracks import LiveTracks
from apcc_graph.estimation.options import GraphOptions
from apcc_graph.estimation.projection_tracks import ProjectionTracks
from apcc_graph.estimation.smoother_options import SmootherOptions
from apcc_graph.estimation.terms.noisy import TIP_TRACK_FRAMES
from apcc_graph.estimation.window import Window
from apcc_graph.factors.keys import tip_key
from apcc_graph.factors.landmark import observation_factors
from apcc_graph.factors.tip_projection import TipProjectionFactor
from apcc_graph.factors.track_points import TrackObservations
from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.parameterisation import Bending
from apcc_graph.model.robot import Robot

if TYPE_CHECKING:  # the smoother's package imports this module
    from apcc_graph.estimation.smoother.solver import Additions


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


class TipLandmarks(Landmarks):
    """The landmarks of the smoother with model error as noise: a track that outlives the
    window keeps its point as a variable, as in the exact model
    (:mod:`~apcc_graph.estimation.landmarks`), but its observations hang from the tip pose of
    the camera's segment through the camera's mounting (gtsam's C++ projection factors with a
    body pose), so no camera-pose variable is needed.

    Args:
        robot, sigma_px, inlier_sigmas, lag, max_per_camera, prior_sigma: as for
            :class:`~apcc_graph.estimation.landmarks.Landmarks`.
        tips: frame -> ``(S, 4, 4)`` the current tip poses (read, never changed, here).
        mounts: camera -> ``tip_T_cam``.
    """

    def __init__(self, robot: Robot, tips: Mapping[int, FloatArray],
                 mounts: Mapping[int, FloatArray], sigma_px: float, inlier_sigmas: float,
                 lag: float, max_per_camera: int, prior_sigma: float) -> None:
        self.tips, self.mounts = tips, mounts
        super().__init__(robot, None, None, sigma_px, inlier_sigmas, lag, max_per_camera,
                         prior_sigma)

    def _prior_sigma(self, cam: int, frame: int, point: FloatArray) -> float:
        """At most ten times the point's depth from the camera that first saw it: the tips
        are variables here, and a point's prior must not hold them where a 10 m one would
        leave a near point free to take up what the tips' ties should decide."""
        centre = (self.tips[frame][cam] @ self.mounts[cam])[:3, 3]
        return min(self.prior_sigma, 10.0 * float(np.linalg.norm(point - centre)))

    def _attach(self, add: Additions, frames: NDArray[np.int64], cam: int,
                pieces: NDArray[np.int64], xy: FloatArray) -> None:
        """Inlier observations into the graph: projection factors on the tip poses of camera
        ``cam``'s segment, with the camera's mounting as the body pose."""
        for factor in observation_factors(frames, cam, pieces, xy, self._intrinsics[cam],
                                          self.sigma_px, tip_key, self.mounts[cam]):
            add.graph.add(factor)

    def observe(self, add: Additions, f: int, t: float, cam: int, pieces: NDArray[np.int64],
                xy: FloatArray, weights: FloatArray) -> int:
        """Frame ``f``'s observations of landmarks ``pieces``; besides the gate's ``weights``,
        each is judged against its landmark's point at the frame's first tips (no two-frame
        constraint vouches for it here): beyond ``inlier_sigmas`` it stays out (without this,
        the gate's misses made the tips of two of three replay seeds 30-45 / 100-140 mm off).
        Returns how many were left out."""
        K = self._intrinsics[cam]
        world_T_cam = self.tips[f][cam] @ self.mounts[cam]
        points = np.array([self.points[p] for p in pieces.tolist()]).reshape(-1, 3)
        local = (points - world_T_cam[:3, 3]) @ world_T_cam[:3, :3]
        with np.errstate(divide="ignore", invalid="ignore"):
            seen = local[:, :2] / local[:, 2:3]
        pixels = (seen - xy) * np.array([K.fx(), K.fy()]) / self.sigma_px
        fits = (local[:, 2] > 0.0) & (np.linalg.norm(pixels, axis=1) <= self.inlier_sigmas)
        return super().observe(add, f, t, cam, pieces, xy, weights * fits)
