"""The Cramer-Rao bound of a whole sequence's angles: every observation once, points as
nuisance.

For a simulation (true angles, true points, which observation belongs to which track and which
are outliers) and the pixel noise, the Fisher information of all angles ``theta[f, j]`` is the
sum over tracks of each track's information with its 3-D point eliminated (Schur complement:
what bundle adjustment sees when every track has its own unknown point), plus an optional prior
on the first frame. Its inverse bounds the covariance of any unbiased estimator; the per-angle
bound is the square root of its diagonal. Outliers carry no information and are left out; each
track is its own point, even when the simulator re-used a scene point for a later track (no
re-identification). The maths is that of the projection factor
(:mod:`apcc_graph.factors.projection`), evaluated at the truth with noise-free pixels; see
``docs/estimation.md``.

The information matrix is dense, ``(F S)^2``: 26 MB for 600 frames of three segments, 650 MB
for 3000; use :func:`sequence_bound` on a window of a longer sequence (the bound is flat along
a sequence whose tracks are short against it).
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from collections.abc import Sequence as SequenceOf
from dataclasses import dataclass

import numpy as np
import scipy.linalg
from numpy.typing import NDArray

from apcc_graph.factors.camera_chain import CameraChain
from apcc_graph.factors.projection import build_observations, chunk_tracks
from apcc_graph.factors.reduced_system import reduced_system
from apcc_graph.factors.track_points import cut_tracks
from apcc_graph.model.arrays import FloatArray, rms, window_rms
from apcc_graph.model.bending import bending_vector
from apcc_graph.model.parameterisation import Bending
from apcc_graph.simulation.simulator import Simulation


@dataclass(frozen=True)
class SequenceBound:
    """Per-frame, per-angle Cramer-Rao bound of a sequence.

    Attributes:
        sigmas: ``(F, S)`` the smallest standard deviation an unbiased estimator can have for
            each angle (radians); ``inf`` where the data do not determine it.
        theta0_sigma: the start prior it was computed with (radians), or ``None``.
        calibration: with unknown segment models, ``(S, 2)`` the bound of each segment's k and
            delta_max (radians); ``None`` when the models were known.
        components: for a spatial robot, ``(F, 2 S)`` the bound of each bending vector's ``u``
            and ``v`` (radians), ``sigmas`` being that of its error norm; ``None`` otherwise.
        mounts: with unknown camera mounts, ``(S, 6)`` the bound of each segment's camera
            mounting in gtsam's ``Pose3`` tangent (rotations about the camera's axes in
            radians, then translations along them in metres; NaN for a segment without a
            camera); ``None`` when the mounts were known.
    """

    sigmas: FloatArray
    theta0_sigma: float | None
    calibration: FloatArray | None = None
    components: FloatArray | None = None
    mounts: FloatArray | None = None

    def rms(self, frames: slice | None = None) -> FloatArray:
        """``(S,)`` RMS of the per-angle bound over ``frames`` (default all), radians: the
        figure to set beside an estimator's RMS error over the same frames."""
        return rms(self.sigmas if frames is None else self.sigmas[frames])

    def window_rms(self, window: int = 100) -> FloatArray:
        """``(W, S)`` :meth:`rms` over consecutive windows of ``window`` frames."""
        return window_rms(self.sigmas, window)


def fisher_information(simulation: Simulation, noise_px: float,
                       theta0_sigma: float | None = math.radians(0.1),
                       max_track_frames: int | None = None,
                       last_frame: int | None = None,
                       calibration_sigmas: tuple[float, float] | None = None,
                       spatial: bool = False,
                       mount_sigmas: tuple[float, float] | None = None) -> FloatArray:
    """The ``(F S, F S)`` Fisher information of all angles, index ``f * S + j``.

    With ``spatial`` the unknowns are every segment's bending vector ``(u, v) = theta (cos psi,
    sin psi)`` (:mod:`apcc_graph.model.bending`): the matrix is ``(2 F S)`` square, ``u`` of
    segment j at frame f at ``2 (f S + j)`` and ``v`` after it, and ``theta0_sigma`` is the
    prior of both components of frame 0's bending vectors.

    With ``calibration_sigmas`` the segments' k and delta_max are unknowns too (the bound of a
    self-calibrating estimator): the matrix is ``(F S + 2 S)`` square, the calibration of
    segment j at ``F S + 2 j`` (k) and ``F S + 2 j + 1`` (delta_max), with priors of
    ``calibration_sigmas`` (k, radians). With ``mount_sigmas`` (radians, metres) every camera's
    mounting is unknown too: six more columns per camera with tracks, in camera order, after
    all others (:func:`apcc_graph.factors.camera_chain.mount_derivatives`), with priors of
    those standard deviations.

    Args:
        simulation: the simulated sequence and its ground truth.
        noise_px: standard deviation of the pixel noise (pixels, per coordinate).
        theta0_sigma: prior standard deviation on each angle of frame 0 (radians); ``None``
            for none (vision alone).
        max_track_frames: cut tracks into pieces of at most this many frames, each with its
            own point (what an estimator that keeps only that much of a track can know);
            ``None`` for whole tracks.
        last_frame: count only the observations of frames up to this one (what a
            fixed-lag smoother has seen when it lets a frame go); the matrix keeps all frames,
            and later frames then carry no information of their own.
    """
    if not noise_px > 0.0:
        raise ValueError(f"noise_px = {noise_px!r}: expected > 0 (pixels)")
    seq = simulation.sequence
    robot = seq.robot
    assert seq.thetas is not None
    n_frames, S = seq.n_frames, seq.n_segments
    calibrate = calibration_sigmas is not None
    if not spatial and seq.psis is not None and np.any(seq.psis != 0.0):
        raise ValueError("fisher_information: the recording bends out of the plane psi = 0; "
                         "its bound is the spatial one (spatial=True)")
    truth = true_parameters(simulation, spatial)
    bending = Bending.free(robot.segments) if spatial else Bending.fixed(robot.segments)
    P = bending.dim  # parameters per frame
    D0 = n_frames * P
    C0 = D0 + (2 * S if calibrate else 0)
    mounted = sorted(seq.tracks) if mount_sigmas is not None else []
    info = np.zeros((C0 + 6 * len(mounted),) * 2)
    for cam in seq.tracks:
        extra = D0 + np.arange(2 * (cam + 1)) if calibrate else np.zeros(0, dtype=int)
        if mounted:
            extra = np.concatenate([extra, C0 + 6 * mounted.index(cam) + np.arange(6)])
        for index, H in _camera_blocks(simulation, cam, bending, truth, noise_px,
                                       max_track_frames, last_frame, calibrate, bool(mounted)):
            index = np.concatenate([index, extra])
            info[np.ix_(index, index)] += H
    sigmas = [(np.arange(P), np.full(P, np.inf if theta0_sigma is None else theta0_sigma))]
    if calibration_sigmas is not None:
        sigmas.append((D0 + np.arange(2 * S), np.tile(calibration_sigmas, S)))
    if mount_sigmas is not None:
        rot, pos = (float(v) for v in mount_sigmas)
        sigmas.append((C0 + np.arange(6 * len(mounted)),
                       np.tile([rot] * 3 + [pos] * 3, len(mounted))))
    for diag, sigma in sigmas:  # the priors
        info[diag, diag] += 1.0 / np.asarray(sigma, dtype=float) ** 2
    return info


def _camera_blocks(simulation: Simulation, cam: int, bending: Bending, truth: FloatArray,
                   noise_px: float, max_track_frames: int | None, last_frame: int | None,
                   calibrate: bool, mount: bool) -> Iterator[tuple[NDArray[np.int64],
                                                                    FloatArray]]:
    """Camera ``cam``'s information per chunk of tracks at the truth: the frame columns it
    touches (``f * P + i``) and its reduced system's ``H`` (those columns, then the chain's
    calibration and mount columns)."""
    seq = simulation.sequence
    camera = seq.robot.cameras[cam]
    assert camera is not None
    tracks = seq.tracks[cam]
    inlier = ~simulation.outliers[cam]
    if last_frame is not None:
        inlier = inlier & (tracks.frames <= last_frame)
    if not inlier.any():
        return
    ids = cut_tracks(tracks.frames, tracks.track_ids, max_track_frames)
    xy = camera.normalized(simulation.clean_uv[cam])
    obs = build_observations(cam, tracks.frames, ids, xy,
                             camera.pixel_jacobian(xy) / noise_px, inlier)
    landmark = np.zeros(obs.n_tracks, dtype=np.int64)
    order = np.lexsort((tracks.frames[inlier], ids[inlier]))
    landmark[obs.tracks] = simulation.landmarks[cam][inlier][order]
    chain = CameraChain(bending.head(cam + 1), camera.tip_T_cam, seq.world_T_base)
    n, P = chain.n_parameters, bending.dim
    for chunk in chunk_tracks(obs):
        part = obs.select(chunk)
        first, last = int(part.frames.min()), int(part.frames.max())
        out = reduced_system(part, chain, truth[first:last + 1], first, np.ones(len(part)),
                             simulation.points_world[landmark[chunk]], refine_points=False,
                             calibration=calibrate, mount=mount)
        yield ((np.arange(first, last + 1) * P)[:, None] + np.arange(n)).ravel(), out.H


def true_parameters(simulation: Simulation, spatial: bool = False) -> FloatArray:
    """``(F, S)`` true angles, or with ``spatial`` ``(F, 2 S)`` true bending vectors
    ``(u_0, v_0, u_1, ...)`` (radians)."""
    seq = simulation.sequence
    assert seq.thetas is not None
    if not spatial:
        return seq.thetas
    psis = np.zeros_like(seq.thetas) if seq.psis is None else seq.psis
    u, v = bending_vector(seq.thetas, psis)
    return np.stack([u, v], axis=-1).reshape(seq.n_frames, -1)


def sequence_bound(simulation: Simulation, noise_px: float,
                   theta0_sigma: float | None = math.radians(0.1),
                   max_track_frames: int | None = None,
                   calibration_sigmas: tuple[float, float] | None = None,
                   spatial: bool = False,
                   mount_sigmas: tuple[float, float] | None = None) -> SequenceBound:
    """The per-frame, per-angle Cramer-Rao bound of a simulation (radians).

    Args: as :func:`fisher_information`; with ``calibration_sigmas`` the segment models are
        unknown too, and the bound of their k and delta_max is returned as well; with
        ``mount_sigmas`` the camera mounts, and the bound of the mounts.

    Returns:
        The bound; angles the data leave undetermined (a frame no camera saw, no start prior
        and no motion) are ``inf``. With ``spatial``, ``sigmas`` is the bound of each bending
        vector's error norm, ``sqrt(sigma_u^2 + sigma_v^2)`` per segment, and
        ``components`` holds ``(sigma_u, sigma_v)`` per segment, ``(F, 2 S)``.
    """
    info = fisher_information(simulation, noise_px, theta0_sigma, max_track_frames,
                              calibration_sigmas=calibration_sigmas, spatial=spatial,
                              mount_sigmas=mount_sigmas)
    seq = simulation.sequence
    n_frames, S = seq.n_frames, seq.n_segments
    sigmas = _bound_sigmas(info)
    D0 = n_frames * S * (2 if spatial else 1)
    C0 = D0 + (0 if calibration_sigmas is None else 2 * S)
    calibration = None if calibration_sigmas is None else sigmas[D0:C0].reshape(S, 2)
    mounts = None
    if mount_sigmas is not None:
        mounts = np.full((S, 6), np.nan)
        mounts[sorted(seq.tracks)] = sigmas[C0:].reshape(-1, 6)
    if spatial:
        components = sigmas[:D0].reshape(n_frames, 2 * S)
        pairs = components.reshape(n_frames, S, 2)
        return SequenceBound(np.sqrt(np.sum(pairs**2, axis=-1)), theta0_sigma, calibration,
                             components, mounts)
    return SequenceBound(sigmas[:D0].reshape(n_frames, S), theta0_sigma, calibration,
                         mounts=mounts)


def _bound_sigmas(info: FloatArray) -> FloatArray:
    """Square roots of the diagonal of ``info^-1``; ``inf`` along its null space."""
    try:
        U = scipy.linalg.cholesky(info, lower=False, check_finite=False)
        U_inv = scipy.linalg.solve_triangular(U, np.eye(len(info)), check_finite=False)
        variance = np.einsum("ij,ij->i", U_inv, U_inv)  # diag(U^-1 U^-T)
    except np.linalg.LinAlgError:
        lam, vec = np.linalg.eigh(info)
        tol = 1e-10 * max(float(lam[-1]), 1e-300)
        good = lam > tol
        variance = (vec[:, good] ** 2) @ (1.0 / lam[good])
        null = np.sum(vec[:, ~good] ** 2, axis=1) > 1e-9
        variance[null] = np.inf
    return np.sqrt(variance)


@dataclass(frozen=True)
class LagBound:
    """The Cramer-Rao bound of a fixed-lag smoother's final estimates, at sampled frames.

    A fixed-lag smoother lets frame ``f`` go once it has seen frame ``f + lag_frames``: its
    final estimate of ``f`` can use no later observation. The bound of that estimate is the
    ``f`` block of the inverse information of the observations up to ``f + lag_frames`` (the
    marginalisation of older frames loses nothing in the linear-Gaussian limit). It lies between
    the filtering bound (``lag_frames = 0``) and the whole sequence's (:func:`sequence_bound`).

    Attributes:
        frames: ``(K,)`` the sampled frames.
        sigmas: ``(K, S)`` their per-angle bound (radians).
        lag_frames: the lag in frames.
    """

    frames: NDArray[np.int64]
    sigmas: FloatArray
    lag_frames: int

    def rms(self, first: int = 0, stop: int | None = None) -> FloatArray:
        """``(S,)`` RMS of the bound over the sampled frames in ``first .. stop - 1``."""
        keep = (self.frames >= first) & (self.frames < (stop if stop is not None else 2**62))
        return rms(self.sigmas[keep])

    def window_rms(self, window: int = 100) -> FloatArray:
        """``(W, S)`` :meth:`rms` over consecutive windows of ``window`` frames."""
        end = int(self.frames.max()) + 1
        return np.array([self.rms(s, s + window) for s in range(0, end, window)])


def lag_bound(simulation: Simulation, noise_px: float, lag_frames: int,
              theta0_sigma: float | None = math.radians(0.1), step: int = 10,
              max_track_frames: int | None = None,
              frames: SequenceOf[int] | None = None) -> LagBound:
    """The bound of a fixed-lag smoother that lets a frame go ``lag_frames`` frames later.

    Args:
        simulation, noise_px, theta0_sigma, max_track_frames: as :func:`fisher_information`.
        lag_frames: the smoother's lag in frames (lag in seconds times the frame rate).
        step: sample every ``step``-th frame (each sample builds and factors one information
            matrix, so the cost is that of :func:`sequence_bound` per sample).
        frames: sample these frames instead (ascending, within the recording).

    Returns:
        The bound at frames ``0, step, 2 step, ...`` (or ``frames``).
    """
    if lag_frames < 0 or step < 1:
        raise ValueError(f"lag_frames = {lag_frames!r}, step = {step!r}: expected "
                         "lag_frames >= 0 and step >= 1")
    n_frames, S = simulation.sequence.n_frames, simulation.sequence.n_segments
    if frames is None:
        frames = np.arange(0, n_frames, step, dtype=np.int64)
    else:
        frames = np.asarray(frames, dtype=np.int64)
        if frames.ndim != 1 or np.any(np.diff(frames) <= 0) or (
                len(frames) and not 0 <= frames[0] <= frames[-1] < n_frames):
            raise ValueError(f"frames = {frames.tolist()!r}: expected ascending frames in "
                             f"0 .. {n_frames - 1}")
    sigmas = np.full((len(frames), S), np.inf)
    for i, f in enumerate(frames.tolist()):
        last = min(f + lag_frames, n_frames - 1)
        info = fisher_information(simulation, noise_px, theta0_sigma, max_track_frames,
                                  last_frame=last)[:(last + 1) * S, :(last + 1) * S]
        try:
            U = scipy.linalg.cholesky(info, lower=False, check_finite=False)
        except np.linalg.LinAlgError:
            # some frame up to this cut is undetermined (no camera saw it: a blackout); the
            # others keep their bound, the undetermined directions are inf
            sigmas[i] = _bound_sigmas(info)[f * S:(f + 1) * S]
            continue
        # The f block of info^-1 = U^-1 U^-T: rows f S.. of U^-1 come from solving U^T x = e.
        unit = np.zeros((len(info), S))
        unit[f * S + np.arange(S), np.arange(S)] = 1.0
        x = scipy.linalg.solve_triangular(U, unit, trans="T", check_finite=False)
        sigmas[i] = np.sqrt(np.einsum("ij,ij->j", x, x))
    return LagBound(frames, sigmas, int(lag_frames))
