"""Factor-graph building shared by the batch optimiser and the fixed-lag smoother.

Variables: one vector per frame, key :func:`apcc_graph.factors.keys.frame_key`, in the
robot's parameterisation (:class:`~apcc_graph.model.parameterisation.Bending`): the ``S``
angles in fixed bending planes (a planar robot), or the ``2 S`` bending-vector components
``(u_0, v_0, u_1, v_1, ...)`` (radians). Factors (``docs/estimation.md``):

- the start prior on the first frame (``theta0``, ``GraphOptions.theta0_sigma`` per component);
- a random-walk motion prior between consecutive frames (weak; ``None`` leaves it out);
- soft joint limits on each segment's bend ``|theta|`` (the bending vector's length ``|b|``);
- per camera, the projection factors of its tracks (:class:`CameraTerms`): every observation
  once, each track's point eliminated, tracks grouped in chunks; row weights hold the robust
  decisions (:mod:`apcc_graph.estimation.robust`).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

import gtsam
import numpy as np
from numpy.typing import NDArray

from apcc_graph.estimation.image_motion import motion_clock
from apcc_graph.estimation.options import GraphOptions
from apcc_graph.estimation.robust import gnc_tls_weights
from apcc_graph.factors.keys import calibration_key, frame_key, mount_key
from apcc_graph.factors.projection import (
    CameraChain,
    ProjectionFactor,
    TrackObservations,
    build_observations,
    calibrated,
    chunk_tracks,
)
from apcc_graph.factors.track_points import cut_tracks
from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.parameterisation import Bending
from apcc_graph.model.robot import Robot
from apcc_graph.model.segment import Segment
from apcc_graph.model.sequence import Sequence as RobotSequence

__all__ = ["CameraTerms", "calibration_factors", "calibration_from", "camera_observations",
           "frame_key", "limit_factor", "mount_factors", "observed_cameras", "prior_factors",
           "thetas_from", "values_from"]


def camera_observations(sequence: RobotSequence, cam: int, noise_px: float,
                        min_rows: int = 2, frames: range | None = None,
                        max_track_frames: int | None = None,
                        clock: FloatArray | None = None) -> TrackObservations | None:
    """Camera ``cam``'s observations as tracks (undistorted, whitened by ``noise_px``).

    Tracks longer than ``max_track_frames`` are cut into pieces with points of their own
    (:func:`apcc_graph.factors.track_points.cut_tracks`, on ``clock`` when given: ``(F,)``
    ticks per frame); pieces seen in fewer than ``min_rows``
    frames are left out; ``None`` when nothing is left. ``frames`` restricts the rows to a range of
    frames.
    """
    camera = sequence.robot.cameras[cam]
    if camera is None or cam not in sequence.tracks:
        return None
    tracks = sequence.tracks[cam]
    ids = cut_tracks(tracks.frames, tracks.track_ids, max_track_frames, clock)
    keep = np.ones(len(tracks), dtype=bool)
    if frames is not None:
        keep &= (tracks.frames >= frames.start) & (tracks.frames < frames.stop)
    _, inverse, counts = np.unique(ids[keep], return_inverse=True, return_counts=True)
    keep[keep] = counts[inverse] >= min_rows
    if not keep.any():
        return None
    bearings = sequence.bearings(cam)[keep]
    xy = bearings[:, :2] / bearings[:, 2:3]
    return build_observations(cam, tracks.frames[keep], ids[keep], xy,
                              camera.pixel_jacobian(xy) / noise_px)


def observed_cameras(sequence: RobotSequence, options: GraphOptions) -> list[TrackObservations]:
    """Every camera's observations as ``options`` build them (:func:`camera_observations`
    with its noise, shortest tracks and longest pieces); cameras left with none are left
    out."""
    clock = None
    cut = options.max_track_frames
    if cut is not None and options.still_tick is not None and _longest_track(sequence) > cut:
        clock = motion_clock(sequence, options.threshold_px, still_tick=options.still_tick)
    found = (camera_observations(sequence, cam, options.threshold_px, options.min_track_rows,
                                 max_track_frames=options.max_track_frames, clock=clock)
             for cam in sequence.robot.camera_segments)
    return [obs for obs in found if obs is not None]


def _longest_track(sequence: RobotSequence) -> int:
    """The most frames any track of the sequence spans (0 without tracks)."""
    longest = 0
    for tracks in sequence.tracks.values():
        if len(tracks) == 0:
            continue
        ids, inverse = np.unique(tracks.track_ids, return_inverse=True)
        first = np.full(len(ids), np.iinfo(np.int64).max)
        last = np.full(len(ids), -1)
        np.minimum.at(first, inverse, tracks.frames)
        np.maximum.at(last, inverse, tracks.frames)
        longest = max(longest, int(np.max(last - first)) + 1)
    return longest


def camera_chain(robot: Robot, cam: int, bending: Bending,
                 world_T_base: FloatArray | None = None) -> CameraChain:
    """What fixes camera ``cam``'s pose: the parameterisation of its segments, its mounting
    and the base poses."""
    camera = robot.cameras[cam]
    assert camera is not None
    return CameraChain(bending.head(cam + 1), camera.tip_T_cam, world_T_base)


class CameraTerms:
    """One camera's projection factors (one per chunk of tracks) and their robust weights.

    Args:
        obs: the camera's tracks.
        chain: the camera's chain (base poses over the frames the observations index).
        n_segments: the dimension of a frame's vector (the parameterisation's ``dim``).
        frames_per_chunk: see :func:`apcc_graph.factors.projection.chunk_tracks`.
        calibrate: the factors also depend on the segments' ``(k, delta_max)`` variables
            (:func:`apcc_graph.factors.keys.calibration_key`).
        mount: the factors also depend on the camera's mounting
            (:func:`apcc_graph.factors.keys.mount_key`).
    """

    def __init__(self, obs: TrackObservations, chain: CameraChain, n_segments: int,
                 frames_per_chunk: int, calibrate: bool = False, mount: bool = False) -> None:
        self.camera = obs.camera
        self.chain = chain
        self.chunks = [ProjectionFactor(obs.select(c), chain, n_segments, calibrate=calibrate,
                                        mount=mount)
                       for c in chunk_tracks(obs, frames_per_chunk)]
        self.norms = [np.zeros(len(c.obs)) for c in self.chunks]

    def factors(self) -> list[gtsam.CustomFactor]:
        """The gtsam factors (weights are read at every linearisation)."""
        return [c.factor() for c in self.chunks]

    def measure(self, thetas: FloatArray, robust: bool = False,
                segments: Sequence[Segment] | None = None,
                tip_T_cam: FloatArray | None = None) -> None:
        """Residual norms of every observation at ``thetas`` (``(F, S)``, all frames); with
        ``robust``, each track's point is found afresh, robustly (the first decisions).
        ``segments`` replaces the robot's segment models and ``tip_T_cam`` the camera's
        mounting (self-calibration)."""
        chain = (self.chain if segments is None
                 else self.chain.with_segments(segments[:len(self.chain.segments)]))
        if tip_T_cam is not None:
            chain = chain.with_mount(tip_T_cam)
        for i, c in enumerate(self.chunks):
            self.norms[i] = c.residual_norms(thetas[c.first:c.last + 1], robust=robust,
                                             chain=chain)

    def set_weights(self, threshold: float, mu: float) -> int:
        """GNC weights from the last :meth:`measure`; returns how many rows changed between
        inlier and outlier (weight above or below one half)."""
        changed = 0
        for c, norms in zip(self.chunks, self.norms, strict=True):
            new = gnc_tls_weights(norms, threshold, mu)
            changed += int(np.sum((new > 0.5) != (c.weights > 0.5)))
            c.weights[:] = new
        return changed

    def inliers_per_frame(self, n_frames: int) -> NDArray[np.int64]:
        """``(n_frames,)`` observations with weight above one half, per frame."""
        out = np.zeros(n_frames, dtype=np.int64)
        for c in self.chunks:
            out += np.bincount(c.obs.frames[c.weights > 0.5], minlength=n_frames)[:n_frames]
        return out

    def outlier_rows(self) -> int:
        """Observations currently judged outliers (weight at most one half)."""
        return int(sum(np.sum(c.weights <= 0.5) for c in self.chunks))


def limit_factor(key: int, bending: Bending, sigma: float) -> gtsam.CustomFactor:
    """Soft joint limits of one frame,
    :meth:`~apcc_graph.model.parameterisation.Bending.limit_residual`: ``r_j = max(0,
    |b_j| - theta_max_j) / sigma`` per segment, smooth through straight."""

    def error_func(this: gtsam.CustomFactor, values: gtsam.Values,
                   H: list[np.ndarray] | None) -> np.ndarray:
        r, J = bending.limit_residual(values.atVector(key), sigma)
        if H is not None:
            H[0] = J
        return r

    return gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(bending.n_segments), [key],
                              error_func)


def prior_factors(frames: Iterable[int], timestamps: Sequence[float] | FloatArray,
                  theta0: FloatArray | None, bending: Bending, options: GraphOptions,
                  limits: bool = True, start_sigmas: FloatArray | None = None
                  ) -> list[gtsam.NonlinearFactor]:
    """Start prior (when ``theta0``, the first frame's vector, is given, on the first of
    ``frames``), motion priors between consecutive frames and joint limits.

    ``timestamps[f]`` is frame f's time (seconds); frame vectors are ``bending``'s. The start
    prior's sigma is ``options.theta0_sigma`` on every component, or ``start_sigmas``
    (``(dim,)`` radians, one per component) when given.
    """
    frames = list(frames)
    dim = bending.dim
    out: list[gtsam.NonlinearFactor] = []
    if theta0 is not None:
        theta0 = np.asarray(theta0, dtype=float)
        if theta0.shape != (dim,):
            raise ValueError(f"theta0 has shape {theta0.shape}: expected ({dim},)")
        if start_sigmas is None:
            noise = gtsam.noiseModel.Isotropic.Sigma(dim, options.theta0_sigma)
        else:
            sig = np.asarray(start_sigmas, dtype=float)
            if sig.shape != (dim,) or not np.all(np.isfinite(sig) & (sig > 0.0)):
                raise ValueError(f"start_sigmas {sig!r}: expected ({dim},) positive radians")
            noise = gtsam.noiseModel.Diagonal.Sigmas(sig)
        out.append(gtsam.PriorFactorVector(frame_key(frames[0]), theta0, noise))
    for prev, f in zip(frames[:-1], frames[1:], strict=True):
        if options.motion_sigma is not None:
            dt = max(float(timestamps[f] - timestamps[prev]), 1e-9)
            out.append(gtsam.BetweenFactorVector(
                frame_key(prev), frame_key(f), np.zeros(dim),
                gtsam.noiseModel.Isotropic.Sigma(dim, options.motion_sigma * np.sqrt(dt))))
    if limits:
        out += [limit_factor(frame_key(f), bending, options.limit_sigma) for f in frames]
    return out


def values_from(thetas: FloatArray, frames: Iterable[int]) -> gtsam.Values:
    """Values holding ``thetas[i]`` at frame ``frames[i]``'s key."""
    values = gtsam.Values()
    for f, theta in zip(frames, thetas, strict=True):
        values.insert(frame_key(int(f)), np.asarray(theta, dtype=float))
    return values


def thetas_from(values: gtsam.Values, frames: Iterable[int]) -> FloatArray:
    """``(F, dim)`` the frame vectors of ``frames`` in ``values``."""
    return np.array([values.atVector(frame_key(int(f))) for f in frames])


def calibration_factors(robot: Robot, sigmas: tuple[float, float]
                        ) -> list[gtsam.NonlinearFactor]:
    """Self-calibration priors: each segment's ``(k, delta_max)`` variable
    (:func:`~apcc_graph.factors.keys.calibration_key`) around the robot's values, with
    standard deviations ``sigmas = (k sigma, delta_max sigma in radians)``."""
    noise = gtsam.noiseModel.Diagonal.Sigmas(np.asarray(sigmas, dtype=float))
    return [gtsam.PriorFactorVector(calibration_key(j), np.array([s.k, s.delta_max]), noise)
            for j, s in enumerate(robot.segments)]


def mount_factors(robot: Robot, cameras: Iterable[int], sigmas: tuple[float, float]
                  ) -> list[gtsam.NonlinearFactor]:
    """Mount-calibration priors: each of ``cameras``' mounting
    (:func:`~apcc_graph.factors.keys.mount_key`, a ``Pose3``) around the robot's
    ``tip_T_cam``, with standard deviations ``sigmas = (rotation in radians, translation in
    metres)`` on each axis of the camera frame."""
    rot, pos = (float(v) for v in sigmas)
    noise = gtsam.noiseModel.Diagonal.Sigmas(np.array([rot] * 3 + [pos] * 3))
    out: list[gtsam.NonlinearFactor] = []
    for c in cameras:
        camera = robot.cameras[c]
        assert camera is not None
        out.append(gtsam.PriorFactorPose3(mount_key(c), gtsam.Pose3(camera.tip_T_cam), noise))
    return out


def calibration_from(values: gtsam.Values, robot: Robot) -> tuple[Segment, ...]:
    """The robot's segments with ``k`` and ``delta_max`` read from ``values`` (clamped to
    their valid ranges)."""
    return tuple(calibrated(s, *values.atVector(calibration_key(j)))
                 for j, s in enumerate(robot.segments))
