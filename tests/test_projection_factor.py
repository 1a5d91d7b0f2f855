"""Projection factor in joint space: camera chain poses and derivatives, track grouping, vectorised
triangulation, the reduced (points eliminated) Gauss-Newton system against a dense numerical
Schur complement, its compression, the gtsam factor and its convergence, chunking."""

from __future__ import annotations

import math
from pathlib import Path

import gtsam
import numpy as np
import pytest
from helpers import factor_hessian, random_pose
from hypothesis import given, settings
from hypothesis import strategies as st

from apcc_graph import Robot, Segment, TipCamera
from apcc_graph.factors.camera_chain import CameraChain, camera_poses
from apcc_graph.factors.keys import frame_key
from apcc_graph.factors.projection import (
    ProjectionFactor,
    build_observations,
    chunk_tracks,
    compress,
)
from apcc_graph.factors.reduced_system import reduced_system
from apcc_graph.factors.track_points import MIN_DEPTH, TrackObservations
from apcc_graph.factors.triangulation import triangulate
from apcc_graph.io.robot_file import load_robot
from apcc_graph.model.parameterisation import Bending
from apcc_graph.simulation.simulator import simulate

ROBOT = Path(__file__).resolve().parents[1] / "data/robots/planar_three.toml"
SEGMENTS = (Segment(0.3, k=0.2, delta_max=0.1, theta_max=1.0),
            Segment(0.3, k=0.3, delta_max=-0.05, theta_max=1.0),
            Segment(0.25, k=0.25, delta_max=0.03, theta_max=1.0))


@pytest.fixture(scope="module")
def lens_robot() -> Robot:
    """Cameras on segments 1 and 2 with a tilted, shifted mounting and a distorting lens."""
    rng = np.random.default_rng(0)
    cam = TipCamera(500.0, 490.0, 320.0, 240.0, 640, 480,
                    distortion=(-0.2, 0.05, 1e-3, -1e-3), tip_T_cam=random_pose(rng, 0.2, 0.02))
    return Robot(SEGMENTS, [None, cam, cam])


def random_bases(rng: np.random.Generator, n: int) -> np.ndarray:
    return np.stack([random_pose(rng, 0.3, 0.2) for _ in range(n)])


def camera_observations(robot: Robot, sequence, cam: int, noise_px: float = 1.0,
                        keep: np.ndarray | None = None) -> TrackObservations:
    """A camera's rows as the factor takes them: undistorted normalised points, whitening."""
    camera = robot.cameras[cam]
    tracks = sequence.tracks[cam]
    xy = camera.normalized(tracks.uv)
    return build_observations(cam, tracks.frames, tracks.track_ids, xy,
                              camera.pixel_jacobian(xy) / noise_px, keep)


def bending_of(robot: Robot, sequence) -> Bending:
    """The parameterisation a sequence's truth is in: free planes if it bends in 3-D."""
    return (Bending.fixed(robot.segments) if sequence.psis is None
            else Bending.free(robot.segments))


def truth_of(robot: Robot, sequence) -> np.ndarray:
    """``(F, dim)`` the sequence's true frame vectors."""
    return bending_of(robot, sequence).vector(sequence.thetas, sequence.psis)


def camera_chain(robot: Robot, sequence, cam: int) -> CameraChain:
    return CameraChain(bending_of(robot, sequence).head(cam + 1), robot.cameras[cam].tip_T_cam,
                       sequence.world_T_base)


def parameterised(kind: str, rng: np.random.Generator, n_frames: int, n: int
                  ) -> tuple[Bending, np.ndarray, np.ndarray, np.ndarray | None]:
    """A parameterisation of ``SEGMENTS[:n]`` (``"planar"``: fixed planes at 0, ``"fixed"``:
    random fixed planes, ``"free"``: bending vectors), random frame vectors in it, and the same
    bends as ``(thetas, psis)`` for the robot's own kinematics."""
    thetas = rng.uniform(-1.0, 1.0, (n_frames, n))
    if kind == "planar":
        return Bending.fixed(SEGMENTS[:n]), thetas, thetas, None
    if kind == "fixed":
        planes = rng.uniform(-math.pi, math.pi, n)
        return (Bending.fixed(SEGMENTS[:n], planes), thetas, thetas,
                np.broadcast_to(planes, thetas.shape))
    psis = rng.uniform(-math.pi, math.pi, (n_frames, n))
    bending = Bending.free(SEGMENTS[:n])
    return bending, bending.vector(thetas, psis), thetas, psis


# ------------------------------------------------------------------------------ camera_poses
@pytest.mark.parametrize("base", ["none", "fixed", "moving"])
@pytest.mark.parametrize("kind", ["planar", "fixed", "free"])
def test_camera_poses_equal_the_robots(base: str, kind: str) -> None:
    rng = np.random.default_rng(1)
    mounts = [random_pose(rng, 0.3, 0.05) for _ in range(3)]
    robot = Robot(SEGMENTS, [TipCamera(500.0, 500.0, 320.0, 240.0, 640, 480, tip_T_cam=m)
                             for m in mounts])
    n_frames = 9
    bending, x, thetas, psis = parameterised(kind, rng, n_frames, 3)
    world_T_base = {"none": None, "fixed": random_pose(rng, 0.5, 0.3),
                    "moving": random_bases(rng, n_frames)}[base]
    expected = robot.camera_poses(thetas, psis, world_T_base)
    tips = robot.forward(thetas, psis, world_T_base)
    for cam in range(3):
        n = cam + 1
        head = bending.head(n)
        poses, d_poses = camera_poses(x[:, :head.dim], head, mounts[cam], world_T_base)
        assert poses.shape == (n_frames, 4, 4)
        assert d_poses.shape == (n_frames, head.dim, 4, 4)
        np.testing.assert_allclose(poses, expected[cam], atol=1e-12)
        np.testing.assert_allclose(poses, tips[:, cam] @ mounts[cam], atol=1e-12)
        plain, none = camera_poses(x[:, :head.dim], head, mounts[cam], world_T_base,
                                   derivatives=False)
        assert none is None
        np.testing.assert_array_equal(plain, poses)
    with pytest.raises(ValueError, match="columns"):
        camera_poses(x, bending.head(2), mounts[0])


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), kind=st.sampled_from(["planar", "fixed", "free"]),
       cam=st.integers(0, 2))
def test_camera_pose_derivatives_match_central_differences(seed: int, kind: str,
                                                           cam: int) -> None:
    rng = np.random.default_rng(seed)
    n, n_frames = cam + 1, 4
    mount = random_pose(rng, 0.4, 0.05)
    bending, thetas, _, _ = parameterised(kind, rng, n_frames, n)
    base = random_bases(rng, n_frames)
    _, d_poses = camera_poses(thetas, bending, mount, base)
    np.testing.assert_array_equal(d_poses[..., 3, :], 0.0)
    h = 1e-6
    for j in range(bending.dim):
        for f in range(n_frames):
            plus, minus = thetas.copy(), thetas.copy()
            plus[f, j] += h
            minus[f, j] -= h
            numeric = (camera_poses(plus, bending, mount, base, False)[0]
                       - camera_poses(minus, bending, mount, base, False)[0]) / (2 * h)
            # Frame f's angle moves frame f only.
            np.testing.assert_allclose(numeric[f], d_poses[f, j], atol=1e-8)
            others = np.delete(numeric, f, axis=0)
            np.testing.assert_array_equal(others, 0.0)


# ------------------------------------------------------------------------ TrackObservations
@settings(max_examples=100, deadline=None)
@given(pairs=st.sets(st.tuples(st.integers(0, 40), st.integers(0, 25)), min_size=1,
                     max_size=80),
       data=st.data())
def test_build_groups_rows_by_track_and_frame(pairs: set, data: st.DataObject) -> None:
    rows = data.draw(st.permutations(sorted(pairs)))
    ids = np.array([p[0] for p in rows])
    frames = np.array([p[1] for p in rows])
    # Each row's payload names its (id, frame), so the rows can be followed through the sort.
    xy = np.column_stack([ids + 0.5, frames * 10.0])
    whiten = np.zeros((len(rows), 2, 2))
    whiten[:, 0, 0], whiten[:, 1, 1], whiten[:, 0, 1] = ids, frames, 1.0
    obs = TrackObservations.build(4, frames, ids, xy, whiten)
    N = len(rows)
    assert len(obs) == N and obs.camera == 4
    np.testing.assert_array_equal(obs.ids, np.unique(ids))
    assert obs.n_tracks == len(obs.ids)
    # Rows sorted by (track, frame); tracks compact and non-decreasing.
    key = obs.tracks * 100 + obs.frames
    assert np.all(np.diff(key) > 0)
    np.testing.assert_array_equal(np.unique(obs.tracks), np.arange(obs.n_tracks))
    # Payload still with its row.
    np.testing.assert_array_equal(obs.xy[:, 0], obs.ids[obs.tracks] + 0.5)
    np.testing.assert_array_equal(obs.xy[:, 1], obs.frames * 10.0)
    np.testing.assert_array_equal(obs.whiten[:, 0, 0], obs.ids[obs.tracks])
    np.testing.assert_array_equal(obs.whiten[:, 1, 1], obs.frames)
    assert sorted(zip(obs.ids[obs.tracks].tolist(), obs.frames.tolist(), strict=True)) == sorted(
        pairs)
    # starts: offsets of each track's rows.
    assert obs.starts[0] == 0 and obs.starts[-1] == N and len(obs.starts) == obs.n_tracks + 1
    for t in range(obs.n_tracks):
        np.testing.assert_array_equal(obs.tracks[obs.starts[t]:obs.starts[t + 1]], t)
        assert obs.starts[t + 1] > obs.starts[t]
    # select: all tracks round trip; a subset equals building its rows afresh.
    whole = obs.select(np.arange(obs.n_tracks))
    for name in ("frames", "tracks", "xy", "whiten", "ids", "starts"):
        np.testing.assert_array_equal(getattr(whole, name), getattr(obs, name))
    subset = np.flatnonzero(data.draw(st.lists(st.booleans(), min_size=obs.n_tracks,
                                               max_size=obs.n_tracks)))
    part = obs.select(subset)
    in_subset = np.isin(ids, obs.ids[subset])
    fresh = TrackObservations.build(4, frames[in_subset], ids[in_subset], xy[in_subset],
                                    whiten[in_subset])
    assert part.n_tracks == len(subset) and len(part) == in_subset.sum()
    for name in ("frames", "tracks", "xy", "whiten", "ids", "starts"):
        np.testing.assert_array_equal(getattr(part, name), getattr(fresh, name))


def test_build_rejects_a_track_twice_in_a_frame_and_ragged_input() -> None:
    xy, whiten = np.zeros((3, 2)), np.tile(np.eye(2), (3, 1, 1))
    with pytest.raises(ValueError, match="twice in one frame"):
        TrackObservations.build(0, [2, 5, 2], [7, 7, 7], xy, whiten)
    with pytest.raises(ValueError, match="rows"):
        TrackObservations.build(0, [1, 2], [7, 7, 7], xy, whiten)
    ok = TrackObservations.build(0, [2, 5, 2], [7, 7, 8], xy, whiten)  # same frame, two tracks
    assert ok.n_tracks == 2


# ------------------------------------------------------------------------------ triangulate
def _rig(rng: np.random.Generator, n_frames: int, n_points: int, baseline: float,
         rotate: float = 0.05):
    """Camera poses within a few centimetres and points 1-4 m in front of them."""
    poses = np.stack([random_pose(rng, rotate, 0.0) for _ in range(n_frames)])
    poses[:, :3, 3] = rng.uniform(-baseline, baseline, (n_frames, 3))
    ray = np.column_stack([rng.uniform(-0.4, 0.4, (n_points, 2)), np.ones(n_points)])
    points = ray / np.linalg.norm(ray, axis=1, keepdims=True) * rng.uniform(1.0, 4.0,
                                                                           n_points)[:, None]
    return poses, points


def _observe(poses: np.ndarray, points: np.ndarray, frames: np.ndarray, ids: np.ndarray):
    R, o = poses[frames, :3, :3], poses[frames, :3, 3]
    q = np.einsum("nji,nj->ni", R, points[ids] - o)
    return q[:, :2] / q[:, 2:]


def _rows(rng: np.random.Generator, n_frames: int, n_points: int, min_rows: int = 2):
    frames, ids = [], []
    for t in range(n_points):
        seen = rng.choice(n_frames, rng.integers(min_rows, n_frames + 1), replace=False)
        frames.extend(seen.tolist())
        ids.extend([t] * len(seen))
    return np.array(frames), np.array(ids)


def test_triangulate_recovers_noise_free_points() -> None:
    rng = np.random.default_rng(2)
    poses, points = _rig(rng, 8, 60, baseline=0.03)
    frames, ids = _rows(rng, 8, 60)
    whiten = np.tile(500.0 * np.eye(2), (len(frames), 1, 1))
    obs = TrackObservations.build(0, frames, ids, _observe(poses, points, frames, ids), whiten)
    R, o = poses[obs.frames, :3, :3], poses[obs.frames, :3, 3]
    got = triangulate(obs, R, o, np.ones(len(obs)))
    np.testing.assert_allclose(got, points[obs.ids], atol=1e-6)
    # Started from a previous solution (moved by a few cm) it gets there too.
    again = triangulate(obs, R, o, np.ones(len(obs)), got + rng.normal(0.0, 0.03, got.shape))
    np.testing.assert_allclose(again, points[obs.ids], atol=1e-6)


def test_zero_weight_outlier_rows_do_not_move_the_points() -> None:
    rng = np.random.default_rng(3)
    n_frames, n_points = 10, 50
    poses, points = _rig(rng, n_frames, n_points, baseline=0.04)
    frames, ids = _rows(rng, n_frames, n_points, min_rows=3)
    xy = _observe(poses, points, frames, ids) + rng.normal(0.0, 1e-4, (len(frames), 2))
    # Outliers: extra rows in the frames a track was not seen in, at random pixels; several of
    # them are a track's first row (its anchor).
    out_frames, out_ids = [], []
    for t in range(n_points):
        free = np.setdiff1d(np.arange(n_frames), frames[ids == t])
        if len(free):
            out_frames.append(int(free[0]))
            out_ids.append(t)
    out_frames, out_ids = np.array(out_frames), np.array(out_ids)
    out_xy = rng.uniform(-0.6, 0.6, (len(out_ids), 2))
    all_frames = np.concatenate([frames, out_frames])
    all_ids = np.concatenate([ids, out_ids])
    all_xy = np.concatenate([xy, out_xy])
    weights = np.concatenate([np.ones(len(frames)), np.zeros(len(out_frames))])
    whiten = 500.0 * np.eye(2) * rng.uniform(0.5, 2.0, (len(all_ids), 1, 1))
    order = rng.permutation(len(all_ids))
    mixed = TrackObservations.build(0, all_frames[order], all_ids[order], all_xy[order],
                                    whiten[order])
    # The weights travel with the rows: rebuild them in the sorted order.
    w_of = {(int(i), int(f)): w for i, f, w in zip(all_ids, all_frames, weights, strict=True)}
    w_sorted = np.array([w_of[(int(mixed.ids[t]), int(f))]
                         for t, f in zip(mixed.tracks, mixed.frames, strict=True)])
    assert np.any(w_sorted[mixed.starts[:-1]] == 0.0)
    clean = TrackObservations.build(0, frames, ids, xy, whiten[:len(frames)])
    got = triangulate(mixed, poses[mixed.frames, :3, :3], poses[mixed.frames, :3, 3], w_sorted)
    want = triangulate(clean, poses[clean.frames, :3, :3], poses[clean.frames, :3, 3],
                       np.ones(len(clean)))
    np.testing.assert_array_equal(mixed.ids, clean.ids)
    np.testing.assert_allclose(got, want, atol=1e-8)
    np.testing.assert_allclose(want, points, atol=0.1)  # and near the truth


def test_a_track_without_parallax_gets_a_finite_point_in_front() -> None:
    rng = np.random.default_rng(4)
    poses, points = _rig(rng, 6, 5, baseline=0.0, rotate=0.1)  # cameras rotate in place
    poses[:, :3, 3] = [0.1, -0.2, 0.3]
    points = points + poses[0, :3, 3]
    frames, ids = _rows(rng, 6, 5)
    xy = _observe(poses, points, frames, ids)
    obs = TrackObservations.build(1, frames, ids, xy, np.tile(500.0 * np.eye(2),
                                                              (len(frames), 1, 1)))
    R, o = poses[obs.frames, :3, :3], poses[obs.frames, :3, 3]
    got = triangulate(obs, R, o, np.ones(len(obs)))
    assert np.all(np.isfinite(got))
    q = np.einsum("nji,nj->ni", R, got[obs.tracks] - o)
    assert np.all(q[:, 2] > MIN_DEPTH)
    # Noise-free rays meet at every depth: the point lies on them.
    np.testing.assert_allclose(q[:, :2] / q[:, 2:], obs.xy, atol=1e-9)


# -------------------------------------------------------------------------- reduced_system
def _residuals(robot: Robot, cam: int, sequence, x: np.ndarray, points: np.ndarray,
               obs: TrackObservations) -> np.ndarray:
    """Stacked whitened residuals ``W_k (m(R^T (p - o)) - x_k)``, poses from the robot at
    frame vectors ``x`` (:func:`bending_of` the sequence)."""
    thetas, psis = bending_of(robot, sequence).polar(x)
    poses = robot.camera_poses(thetas, psis, sequence.world_T_base)[cam]
    R, o = poses[obs.frames, :3, :3], poses[obs.frames, :3, 3]
    q = np.einsum("nji,nj->ni", R, points[obs.tracks] - o)
    return np.einsum("nij,nj->ni", obs.whiten, q[:, :2] / q[:, 2:] - obs.xy).ravel()


def _dense_schur(robot: Robot, cam: int, sequence, thetas: np.ndarray, points: np.ndarray,
                 obs: TrackObservations, h: float = 1e-6):
    """H, g and the stacked residual from central differences in (angles, points), the points
    eliminated exactly."""
    n_frames, n = len(thetas), bending_of(robot, sequence).head(cam + 1).dim
    r = _residuals(robot, cam, sequence, thetas, points, obs)
    Ja = np.zeros((len(r), n_frames * n))
    for f in range(n_frames):
        for j in range(n):
            plus, minus = thetas.copy(), thetas.copy()
            plus[f, j] += h
            minus[f, j] -= h
            Ja[:, f * n + j] = (_residuals(robot, cam, sequence, plus, points, obs)
                                - _residuals(robot, cam, sequence, minus, points, obs)) / (2 * h)
    Jp = np.zeros((len(r), 3 * obs.n_tracks))
    row_track = np.repeat(obs.tracks, 2)
    for a in range(3):  # a row depends on its own track's point only
        plus, minus = points.copy(), points.copy()
        plus[:, a] += h
        minus[:, a] -= h
        Jp[np.arange(len(r)), 3 * row_track + a] = (
            _residuals(robot, cam, sequence, thetas, plus, obs)
            - _residuals(robot, cam, sequence, thetas, minus, obs)) / (2 * h)
    # Eliminate the points: H = J_a^T (I - P) J_a, g = J_a^T (I - P) r with P the projector
    # onto range(J_p). J_p is block diagonal (a track's rows, its point's three columns), so P is
    # the sum of each track's projector, each exact (SVD, rank-revealing: a track seen once has
    # rank 2).
    H, g = Ja.T @ Ja, Ja.T @ r
    for t in range(obs.n_tracks):
        rows = row_track == t
        U, s, _ = np.linalg.svd(Jp[rows][:, 3 * t:3 * t + 3], full_matrices=False)
        Q = U[:, s > 1e-9 * s.max()]
        QJ, Qr = Q.T @ Ja[rows], Q.T @ r[rows]
        H -= QJ.T @ QJ
        g -= QJ.T @ Qr
    return H, g, r


FAST = 5.0
"""Frame rate (fps) of the simulations below: the robot moves six times as far per frame as at
30 fps, so that a dozen frames give the tracks parallax and every point a depth in the scene.
(With little parallax, 1 px noise may put a track's best point behind its cameras; see
test_reduced_cost_is_a_function_of_the_angles_alone.)"""


def _assert_points_in_scene(points: np.ndarray, sequence) -> None:
    """Precondition of the comparisons: no track's point went off to infinity."""
    base = np.zeros(3) if sequence.world_T_base is None else sequence.world_T_base[0, :3, 3]
    assert np.max(np.linalg.norm(points - base, axis=1)) < 20.0


@pytest.mark.parametrize(("cam", "spatial"), [(1, True), (2, False)])
def test_reduced_system_is_the_dense_schur_complement(lens_robot: Robot, cam: int,
                                                      spatial: bool) -> None:
    sim = simulate(lens_robot, 12, noise_px=1.0, seed=5 + cam, scene="room", n_points=400,
                   moving_base=True, spatial=spatial, fps=FAST)
    seq = sim.sequence
    obs = camera_observations(lens_robot, seq, cam)
    assert obs.n_tracks > 20 and np.min(np.diff(obs.starts)) <= 2  # short tracks too
    rng = np.random.default_rng(cam)
    truth = truth_of(lens_robot, seq)
    thetas = truth + rng.normal(0.0, 0.003, truth.shape)
    chain = camera_chain(lens_robot, seq, cam)
    out = reduced_system(obs, chain, thetas, 0, np.ones(len(obs)))
    assert out.H.shape == (12 * chain.n_parameters,) * 2
    _assert_points_in_scene(out.points, seq)
    H, g, r = _dense_schur(lens_robot, cam, seq, thetas, out.points, obs)
    scale = np.abs(H).max()
    # Tolerance: the factor regularises each track's 3x3 point block by 1e-9 of its trace
    # (measured effect ~1e-6 of max |H| here); a wrong Jacobian or Schur term is off by orders
    # more.
    np.testing.assert_allclose(out.H, H, rtol=0, atol=1e-5 * scale)
    np.testing.assert_allclose(out.H, out.H.T, rtol=0, atol=1e-9 * scale)
    np.testing.assert_allclose(out.g, g, rtol=0, atol=1e-6 * np.abs(g).max())
    assert out.cost == pytest.approx(float(r @ r), rel=1e-9)
    norms = np.linalg.norm(r.reshape(-1, 2), axis=1)
    np.testing.assert_allclose(out.residuals, norms, rtol=1e-9, atol=1e-9)


def test_reduced_gradient_is_half_the_derivative_of_the_retriangulated_cost(
        lens_robot: Robot) -> None:
    cam = 2
    sim = simulate(lens_robot, 10, noise_px=1.0, seed=9, scene="room", n_points=400,
                   moving_base=True, fps=FAST)
    seq = sim.sequence
    obs = camera_observations(lens_robot, seq, cam)
    chain = camera_chain(lens_robot, seq, cam)
    rng = np.random.default_rng(9)
    truth = truth_of(lens_robot, seq)
    thetas = truth + rng.normal(0.0, 0.003, truth.shape)
    w = np.ones(len(obs))
    out = reduced_system(obs, chain, thetas, 0, w)
    _assert_points_in_scene(out.points, seq)
    h = 1e-6
    numeric = np.zeros_like(out.g)
    n = cam + 1
    for f in range(len(thetas)):
        for j in range(n):
            plus, minus = thetas.copy(), thetas.copy()
            plus[f, j] += h
            minus[f, j] -= h
            c_plus = reduced_system(obs, chain, plus, 0, w, out.points, jacobians=False).cost
            c_minus = reduced_system(obs, chain, minus, 0, w, out.points, jacobians=False).cost
            numeric[f * n + j] = (c_plus - c_minus) / (2 * h)
    np.testing.assert_allclose(out.g, 0.5 * numeric, rtol=0, atol=1e-5 * np.abs(out.g).max())


def test_reduced_cost_is_a_function_of_the_angles_alone() -> None:
    """The cost is the least squares over the points ("minimised over the points"): the sum of
    squared residuals at the points it returns, the same whatever the points it starts from.
    Short noisy tracks whose best point would lie behind the cameras must not break this.

    Fails at fc393d6: such a track's inverse depth sits at its clamp (points ~1e6 m away) and
    creeps on from call to call, while the cost subtracts the unreachable Gauss-Newton
    decrease ``|y_t|^2``. Here three calls of ``factor.error`` at the same values give 4088.2,
    4068.3, 4060.9; ``reduced_system`` reports a cost of 8103.7 where its own residuals at its
    points sum to 8176.4 (8136.5 when warm-started)."""
    robot = load_robot(ROBOT)
    sim = simulate(robot, 10, noise_px=1.0, seed=1, scene="room", n_points=400)
    seq = sim.sequence
    cam = 2
    obs = camera_observations(robot, seq, cam)
    chain = camera_chain(robot, seq, cam)
    thetas = seq.thetas + np.random.default_rng(1).normal(0.0, 0.01, seq.thetas.shape)
    w = np.ones(len(obs))
    # Through gtsam: the same values, the same error.
    factor = ProjectionFactor(obs, chain, robot.n_segments).factor()
    values = _values(thetas)
    errors = [factor.error(values) for _ in range(3)]
    assert errors[1] == pytest.approx(errors[0], rel=1e-6)
    assert errors[2] == pytest.approx(errors[0], rel=1e-6)
    # The reduced system: its cost is the sum of squares at its points, whatever the start.
    out = reduced_system(obs, chain, thetas, 0, w)
    again = reduced_system(obs, chain, thetas, 0, w, out.points)
    assert out.cost == pytest.approx(float(np.sum(out.residuals**2)), rel=1e-6)
    assert again.cost == pytest.approx(out.cost, rel=1e-6)


def test_cost_vanishes_at_the_truth_without_noise(lens_robot: Robot) -> None:
    sim = simulate(lens_robot, 12, noise_px=0.0, seed=11, scene="room", n_points=400,
                   moving_base=True, spatial=True)
    seq = sim.sequence
    for cam in (1, 2):
        obs = camera_observations(lens_robot, seq, cam)
        out = reduced_system(obs, camera_chain(lens_robot, seq, cam),
                             truth_of(lens_robot, seq), 0, np.ones(len(obs)))
        assert out.cost < 1e-12
        assert np.max(out.residuals) < 1e-6
        assert np.max(np.abs(out.g)) < 1e-6 * np.sqrt(np.abs(out.H).max())
        # Each track's point is the scene point behind it (where it is observed twice or more).
        tracks = seq.tracks[cam]
        order = np.lexsort((tracks.frames, tracks.track_ids))
        landmark = np.zeros(obs.n_tracks, dtype=int)
        landmark[obs.tracks] = sim.landmarks[cam][order]
        many = np.diff(obs.starts) >= 3
        np.testing.assert_allclose(out.points[many], sim.points_world[landmark[many]],
                                   atol=1e-6)


def test_zero_weights_remove_rows(lens_robot: Robot) -> None:
    cam = 1
    sim = simulate(lens_robot, 12, noise_px=1.0, outlier_fraction=0.2, seed=13, scene="room",
                   n_points=400, moving_base=True, fps=FAST)
    seq = sim.sequence
    chain = camera_chain(lens_robot, seq, cam)
    rng = np.random.default_rng(13)
    truth = truth_of(lens_robot, seq)
    thetas = truth + rng.normal(0.0, 0.003, truth.shape)
    tracks = seq.tracks[cam]
    drop = sim.outliers[cam] | (rng.random(len(tracks)) < 0.1)
    # Tracks with three kept rows or more (a point in the scene, see FAST).
    ids, kept_rows = np.unique(tracks.track_ids[~drop], return_counts=True)
    in_long = np.isin(tracks.track_ids, ids[kept_rows >= 3])
    everything = camera_observations(lens_robot, seq, cam, keep=in_long)
    kept = camera_observations(lens_robot, seq, cam, keep=in_long & ~drop)
    assert kept.n_tracks > 10 and len(everything) > len(kept)
    # Weights in the observations' row order, (track, frame); Tracks rows are (frame, track).
    order = np.lexsort((tracks.frames[in_long], tracks.track_ids[in_long]))
    dropped = drop[in_long][order]
    weights = np.where(dropped, 0.0, 1.0)
    full = reduced_system(everything, chain, thetas, 0, weights)
    part = reduced_system(kept, chain, thetas, 0, np.ones(len(kept)))
    _assert_points_in_scene(part.points, seq)
    scale = np.abs(part.H).max()
    np.testing.assert_allclose(full.H, part.H, rtol=0, atol=1e-9 * scale)
    np.testing.assert_allclose(full.g, part.g, rtol=0, atol=1e-9 * np.abs(part.g).max())
    assert full.cost == pytest.approx(part.cost, rel=1e-9)
    np.testing.assert_allclose(full.points, part.points, atol=1e-9)
    np.testing.assert_allclose(full.residuals[~dropped], part.residuals, rtol=0, atol=1e-6)
    # The rows left out still get residual norms: the outliers stand out.
    outlier = sim.outliers[cam][in_long][order]
    assert np.median(full.residuals[outlier]) > 10.0 > np.median(full.residuals[~dropped])
    # A system on the outliers too is a different one.
    polluted = reduced_system(everything, chain, thetas, 0, np.ones(len(everything)))
    assert polluted.cost > 10.0 * part.cost


# -------------------------------------------------------------------------------- compress
@pytest.mark.parametrize(("rows", "cols", "rank"), [(30, 8, 8), (30, 8, 5), (4, 9, 4)])
def test_compress_keeps_the_system_and_cost(rows: int, cols: int, rank: int) -> None:
    rng = np.random.default_rng(rows + cols + rank)
    J = rng.normal(size=(rows, rank)) @ rng.normal(size=(rank, cols))
    r = rng.normal(size=rows)
    H, g, cost = J.T @ J, J.T @ r, float(r @ r)
    A, e = compress(H, g, cost)
    assert A.shape == (cols + 1, cols) and e.shape == (cols + 1,)
    scale = np.abs(H).max()
    np.testing.assert_allclose(A.T @ A, H, rtol=0, atol=1e-10 * scale)
    np.testing.assert_allclose(A.T @ e, g, rtol=0, atol=1e-9 * np.abs(g).max())
    assert float(e @ e) == pytest.approx(cost, rel=1e-9)
    # The Gauss-Newton model |A dx + e|^2 is the least-squares one |J dx + r|^2.
    dx = rng.normal(size=cols)
    assert float(np.sum((A @ dx + e) ** 2)) == pytest.approx(float(np.sum((J @ dx + r) ** 2)),
                                                             rel=1e-9)


# ---------------------------------------------------------------------- ProjectionFactor
def _values(thetas: np.ndarray) -> gtsam.Values:
    values = gtsam.Values()
    for f, t in enumerate(thetas):
        values.insert(frame_key(f), np.asarray(t, dtype=float))
    return values


@pytest.mark.parametrize("cam", [1, 2])
def test_factor_linearises_to_the_reduced_system(lens_robot: Robot, cam: int) -> None:
    sim = simulate(lens_robot, 10, noise_px=1.0, seed=17 + cam, scene="room", n_points=400,
                   moving_base=True, fps=FAST)
    seq = sim.sequence
    obs = camera_observations(lens_robot, seq, cam)
    chain = camera_chain(lens_robot, seq, cam)
    chunk = obs.select(np.flatnonzero(obs.frames[obs.starts[:-1]] >= 2))  # frames 2..9 only
    first, last = int(chunk.frames.min()), int(chunk.frames.max())
    assert first >= 2
    rng = np.random.default_rng(cam)
    truth = truth_of(lens_robot, seq)
    thetas = truth + rng.normal(0.0, 0.003, truth.shape)
    values = _values(thetas)
    S, n = lens_robot.n_segments, cam + 1
    factor = ProjectionFactor(chunk, chain, S).factor()
    assert list(factor.keys()) == [frame_key(f) for f in range(first, last + 1)]
    want = reduced_system(chunk, chain, thetas[first:last + 1], first, np.ones(len(chunk)))
    _assert_points_in_scene(want.points, seq)
    # H in the S-dimensional frame keys: the camera's angles, zero for the segments above it.
    D = (last - first + 1) * S
    index = ((np.arange(last - first + 1) * S)[:, None] + np.arange(n)).ravel()
    H = np.zeros((D, D))
    H[np.ix_(index, index)] = want.H
    g = np.zeros(D)
    g[index] = want.g
    info, eta = factor_hessian(factor, values)
    scale = np.abs(want.H).max()
    np.testing.assert_allclose(info, H, rtol=0, atol=1e-9 * scale)
    np.testing.assert_allclose(eta, -g, rtol=0, atol=1e-8 * np.abs(g).max())
    assert factor.error(values) == pytest.approx(0.5 * want.cost, rel=1e-9)
    zero = gtsam.VectorValues()
    for k in factor.keys():
        zero.insert(k, np.zeros(S))
    assert factor.linearize(values).error(zero) == pytest.approx(0.5 * want.cost, rel=1e-9)


def test_factors_converge_to_the_truth_from_one_degree_off() -> None:
    robot = load_robot(ROBOT)
    sim = simulate(robot, 20, noise_px=0.0, seed=19, scene="room", n_points=500)
    seq = sim.sequence
    S = robot.n_segments
    graph = gtsam.NonlinearFactorGraph()
    for cam in robot.camera_segments:
        obs = camera_observations(robot, seq, cam)
        chain = camera_chain(robot, seq, cam)
        for chunk in chunk_tracks(obs):
            graph.add(ProjectionFactor(obs.select(chunk), chain, S).factor())
    graph.add(gtsam.PriorFactorVector(frame_key(0), seq.thetas[0],
                                      gtsam.noiseModel.Isotropic.Sigma(S, 1e-4)))
    start = _values(seq.thetas + math.radians(1.0))
    assert graph.error(start) > 1e3
    result = gtsam.LevenbergMarquardtOptimizer(graph, start).optimize()
    got = np.array([result.atVector(frame_key(f)) for f in range(seq.n_frames)])
    np.testing.assert_allclose(got, seq.thetas, atol=1e-6)


# --------------------------------------------------------------------------- chunk_tracks
@settings(max_examples=100, deadline=None)
@given(tracks=st.lists(st.tuples(st.integers(0, 200), st.integers(1, 150)), min_size=1,
                       max_size=40),
       frames_per_chunk=st.integers(1, 20))
def test_chunks_partition_tracks_that_start_together(tracks: list, frames_per_chunk: int
                                                     ) -> None:
    frames = np.concatenate([np.arange(s, s + length) for s, length in tracks])
    ids = np.concatenate([np.full(length, i) for i, (_, length) in enumerate(tracks)])
    obs = TrackObservations.build(0, frames, ids, np.zeros((len(ids), 2)),
                                  np.tile(np.eye(2), (len(ids), 1, 1)))
    chunks = chunk_tracks(obs, frames_per_chunk)
    every = np.concatenate(chunks)
    np.testing.assert_array_equal(np.sort(every), np.arange(obs.n_tracks))
    start = obs.frames[obs.starts[:-1]]
    length = np.diff(obs.starts)
    for chunk in chunks:
        assert len(chunk) > 0
        assert np.all(np.diff(chunk) > 0)  # increasing, as select() expects
        assert np.ptp(start[chunk]) < frames_per_chunk
        long = length[chunk] > 4 * frames_per_chunk
        assert long.all() or not long.any()  # long tracks get chunks of their own


def test_chunk_tracks_of_a_simulated_camera() -> None:
    robot = load_robot(ROBOT)
    sim = simulate(robot, 60, noise_px=0.5, seed=23, scene="room", n_points=400,
                   track_lifetime=8.0)
    obs = camera_observations(robot, sim.sequence, 0)
    chunks = chunk_tracks(obs, 10)
    assert len(chunks) >= 6
    np.testing.assert_array_equal(np.sort(np.concatenate(chunks)), np.arange(obs.n_tracks))
    assert sum(len(obs.select(c)) for c in chunks) == len(obs)
    empty = TrackObservations.build(0, [], [], np.zeros((0, 2)), np.zeros((0, 2, 2)))
    assert chunk_tracks(empty) == []


def test_points_left_far_behind_by_the_angles_are_triangulated_afresh() -> None:
    """With one triangulation step per linearisation (the smoother's iSAM2), points kept from
    angles 0.3 rad away must not make the system: those points lie off the rows by hundreds
    of pixels, some near or behind the cameras, and the system at them had information of 1e11
    and more per track where the eliminated system has about 1e6 (the windows iSAM2 then
    called indeterminate after a restart). The factor gives the system at fresh points."""
    robot = load_robot(ROBOT)
    sim = simulate(robot, 8, noise_px=1.0, seed=3, scene="room", n_points=400)
    seq = sim.sequence
    cam = 2
    obs = camera_observations(robot, seq, cam)
    chain = camera_chain(robot, seq, cam)
    w = np.ones(len(obs))
    away = reduced_system(obs, chain, seq.thetas + 0.3, 0, w)
    want = reduced_system(obs, chain, seq.thetas, 0, w)
    factor = ProjectionFactor(obs, chain, robot.n_segments)
    factor.points, factor.point_iterations = away.points, 1
    got = factor.system(seq.thetas)
    assert np.max(got.residuals) < 10.0
    assert got.cost == pytest.approx(want.cost, rel=0.05)
    top = np.linalg.eigvalsh(got.H)[-1]
    assert top == pytest.approx(np.linalg.eigvalsh(want.H)[-1], rel=0.05)
