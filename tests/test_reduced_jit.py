"""The compiled kernels held to their numpy reference: the same points, camera poses,
systems, costs and residual norms to rounding on seeded random chunks (moving bases, spatial
robots, outliers with weight 0, points behind a camera, calibration and mount columns)."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import random_pose
from test_projection_factor import (
    _rig,
    _rows,
    camera_chain,
    camera_observations,
    lens_robot,  # noqa: F401 (a fixture)
    parameterised,
    random_bases,
    truth_of,
)

from apcc_graph import Robot
from apcc_graph.factors import reduced_jit, track_points, triangulation, triangulation_jit
from apcc_graph.factors.camera_chain import camera_poses
from apcc_graph.factors.reduced_system import reduced_system
from apcc_graph.factors.track_points import TrackObservations
from apcc_graph.factors.triangulation import triangulate_rows
from apcc_graph.simulation.simulator import simulate


def test_the_kernels_constants_are_the_references() -> None:
    assert reduced_jit.MIN_DEPTH == triangulation_jit.MIN_DEPTH == track_points.MIN_DEPTH
    assert triangulation_jit.MIN_INVERSE_DEPTH == triangulation.MIN_INVERSE_DEPTH
    assert triangulation_jit.DEFAULT_DEPTH == triangulation.DEFAULT_DEPTH


def _rig_rows(seed: int, n_frames: int = 10, n_points: int = 40):
    """Rows of a random rig, row-last poses, and weights with outliers left out."""
    rng = np.random.default_rng(seed)
    poses, points = _rig(rng, n_frames, n_points, baseline=0.05)
    frames, ids = _rows(rng, n_frames, n_points)
    R, o = poses[frames, :3, :3], poses[frames, :3, 3]
    q = np.einsum("nji,nj->ni", R, points[ids] - o)
    xy = q[:, :2] / q[:, 2:] + rng.normal(0.0, 2e-3, (len(frames), 2))
    whiten = np.broadcast_to(np.diag([500.0, 480.0]), (len(frames), 2, 2))
    obs = TrackObservations.build(0, frames, ids, xy, whiten)
    order = np.lexsort((frames, ids))
    Rb = np.ascontiguousarray(np.moveaxis(R[order], 0, -1))
    ob = np.ascontiguousarray(o[order].T)
    weights = (rng.random(len(frames)) > 0.1).astype(float)
    return obs, Rb, ob, weights, np.ascontiguousarray(points.T)


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
@pytest.mark.parametrize("start", ["scratch", "near", "behind"])
def test_triangulation_equals_the_reference(seed: int, start: str) -> None:
    obs, Rb, ob, weights, truth = _rig_rows(seed)
    rng = np.random.default_rng(seed + 10)
    points = {"scratch": None, "near": truth + rng.normal(0.0, 0.05, truth.shape),
              "behind": -truth}[start]  # behind: every anchor restarts on its ray
    for iterations in (1, 2):  # the same steps to rounding
        ref = triangulate_rows(obs, Rb, ob, weights, points, iterations, engine="numpy")
        out = triangulate_rows(obs, Rb, ob, weights, points, iterations, engine="numba")
        np.testing.assert_allclose(out, ref, rtol=1e-9, atol=1e-10)
    # Converged: a last step whose cost ties the previous one to rounding may be taken by one
    # engine and not the other; they then differ by less than that step (tolerance 1e-6).
    ref = triangulate_rows(obs, Rb, ob, weights, points, 10, engine="numpy")
    out = triangulate_rows(obs, Rb, ob, weights, points, 10, engine="numba")
    np.testing.assert_allclose(out, ref, rtol=0, atol=1e-6)
    # and the answer is the truth's neighbourhood (2e-3 noise on a 5 cm rig), not a shared
    # mistake
    assert np.median(np.linalg.norm(out - truth, axis=0)) < 0.2


def test_an_unknown_engine_is_refused() -> None:
    obs, Rb, ob, weights, _ = _rig_rows(0)
    with pytest.raises(ValueError, match="engine = 'fortran'"):
        triangulate_rows(obs, Rb, ob, weights, None, engine="fortran")


def _assert_same_system(a, b, obs: TrackObservations, tolerance: float = 1e-7) -> None:
    """The same system to ``tolerance`` relative to the largest entry, and the same points
    (metres) of the tracks with three rows or more: a point seen once or twice is barely
    determined along its rays, and its step there is the damping's (it then leaves the system
    with its rows).

    Rounding: a narrow-baseline track's 3x3 point block is ill conditioned, and eliminating it
    cancels most of what its rows say, so perturbing the points by 1e-15 (relative) moves the
    reference's own ``g`` by 3e-9 and ``H`` by 1e-9 of their largest entries on these
    chunks; a wrong term moves them by orders more."""
    scale = np.abs(b.H).max()
    np.testing.assert_allclose(a.H, b.H, rtol=0, atol=tolerance * scale)
    np.testing.assert_allclose(a.g, b.g, rtol=0, atol=tolerance * np.abs(b.g).max())
    assert a.cost == pytest.approx(b.cost, rel=tolerance)
    determined = np.diff(obs.starts) >= 3
    np.testing.assert_allclose(a.points[determined], b.points[determined], rtol=0,
                               atol=100 * tolerance)
    np.testing.assert_array_equal(np.isinf(a.residuals), np.isinf(b.residuals))
    finite = np.isfinite(b.residuals) & determined[obs.tracks]
    np.testing.assert_allclose(a.residuals[finite], b.residuals[finite], rtol=tolerance,
                               atol=tolerance)


@pytest.mark.parametrize(("cam", "spatial", "columns"),
                         [(1, True, "frames"), (2, False, "frames"), (2, False, "calibration"),
                          (1, True, "mount"), (2, False, "both")])
def test_reduced_system_equals_the_reference(lens_robot: Robot, cam: int, spatial: bool,  # noqa: F811
                                             columns: str) -> None:
    sim = simulate(lens_robot, 12, noise_px=1.0, seed=5 + cam, scene="room", n_points=300,
                   moving_base=True, spatial=spatial, fps=10.0, outlier_fraction=0.1)
    seq = sim.sequence
    obs = camera_observations(lens_robot, seq, cam)
    rng = np.random.default_rng(cam)
    truth = truth_of(lens_robot, seq)
    thetas = truth[2:] + rng.normal(0.0, 0.003, truth[2:].shape)  # frames 2.. (first = 2)
    keep = obs.frames >= 2
    obs = obs.select(np.unique(obs.tracks[keep]))
    obs = TrackObservations.build(cam, obs.frames[obs.frames >= 2],
                                  obs.ids[obs.tracks][obs.frames >= 2],
                                  obs.xy[obs.frames >= 2], obs.whiten[obs.frames >= 2])
    weights = (rng.random(len(obs)) > 0.1).astype(float)
    chain = camera_chain(lens_robot, seq, cam)
    kw = {"calibration": columns in ("calibration", "both"), "mount": columns in ("mount", "both")}
    ref = reduced_system(obs, chain, thetas, 2, weights, engine="numpy", **kw)
    out = reduced_system(obs, chain, thetas, 2, weights, engine="numba", **kw)
    extra = 2 * (cam + 1) * kw["calibration"] + 6 * kw["mount"]
    assert out.H.shape == (10 * chain.n_parameters + extra,) * 2
    # Triangulated from scratch, the points agree to the triangulation's stopping tolerance
    # (test above) and the cost, minimised over them, closer; the systems then differ by what
    # such a move of an ill-determined point does, so they are compared at the same points.
    determined = np.diff(obs.starts) >= 3
    np.testing.assert_allclose(out.points[determined], ref.points[determined], rtol=1e-7,
                               atol=1e-6)  # relative: a point without parallax lies far away
    assert out.cost == pytest.approx(ref.cost, rel=1e-9)
    out = reduced_system(obs, chain, thetas, 2, weights, ref.points, refine_points=False,
                         engine="numba", **kw)
    _assert_same_system(out, ref, obs)
    # One step from the previous points, as the smoother relinearises.
    moved = thetas + rng.normal(0.0, 1e-3, thetas.shape)
    previous = ref.points
    ref = reduced_system(obs, chain, moved, 2, weights, previous, point_iterations=1,
                         engine="numpy", **kw)
    out = reduced_system(obs, chain, moved, 2, weights, previous, point_iterations=1,
                         engine="numba", **kw)
    _assert_same_system(out, ref, obs)


def test_a_point_behind_a_camera_is_left_out_alike(lens_robot: Robot) -> None:  # noqa: F811
    sim = simulate(lens_robot, 8, noise_px=1.0, seed=3, scene="room", n_points=200, fps=10.0)
    seq = sim.sequence
    obs = camera_observations(lens_robot, seq, 2)
    chain = camera_chain(lens_robot, seq, 2)
    truth = truth_of(lens_robot, seq)
    first = reduced_system(obs, chain, truth, 0, np.ones(len(obs)), engine="numpy")
    points = first.points.copy()
    base = chain.poses(truth, 0, False)[0][0]
    points[:5] = 2 * base[:3, 3] - points[:5]  # mirrored through the first camera: behind it
    kw = {"refine_points": False}
    ref = reduced_system(obs, chain, truth, 0, np.ones(len(obs)), points, engine="numpy", **kw)
    out = reduced_system(obs, chain, truth, 0, np.ones(len(obs)), points, engine="numba", **kw)
    assert np.isinf(ref.residuals).any()
    _assert_same_system(out, ref, obs)


@pytest.mark.parametrize("kind", ["planar", "fixed"])
@pytest.mark.parametrize("base", ["none", "one", "per frame"])
@pytest.mark.parametrize("n", [1, 3])
def test_compiled_camera_poses_equal_the_reference(kind: str, base: str, n: int) -> None:
    rng = np.random.default_rng(n + 7 * len(base))
    bending, x, _, _ = parameterised(kind, rng, 9, n)
    mount = random_pose(rng, 0.3, 0.05)
    bases = {"none": None, "one": random_pose(rng, 0.5, 0.3),
             "per frame": random_bases(rng, 9)}[base]
    for derivatives in (False, True):
        ref = camera_poses(x, bending, mount, bases, derivatives, engine="numpy")
        out = camera_poses(x, bending, mount, bases, derivatives, engine="numba")
        np.testing.assert_allclose(out[0], ref[0], rtol=0, atol=1e-14)
        if derivatives:
            np.testing.assert_allclose(out[1], ref[1], rtol=0, atol=1e-14)
        else:
            assert out[1] is None and ref[1] is None


def test_camera_poses_refuse_an_unknown_engine_and_a_wrong_base_count() -> None:
    bending, x, _, _ = parameterised("planar", np.random.default_rng(0), 4, 2)
    with pytest.raises(ValueError, match="engine = 'cuda'"):
        camera_poses(x, bending, np.eye(4), engine="cuda")
    with pytest.raises(ValueError, match="3 poses for 4 frames"):
        camera_poses(x, bending, np.eye(4), np.tile(np.eye(4), (3, 1, 1)))


@pytest.mark.parametrize("spatial", [False, True])
def test_known_points_system_equals_the_reference(lens_robot: Robot, spatial: bool) -> None:  # noqa: F811
    """The initial guess's system (one frame, known points, outliers and a point behind a
    camera): compiled and numpy alike, with Cauchy and with 0/1 weights."""
    from apcc_graph.estimation.initial_guess import FrameRows, _normal_equations
    from apcc_graph.model.parameterisation import Bending

    sim = simulate(lens_robot, 6, noise_px=1.0, seed=4, scene="room", n_points=300,
                   moving_base=True, spatial=spatial, fps=10.0, outlier_fraction=0.2)
    seq, f = sim.sequence, 4
    bending = Bending.free(lens_robot.segments) if spatial else Bending.fixed(lens_robot.segments)
    x = bending.vector(seq.thetas[f], None if seq.psis is None else seq.psis[f])
    rows = []
    for cam, trk in seq.tracks.items():
        camera = lens_robot.cameras[cam]
        sel = np.flatnonzero(trk.frames == f)
        xy = camera.normalized(trk.uv[sel])
        points = sim.points_world[sim.landmarks[cam][sel]].copy()
        points[0] = 2 * seq.world_T_base[f, :3, 3] - points[0]  # mostly behind the camera
        rows.append(FrameRows(cam, points, xy, camera.pixel_jacobian(xy)))
    x = x + np.random.default_rng(1).normal(0.0, 2e-4, x.shape)
    for scale in (None, 9.0):
        ref = _normal_equations(x, lens_robot, bending, seq.world_T_base[f], rows, scale, 5.0,
                                engine="numpy")
        out = _normal_equations(x, lens_robot, bending, seq.world_T_base[f], rows, scale, 5.0,
                                engine="numba")
        np.testing.assert_allclose(out[0], ref[0], rtol=0, atol=1e-10 * np.abs(ref[0]).max())
        np.testing.assert_allclose(out[1], ref[1], rtol=0, atol=1e-10 * np.abs(ref[1]).max())
        assert out[2] == pytest.approx(ref[2], rel=1e-10)
        for a, b in zip(out[3], ref[3], strict=True):
            np.testing.assert_array_equal(a, b)
        assert 0 < sum(int(b.sum()) for b in ref[3]) < sum(len(b) for b in ref[3])


def test_use_engine_switches_the_default_for_a_block_and_restores_it() -> None:
    from apcc_graph.factors.engine import resolve, use_engine

    obs, Rb, ob, weights, _ = _rig_rows(1)
    calls = []
    original = triangulation_jit.triangulate

    def spy(*args):
        calls.append(1)
        return original(*args)

    triangulation_jit.triangulate = spy
    try:
        with use_engine("numpy"):
            assert resolve(None) == "numpy"
            triangulate_rows(obs, Rb, ob, weights, None)
        assert calls == []  # the reference ran
        with pytest.raises(RuntimeError), use_engine("numpy"):
            raise RuntimeError
        assert resolve(None) == "numba"
        triangulate_rows(obs, Rb, ob, weights, None)
        assert calls == [1]
    finally:
        triangulation_jit.triangulate = original
    with pytest.raises(ValueError, match="expected one of 'numba', 'numpy'"), use_engine("c"):
        pass
