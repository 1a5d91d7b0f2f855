"""The sequence Cramer-Rao bound: the Fisher information against a numerical one built from the
pixel predictions, outliers left out, cut tracks, the start prior, noise scaling, undetermined
angles, and the RMS summaries."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from helpers import random_pose

from apcc_graph import Robot, Segment, TipCamera
from apcc_graph.evaluation.sequence_bound import (
    SequenceBound,
    fisher_information,
    lag_bound,
    sequence_bound,
)
from apcc_graph.model.sequence import Sequence, Tracks
from apcc_graph.simulation.simulator import Simulation, simulate

SEGMENTS = (Segment(0.3, k=0.2, delta_max=0.1, theta_max=1.0),
            Segment(0.3, k=0.3, delta_max=-0.05, theta_max=1.0),
            Segment(0.25, k=0.25, delta_max=0.03, theta_max=1.0))
PRIOR = math.radians(0.1)


@pytest.fixture(scope="module")
def robot() -> Robot:
    """A pinhole camera, a distorting lens on a tilted mount, another mount and focal length."""
    rng = np.random.default_rng(0)
    return Robot(SEGMENTS, [
        TipCamera(500.0, 500.0, 320.0, 240.0, 640, 480),
        TipCamera(500.0, 490.0, 320.0, 240.0, 640, 480, distortion=(-0.2, 0.05, 1e-3, -1e-3),
                  tip_T_cam=random_pose(rng, 0.2, 0.02)),
        TipCamera(450.0, 450.0, 330.0, 230.0, 640, 480, tip_T_cam=random_pose(rng, 0.2, 0.02)),
    ])


def keep_rows(sim: Simulation, keep: dict[int, np.ndarray]) -> Simulation:
    """The simulation with only the rows ``keep[cam]`` of each camera (ground truth alike)."""
    seq = sim.sequence
    tracks = {c: Tracks(t.frames[keep[c]], t.track_ids[keep[c]], t.uv[keep[c]])
              for c, t in seq.tracks.items()}
    sequence = Sequence(seq.robot, seq.timestamps, tracks, seq.world_T_base, seq.thetas,
                        seq.psis)
    return dataclasses.replace(
        sim, sequence=sequence,
        landmarks={c: sim.landmarks[c][keep[c]] for c in keep},
        clean_uv={c: sim.clean_uv[c][keep[c]] for c in keep},
        outliers={c: sim.outliers[c][keep[c]] for c in keep})


# ------------------------------------------------------------------- against a dense Fisher
def _pixels(robot: Robot, sim: Simulation, thetas: np.ndarray,
            points: dict[int, np.ndarray]) -> np.ndarray:
    """All noise-free pixel predictions, camera by camera, row by row: ``(2 N,)``."""
    seq = sim.sequence
    poses = robot.camera_poses(thetas, seq.psis, seq.world_T_base)
    out = []
    for cam, tracks in seq.tracks.items():
        R, o = poses[cam][tracks.frames, :3, :3], poses[cam][tracks.frames, :3, 3]
        in_cam = np.einsum("nji,nj->ni", R, points[cam] - o)
        out.append(robot.cameras[cam].project(in_cam).ravel())
    return np.concatenate(out)


def _robot_with(robot: Robot, cal: np.ndarray) -> Robot:
    return Robot([Segment(s.length, k, d, s.theta_max)
                  for s, (k, d) in zip(robot.segments, cal.reshape(-1, 2), strict=True)],
                 robot.cameras)


def dense_fisher(robot: Robot, sim: Simulation, noise_px: float,
                 theta0_sigma: float | None,
                 calibration_sigmas: tuple[float, float] | None = None) -> np.ndarray:
    """Fisher information of the angles (and, with ``calibration_sigmas``, of every segment's
    k and delta_max, after them) from central differences of the pixel predictions in (all
    angles, [calibration,] one point per camera and track id), the points eliminated exactly."""
    seq = sim.sequence
    n_frames, S = seq.thetas.shape
    points = {c: sim.points_world[sim.landmarks[c]] for c in seq.tracks}
    h = 1e-6
    n_rows = sum(len(t) for t in seq.tracks.values())
    n_cal = 0 if calibration_sigmas is None else 2 * S
    Ja = np.zeros((2 * n_rows, n_frames * S + n_cal))
    for f in range(n_frames):
        for j in range(S):
            plus, minus = seq.thetas.copy(), seq.thetas.copy()
            plus[f, j] += h
            minus[f, j] -= h
            Ja[:, f * S + j] = (_pixels(robot, sim, plus, points)
                                - _pixels(robot, sim, minus, points)) / (2 * h)
    cal = np.array([[s.k, s.delta_max] for s in robot.segments]).ravel()
    for c in range(n_cal):
        plus, minus = cal.copy(), cal.copy()
        plus[c] += h
        minus[c] -= h
        Ja[:, n_frames * S + c] = (_pixels(_robot_with(robot, plus), sim, seq.thetas, points)
                                   - _pixels(_robot_with(robot, minus), sim, seq.thetas,
                                             points)) / (2 * h)
    # Point columns: (camera, track id) -> 3 columns; each row sees its own track's point only,
    # so all points move at once per axis.
    row_point, n_points = [], 0
    for tracks in seq.tracks.values():
        ids, index = np.unique(tracks.track_ids, return_inverse=True)
        row_point.append(n_points + index)
        n_points += len(ids)
    row_point = np.repeat(np.concatenate(row_point), 2)
    Jp = np.zeros((2 * n_rows, 3 * n_points))
    for a in range(3):
        plus = {c: p.copy() for c, p in points.items()}
        minus = {c: p.copy() for c, p in points.items()}
        for c in points:
            plus[c][:, a] += h
            minus[c][:, a] -= h
        Jp[np.arange(2 * n_rows), 3 * row_point + a] = (
            _pixels(robot, sim, seq.thetas, plus) - _pixels(robot, sim, seq.thetas, minus)) / (
            2 * h)
    inlier = np.repeat(np.concatenate([~sim.outliers[c] for c in seq.tracks]), 2)
    Ja, Jp, row_point = Ja[inlier] / noise_px, Jp[inlier] / noise_px, row_point[inlier]
    info = Ja.T @ Ja
    # Eliminate the points: J_a^T (I - P) J_a with P the projector onto range(J_p). J_p is
    # block diagonal (rows of a point, its three columns), so the projector is the sum of each
    # point's; each is exact (SVD, rank-revealing: a point seen once has rank 2).
    for p in np.unique(row_point):
        rows = row_point == p
        U, s, _ = np.linalg.svd(Jp[rows][:, 3 * p:3 * p + 3], full_matrices=False)
        QJ = U[:, s > 1e-9 * s.max()].T @ Ja[rows]
        info -= QJ.T @ QJ
    if theta0_sigma is not None:
        info[np.arange(S), np.arange(S)] += 1.0 / theta0_sigma**2
    if calibration_sigmas is not None:
        D0 = n_frames * S
        info[D0 + np.arange(n_cal), D0 + np.arange(n_cal)] += np.tile(
            1.0 / np.asarray(calibration_sigmas) ** 2, S)
    return info


def test_fisher_information_is_the_dense_numerical_one(robot: Robot) -> None:
    """Fails at fc393d6 by ~9e-5 of max |I| (sigmas ~1.2e-4 too small): reduced_system adds
    ``1e-9 trace(C_t) + 1e-12`` to each point block before the Schur complement, which drops
    part of the depth direction of small-parallax tracks. The dense Fisher with that same
    jitter matches to ~2e-9."""
    sim = simulate(robot, 8, noise_px=1.0, seed=3, scene="room", n_points=300,
                   moving_base=True)
    assert all(len(t) > 50 for t in sim.sequence.tracks.values())
    want = dense_fisher(robot, sim, 1.0, PRIOR)
    info = fisher_information(sim, 1.0, PRIOR)
    assert info.shape == (24, 24)
    np.testing.assert_allclose(info, info.T, rtol=0, atol=1e-12 * np.abs(info).max())
    np.testing.assert_allclose(info, want, rtol=0, atol=1e-5 * np.abs(want).max())
    bound = sequence_bound(sim, 1.0, PRIOR)
    np.testing.assert_allclose(bound.sigmas,
                               np.sqrt(np.diag(np.linalg.inv(want))).reshape(8, 3), rtol=1e-5)


def test_bound_is_the_root_of_the_inverse_diagonal(robot: Robot) -> None:
    sim = simulate(robot, 12, noise_px=1.0, seed=4, scene="room", n_points=400,
                   moving_base=True)
    for noise, prior in [(1.0, PRIOR), (0.5, 1e-3)]:
        info = fisher_information(sim, noise, prior)
        bound = sequence_bound(sim, noise, prior)
        assert bound.theta0_sigma == prior and bound.sigmas.shape == (12, 3)
        np.testing.assert_allclose(bound.sigmas,
                                   np.sqrt(np.diag(np.linalg.inv(info))).reshape(12, 3),
                                   rtol=1e-9)
        assert np.all(bound.sigmas[0] < prior)


def test_bound_scales_with_the_pixel_noise(robot: Robot) -> None:
    sim = simulate(robot, 10, noise_px=1.0, seed=5, scene="room", n_points=400)
    one = fisher_information(sim, 1.0, None)
    # (Not to the last digit: the factor's point blocks carry an absolute 1e-12 jitter.)
    np.testing.assert_allclose(fisher_information(sim, 2.5, None), one / 2.5**2, rtol=0,
                               atol=1e-9 * np.abs(one).max())
    np.testing.assert_allclose(sequence_bound(sim, 2.5, None).sigmas,
                               2.5 * sequence_bound(sim, 1.0, None).sigmas, rtol=1e-8)
    for bad in (0.0, -1.0, math.nan):
        with pytest.raises(ValueError, match="noise_px"):
            fisher_information(sim, bad)


def test_a_frame_no_camera_saw_is_undetermined(robot: Robot) -> None:
    sim = simulate(robot, 10, noise_px=1.0, seed=6, scene="room", n_points=400)
    blind = 4
    cut = keep_rows(sim, {c: t.frames != blind for c, t in sim.sequence.tracks.items()})
    bound = sequence_bound(cut, 1.0)
    assert np.all(np.isinf(bound.sigmas[blind]))
    others = np.delete(np.arange(10), blind)
    assert np.all(np.isfinite(bound.sigmas[others]))
    info = fisher_information(cut, 1.0)
    index = (others[:, None] * 3 + np.arange(3)).ravel()
    want = np.sqrt(np.diag(np.linalg.inv(info[np.ix_(index, index)]))).reshape(9, 3)
    np.testing.assert_allclose(bound.sigmas[others], want, rtol=1e-6)


def test_the_lag_bound_past_a_frame_no_camera_saw(robot: Robot) -> None:
    """A blind frame inside the lag leaves every other frame its bound (it was inf for all of
    them while the blind frame was within reach): each sampled frame's is the inverse of the
    information of the frames up to its lag, the blind one left out."""
    sim = simulate(robot, 12, noise_px=1.0, seed=6, scene="room", n_points=400)
    blind, lag = 5, 3
    cut = keep_rows(sim, {c: t.frames != blind for c, t in sim.sequence.tracks.items()})
    bound = lag_bound(cut, 1.0, lag, step=1)
    assert np.all(np.isinf(bound.sigmas[blind]))
    for f in np.delete(np.arange(12), blind):
        last = min(f + lag, 11)
        info = fisher_information(cut, 1.0, last_frame=last)
        seen = [g for g in range(last + 1) if g != blind]
        index = (np.array(seen)[:, None] * 3 + np.arange(3)).ravel()
        inverse = np.linalg.inv(info[np.ix_(index, index)])
        at = seen.index(f)
        want = np.sqrt(np.diag(inverse)[3 * at:3 * at + 3])
        np.testing.assert_allclose(bound.sigmas[f], want, rtol=1e-6, err_msg=str(f))
    picked = lag_bound(cut, 1.0, lag, frames=[3, blind, 8])
    np.testing.assert_array_equal(picked.frames, [3, blind, 8])
    np.testing.assert_allclose(picked.sigmas, bound.sigmas[[3, blind, 8]])
    for bad in ([8, 3], [3, 3], [12], [-1, 2]):
        with pytest.raises(ValueError, match=r"frames = .*expected ascending frames in 0 \.\. 11"):
            lag_bound(cut, 1.0, lag, frames=bad)


# -------------------------------------------------------------------------------- outliers
def test_outlier_rows_carry_no_information(robot: Robot) -> None:
    sim = simulate(robot, 10, noise_px=1.0, outlier_fraction=0.2, seed=7, scene="room",
                   n_points=400, moving_base=True)
    assert all(sim.outliers[c].sum() > 20 for c in sim.sequence.tracks)
    bound = sequence_bound(sim, 1.0)
    # Without the outlier rows at all: the same bound.
    clean = keep_rows(sim, {c: ~sim.outliers[c] for c in sim.sequence.tracks})
    np.testing.assert_allclose(sequence_bound(clean, 1.0).sigmas, bound.sigmas, rtol=1e-12)
    # Whatever the outlier rows' (true) pixels say: the same bound.
    rng = np.random.default_rng(7)
    moved = {c: np.where(sim.outliers[c][:, None], rng.uniform(0.0, 400.0, uv.shape), uv)
             for c, uv in sim.clean_uv.items()}
    np.testing.assert_allclose(sequence_bound(dataclasses.replace(sim, clean_uv=moved),
                                              1.0).sigmas, bound.sigmas, rtol=1e-12)
    # Flagging more rows as outliers loses information: no angle's bound shrinks.
    more = {c: flags | (rng.random(len(flags)) < 0.15) for c, flags in sim.outliers.items()}
    fewer = sequence_bound(dataclasses.replace(sim, outliers=more), 1.0)
    assert np.all(fewer.sigmas >= bound.sigmas * (1.0 - 1e-12))
    assert np.any(fewer.sigmas > bound.sigmas * 1.01)


# ----------------------------------------------------------------------- cut tracks, prior
def test_cut_tracks_give_a_larger_bound(robot: Robot) -> None:
    sim = simulate(robot, 24, noise_px=1.0, seed=8, scene="room", n_points=400,
                   moving_base=True)
    whole = sequence_bound(sim, 1.0)
    for cut in (3, 8):
        short = sequence_bound(sim, 1.0, max_track_frames=cut)
        assert np.all(short.sigmas >= whole.sigmas * (1.0 - 1e-12))
        assert np.any(short.sigmas > whole.sigmas * 1.01)
    info = fisher_information(sim, 1.0)
    for cut in (24, 100):
        np.testing.assert_array_equal(fisher_information(sim, 1.0, max_track_frames=cut), info)
        np.testing.assert_allclose(sequence_bound(sim, 1.0, max_track_frames=cut).sigmas,
                                   whole.sigmas, rtol=1e-12)


def test_a_looser_start_prior_gives_a_larger_bound(robot: Robot) -> None:
    sim = simulate(robot, 12, noise_px=1.0, seed=9, scene="room", n_points=400,
                   moving_base=True)
    previous = None
    for prior in (1e-4, 1e-3, 1e-2):
        bound = sequence_bound(sim, 1.0, prior)
        assert np.all(bound.sigmas[0] <= prior)
        if previous is not None:
            assert np.all(bound.sigmas >= previous * (1.0 - 1e-12))
            assert np.any(bound.sigmas > previous * 1.01)
        previous = bound.sigmas
    vision = sequence_bound(sim, 1.0, None)
    assert vision.theta0_sigma is None
    assert np.all(vision.sigmas >= previous * (1.0 - 1e-12))


# ---------------------------------------------------------------------------- summaries
def test_rms_and_window_rms_by_hand() -> None:
    sigmas = np.arange(1.0, 31.0).reshape(10, 3)
    bound = SequenceBound(sigmas, None)
    np.testing.assert_allclose(bound.rms(), [math.sqrt(np.mean(sigmas[:, j] ** 2))
                                             for j in range(3)], rtol=1e-15)
    # Frames 2..4, angle 1: 8, 11, 14.
    assert bound.rms(slice(2, 5))[1] == pytest.approx(math.sqrt((64 + 121 + 196) / 3))
    windows = bound.window_rms(4)
    assert windows.shape == (3, 3)
    # Angle 0 over frames 0-3: 1, 4, 7, 10; 4-7: 13, 16, 19, 22; 8-9: 25, 28.
    np.testing.assert_allclose(windows[:, 0], [math.sqrt((1 + 16 + 49 + 100) / 4),
                                               math.sqrt((169 + 256 + 361 + 484) / 4),
                                               math.sqrt((625 + 784) / 2)], rtol=1e-15)
    np.testing.assert_allclose(bound.window_rms(10), bound.rms()[None], rtol=1e-15)
    np.testing.assert_allclose(bound.window_rms(1), sigmas, rtol=1e-15)
    assert bound.window_rms().shape == (1, 3)


# ------------------------------------------------------------------ unknown segment models


def test_calibration_information_is_the_dense_numerical_one(robot: Robot) -> None:
    """The calibration rows and columns of the Fisher information against central differences
    of the pixel predictions in each segment's (k, delta_max), points eliminated exactly."""
    sim = simulate(robot, 8, noise_px=1.0, seed=3, scene="room", n_points=300,
                   moving_base=True)
    S, D0 = 3, 8 * 3
    sigmas = (0.05, math.radians(5.0))
    info = fisher_information(sim, 1.0, PRIOR, calibration_sigmas=sigmas)
    assert info.shape == (D0 + 2 * S,) * 2
    np.testing.assert_allclose(info[:D0, :D0], fisher_information(sim, 1.0, PRIOR),
                               rtol=0, atol=1e-9 * np.abs(info).max())
    want = dense_fisher(robot, sim, 1.0, PRIOR, calibration_sigmas=sigmas)
    np.testing.assert_allclose(info, want, rtol=0, atol=1e-5 * np.abs(want).max())


def test_unknown_segment_models_raise_the_bound(robot: Robot) -> None:
    sim = simulate(robot, 30, noise_px=1.0, seed=6, scene="room", n_points=400)
    known = sequence_bound(sim, 1.0, PRIOR)
    assert known.calibration is None
    sigmas = (0.05, math.radians(5.0))
    unknown = sequence_bound(sim, 1.0, PRIOR, calibration_sigmas=sigmas)
    assert unknown.calibration.shape == (3, 2)
    assert np.all(unknown.sigmas >= known.sigmas * (1 - 1e-9))
    assert np.any(unknown.sigmas > 1.05 * known.sigmas)
    # The data add to the priors: each calibration bound is below its prior.
    assert np.all(unknown.calibration < np.array(sigmas) * (1 + 1e-9))
    # A tight prior on the models gives back the known-model bound.
    tight = sequence_bound(sim, 1.0, PRIOR, calibration_sigmas=(1e-9, 1e-9))
    np.testing.assert_allclose(tight.sigmas, known.sigmas, rtol=1e-4)


def test_spatial_information_holds_the_planar_one(robot: Robot) -> None:
    """On a planar recording, the spatial information's block of the u components is the
    planar information (u is theta there, the points are eliminated the same way), and the
    v components (out of the plane) are determined too."""
    sim = simulate(robot, 10, noise_px=1.0, seed=5, scene="room", n_points=400)
    planar = fisher_information(sim, 1.0, PRIOR)
    spatial = fisher_information(sim, 1.0, PRIOR, spatial=True)
    assert spatial.shape == (60, 60)
    np.testing.assert_allclose(spatial, spatial.T, rtol=0, atol=1e-12 * np.abs(spatial).max())
    u = np.arange(0, 60, 2)
    np.testing.assert_allclose(spatial[np.ix_(u, u)], planar, rtol=0,
                               atol=1e-9 * np.abs(planar).max())
    bound = sequence_bound(sim, 1.0, PRIOR, spatial=True)
    assert bound.components is not None and bound.components.shape == (10, 6)
    assert np.all(np.isfinite(bound.components))
    pairs = bound.components.reshape(10, 3, 2)
    np.testing.assert_allclose(bound.sigmas, np.sqrt(np.sum(pairs**2, axis=-1)))
    # more unknowns, never a smaller bound on u than on the planar angle
    assert np.all(pairs[..., 0] >= sequence_bound(sim, 1.0, PRIOR).sigmas * (1 - 1e-9))


def test_spatial_bound_of_a_spatial_recording(robot: Robot) -> None:
    sim = simulate(robot, 10, noise_px=1.0, seed=6, scene="room", n_points=400, spatial=True)
    bound = sequence_bound(sim, 1.0, PRIOR, spatial=True)
    assert np.all(np.isfinite(bound.sigmas)) and np.all(bound.sigmas > 0)
    loose = sequence_bound(sim, 1.0, 10 * PRIOR, spatial=True)
    assert np.all(loose.sigmas >= bound.sigmas * (1 - 1e-9))
    # The planes free and the models unknown: two calibration columns per segment after the
    # bending vectors', and the data add to the priors.
    sigmas = (0.05, 0.1)
    info = fisher_information(sim, 1.0, PRIOR, calibration_sigmas=sigmas, spatial=True)
    assert info.shape == (10 * 6 + 6,) * 2
    unknown = sequence_bound(sim, 1.0, PRIOR, calibration_sigmas=sigmas, spatial=True)
    assert unknown.calibration.shape == (3, 2)
    assert np.all(unknown.calibration < np.array(sigmas))
    assert np.all(unknown.sigmas >= bound.sigmas * (1 - 1e-9))
    # A robot that bends out of its plane has no planar bound.
    with pytest.raises(ValueError, match="bends out of the plane"):
        fisher_information(sim, 1.0, PRIOR)
