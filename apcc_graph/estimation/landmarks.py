"""The landmarks of a streaming estimator: tracks that outlive its window keep their point.

A fixed-lag smoother that eliminates each track's point inside its factor has to cut a track
whose first frame leaves the window, and the rest of the track then gets a new point: what the
old observations said about it is lost to the frames still in the window, which raises the bound
of a fixed lag and lets the estimate drift (``docs/estimation.md``). :class:`Landmarks` keeps
such tracks instead (at most ``max_per_camera`` per camera at a time):

- :meth:`Landmarks.promote`: the piece's point, triangulated robustly (which also takes the
  outlier decisions of its observations so far), becomes a ``Point3`` variable with a weak
  prior, and its inlier observations become gtsam's C++ projection factors
  (:mod:`apcc_graph.factors.landmark`);
- :meth:`Landmarks.observe`: a new frame's observations of landmarks, judged by the initial
  guess, join the same way, and the landmarks seen keep a fresh timestamp, so the smoother keeps
  them;
- the observations attach to a ``Pose3`` per frame and camera, created when first needed and
  tied to the frame's angles (:func:`apcc_graph.factors.landmark.camera_pose_factor`);
- :meth:`Landmarks.forget`: a landmark whose track ended (or went unseen for most of a lag) gets
  no more observations, and the smoother marginalises it once it is older than the lag.

The smoother owns the window and the graph; this class only says what to add to them.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING

import gtsam
import numpy as np
from numpy.typing import NDArray

from apcc_graph.estimation.initial_guess import FrameRows
from apcc_graph.estimation.robust import enough_rows, gnc_tls_weights
from apcc_graph.factors.keys import camera_pose_key, point_key
from apcc_graph.factors.landmark import camera_pose_factor, observation_factors
from apcc_graph.factors.projection import CameraChain
from apcc_graph.factors.track_points import TrackObservations
from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.robot import Robot

if TYPE_CHECKING:  # the smoother's package imports this module
    from apcc_graph.estimation.smoother.solver import Additions

ChainLookup = Callable[[int, int, int], CameraChain]
"""``(camera, first, last) -> the camera's chain over frames first .. last``."""
FrameLookup = Callable[[int], tuple[FloatArray, float]]
"""``frame -> (its current angles, its time)``, for frames in the window."""
RobustPoints = Callable[[int, TrackObservations, FloatArray], tuple[FloatArray, FloatArray]]
"""``(camera, pieces, gate) -> (each row's whitened residual norm, each piece's point)``: the
pieces' points found robustly from the rows ``gate`` keeps, at the window's current estimates
(:meth:`~apcc_graph.estimation.projection_tracks.ProjectionTracks.robust_norms`)."""


class Landmarks:
    """Landmark bookkeeping of a streaming estimator (see the module docstring).

    Args:
        robot: the robot (its cameras' pinhole intrinsics for gtsam's projection factors).
        chain: the camera chains over frames of the window.
        frame: a frame's current angles and time.
        sigma_px: the tracks' pixel noise (pixels).
        inlier_sigmas: outlier threshold on whitened residual norms.
        lag: the smoother's window (seconds).
        max_per_camera: most landmarks per camera at a time.
        prior_sigma: a landmark's weak prior at its first triangulation (metres).
        pose_sigma: stiffness of the tie between a frame's angles and its camera poses.
        dim: the length of a frame's vector (default S; 2 S for a spatial robot).
    """

    def __init__(self, robot: Robot, chain: ChainLookup, frame: FrameLookup, sigma_px: float,
                 inlier_sigmas: float,
                 lag: float, max_per_camera: int = 10, prior_sigma: float = 10.0,
                 pose_sigma: float = 1e-4, dim: int | None = None) -> None:
        self.robot = robot
        self.dim = robot.n_segments if dim is None else dim  # a frame's vector
        self.chain, self.frame = chain, frame
        self.sigma_px, self.inlier_sigmas, self.lag = sigma_px, inlier_sigmas, lag
        self.max_per_camera = int(max_per_camera)
        self.prior_sigma, self.pose_sigma = float(prior_sigma), float(pose_sigma)
        self._intrinsics = {c: gtsam.Cal3_S2(cam.fx, cam.fy, 0.0, cam.cx, cam.cy)
                            for c, cam in enumerate(robot.cameras) if cam is not None}
        self.reset()

    def reset(self) -> None:
        """Forget every landmark (after the smoother restarted)."""
        self._of: dict[int, dict[int, int]] = {c: {} for c in self.robot.camera_segments}
        self.points: dict[int, FloatArray] = {}  # landmark -> current world point
        self._seen: dict[int, float] = {}  # landmark -> last time seen
        self._poses: set[tuple[int, int]] = set()  # (frame, camera) pose variables

    def room(self) -> dict[int, int]:
        """camera -> how many more landmarks it may have."""
        return {c: self.max_per_camera - len(of) for c, of in self._of.items()}

    def of(self, cam: int, ids: NDArray[np.int64]) -> NDArray[np.int64]:
        """The landmark of each track id of camera ``cam`` (-1 where the track is not one)."""
        of = self._of.get(cam, {})
        return np.array([of.get(t, -1) for t in ids.tolist()], dtype=np.int64)

    def known_rows(self, cam: int, marks: NDArray[np.int64], xy: FloatArray,
                   whiten: FloatArray) -> tuple[FrameRows, NDArray[np.bool_]] | None:
        """The new frame's observations of landmarks with their current points, for the
        initial guess, and the mask of those rows; ``None`` without any."""
        mask = marks >= 0
        if not mask.any():
            return None
        points = np.array([self.points[p] for p in marks[mask].tolist()])
        return FrameRows(cam, points, xy[mask], whiten[mask]), mask

    def forget(self, seen: Mapping[int, NDArray[np.int64]], t: float) -> None:
        """Landmarks whose track ended (its camera saw something, but not the track) or that
        went unseen for most of a lag get no more observations."""
        for cam, of in self._of.items():
            now = set(seen[cam].tolist()) if cam in seen and len(seen[cam]) else None
            for tid, piece in list(of.items()):
                stale = t - self._seen[piece] > 0.8 * self.lag
                if stale or (now is not None and tid not in now):
                    del of[tid]
                    self.points.pop(piece, None)
                    self._seen.pop(piece, None)

    def retire(self, frames: list[int]) -> None:
        """Frames the coming update marginalises: their camera poses go with them."""
        gone = set(frames)
        self._poses = {(g, c) for g, c in self._poses if g not in gone}

    def promote(self, add: Additions, cam: int, obs: TrackObservations,
                tracks: Mapping[int, int], robust: RobustPoints, t: float,
                gate: FloatArray | None = None) -> tuple[int, int]:
        """Make landmarks of camera ``cam``'s pieces ``obs`` (ids are piece ids; ``tracks``
        maps their track ids to them; ``robust`` finds their points and judges their rows;
        ``gate``: the model-free gate's weight per row, default 1). Returns the observations
        taken and how many of them were judged outliers."""
        gate = np.ones(len(obs)) if gate is None else gate * enough_rows(gate, obs.tracks,
                                                                         obs.starts, 2)
        norms, points = robust(cam, obs, gate)
        weights = gnc_tls_weights(norms, self.inlier_sigmas, math.inf) * gate
        outliers = int(np.sum(weights == 0.0))
        inliers = np.add.reduceat(weights > 0.0, obs.starts[:-1])
        keep = np.flatnonzero((inliers >= 2) & np.all(np.isfinite(points), axis=1))
        if len(keep) == 0:
            return len(obs), outliers
        rows = np.concatenate([np.arange(obs.starts[i], obs.starts[i + 1]) for i in keep])
        rows = rows[weights[rows] > 0.0]
        piece_track = {piece: tid for tid, piece in tracks.items()}
        noise = gtsam.noiseModel.Isotropic.Sigma(3, self.prior_sigma)
        for i in keep.tolist():
            piece, point = int(obs.ids[i]), points[i]
            key = point_key(cam, piece)
            add.values.insert(key, gtsam.Point3(*point))
            add.graph.add(gtsam.PriorFactorPoint3(key, gtsam.Point3(*point), noise))
            add.stamps[key] = t
            self.points[piece] = point.copy()
            self._seen[piece] = t
            self._of[cam][piece_track[piece]] = piece
        self._attach(add, obs.frames[rows], cam, obs.ids[obs.tracks[rows]], obs.xy[rows])
        return len(obs), outliers

    def observe(self, add: Additions, f: int, t: float, cam: int, pieces: NDArray[np.int64],
                xy: FloatArray, weights: FloatArray) -> int:
        """Frame ``f``'s observations of landmarks ``pieces`` (judged by the initial guess:
        ``weights`` 0 for an outlier); how many of them were left out."""
        for piece in pieces.tolist():
            add.stamps[point_key(cam, piece)] = t
            self._seen[piece] = t
        good = weights > 0.0
        if good.any():
            self._attach(add, np.full(int(good.sum()), f), cam, pieces[good], xy[good])
        return int(np.sum(~good))

    def update_points(self, estimate: gtsam.Values) -> None:
        """Take the landmarks' points from the smoother's estimate."""
        for cam, of in self._of.items():
            for piece in of.values():
                key = point_key(cam, piece)
                if estimate.exists(key):
                    self.points[piece] = np.asarray(estimate.atPoint3(key), dtype=float)

    def _attach(self, add: Additions, frames: NDArray[np.int64], cam: int,
                pieces: NDArray[np.int64], xy: FloatArray) -> None:
        """Inlier observations of landmarks ``pieces`` into the graph: gtsam's projection
        factors on camera ``cam``'s pose variables of ``frames``, each created when first
        needed and tied to its frame's angles."""
        for g in np.unique(frames).tolist():
            self._ensure_pose(add, g, cam)
        for factor in observation_factors(frames, cam, pieces, xy, self._intrinsics[cam],
                                          self.sigma_px):
            add.graph.add(factor)

    def _ensure_pose(self, add: Additions, g: int, cam: int) -> None:
        """Camera ``cam``'s pose variable at frame ``g``, tied to the frame's angles, created
        when a landmark observation first needs it (a pose without observations would be
        held by the stiff tie alone: a badly conditioned system)."""
        if (g, cam) in self._poses:
            return
        chain = self.chain(cam, g, g)
        thetas, time = self.frame(g)
        pose = chain.poses(thetas[None, :], g, False)[0][0]
        key = camera_pose_key(g, cam)
        add.values.insert(key, gtsam.Pose3(pose))
        add.stamps[key] = time
        add.graph.add(camera_pose_factor(g, cam, chain, self.dim, self.pose_sigma))
        self._poses.add((g, cam))
